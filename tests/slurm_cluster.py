"""A real one-node SLURM cluster on this machine for the sweep tests: Debian's slurm-wlm and munge, configured for
127.0.0.1 in a folder of its own (state, spool, logs, key, ports), started as root and stopped by process id.

The SLURM executor's jobs run their rule through `srun`, and the jobstep plugin clears every SLURM_* variable
(SLURM_CONF too) before it calls srun: srun then reads the configuration at its compiled-in place,
/etc/slurm/slurm.conf, as on a real cluster's nodes. The cluster is written there while it runs (only where no
configuration is there already) and removed when it stops."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

SYSTEM_CONF = Path("/etc/slurm/slurm.conf")
PROGRAMS = ("munged", "slurmctld", "slurmd", "sbatch", "squeue", "sinfo", "scontrol", "srun")


class Unavailable(Exception):
    """What this machine lacks for the cluster (a program, root, a free /etc/slurm/slurm.conf)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def memory_mb() -> int:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return int(line.split()[1]) // 1024
    return 2000


def config(folder: Path, host: str, ports: tuple[int, int]) -> str:
    return "\n".join([
        "ClusterName=mlnseqtest", f"SlurmctldHost={host}(127.0.0.1)", f"SlurmctldPort={ports[0]}",
        f"SlurmdPort={ports[1]}", "SlurmUser=root", "SlurmdUser=root", "AuthType=auth/munge", "CredType=cred/munge",
        f"AuthInfo=socket={folder}/munge.sock", f"StateSaveLocation={folder}/state", f"SlurmdSpoolDir={folder}/spool",
        f"SlurmctldPidFile={folder}/slurmctld.pid", f"SlurmdPidFile={folder}/slurmd.pid",
        f"SlurmctldLogFile={folder}/slurmctld.log", f"SlurmdLogFile={folder}/slurmd.log",
        "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none", "SelectType=select/cons_tres",
        "SelectTypeParameters=CR_Core", "SchedulerType=sched/backfill", "ReturnToService=2", "MpiDefault=none",
        "MinJobAge=300",  # a finished job stays visible to squeue for 5 minutes (the executor's status command)
        "AccountingStorageType=accounting_storage/none", "JobAcctGatherType=jobacct_gather/none",
        f"NodeName={host} NodeAddr=127.0.0.1 CPUs={os.cpu_count()} RealMemory={memory_mb() * 9 // 10} State=UNKNOWN",
        "PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP", ""])


def check_machine() -> None:
    missing = [p for p in PROGRAMS if shutil.which(p) is None]
    if missing:
        raise Unavailable(f"{', '.join(missing)} not installed (apt-get install slurm-wlm munge; make setup does "
                          "as root)")
    if os.geteuid() != 0:
        raise Unavailable("slurmd and munged run as root here; run the test as root")
    if SYSTEM_CONF.exists():
        raise Unavailable(f"{SYSTEM_CONF} exists: this machine has a SLURM of its own, which the test leaves alone")


def pid_of(path: Path, deadline: float) -> int:
    while time.monotonic() < deadline:
        with contextlib.suppress(FileNotFoundError, ValueError):
            return int(path.read_text().strip())
        time.sleep(0.1)
    raise RuntimeError(f"{path} did not appear: see the logs beside it")


@contextlib.contextmanager
def one_node_cluster(folder: Path) -> Iterator[dict[str, str]]:
    """Start munged, slurmctld and slurmd; yield the environment the SLURM commands need; stop them by pid."""
    check_machine()
    for sub in ("state", "spool"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    key = folder / "munge.key"
    key.write_bytes(os.urandom(1024))
    key.chmod(0o400)
    conf = folder / "slurm.conf"
    host = socket.gethostname()
    conf.write_text(config(folder, host, (free_port(), free_port())))
    env = {**os.environ, "SLURM_CONF": str(conf)}
    pids: list[int] = []
    wrote_system_conf = False
    try:
        SYSTEM_CONF.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(conf, SYSTEM_CONF)
        wrote_system_conf = True
        deadline = time.monotonic() + 30
        subprocess.run(["munged", "--force", f"--socket={folder}/munge.sock", f"--key-file={key}",
                        f"--pid-file={folder}/munged.pid", f"--log-file={folder}/munged.log",
                        f"--seed-file={folder}/munged.seed"], check=True, env=env)
        pids.append(pid_of(folder / "munged.pid", deadline))
        subprocess.run(["slurmctld"], check=True, env=env)
        pids.append(pid_of(folder / "slurmctld.pid", deadline))
        subprocess.run(["slurmd", "-N", host], check=True, env=env)
        pids.append(pid_of(folder / "slurmd.pid", deadline))
        while time.monotonic() < deadline:
            state = subprocess.run(["sinfo", "-h", "-o", "%t"], env=env, capture_output=True, text=True).stdout
            if state.strip() == "idle":
                break
            time.sleep(0.3)
        else:
            raise RuntimeError(f"the node is not idle after 30 s: see {folder}/slurmctld.log and slurmd.log")
        yield env
    finally:
        for pid in reversed(pids):  # slurmd, slurmctld, munged: each by its own process id
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)
        for pid in pids:
            for _ in range(100):
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                time.sleep(0.1)
        if wrote_system_conf:
            SYSTEM_CONF.unlink(missing_ok=True)
