"""Where ``fit`` runs its two independent parts: the **logic** (binarize, formulas, learn-weights) and the
**network** (train: the network, then its fold networks) read only the collected frames and the folds, so they can
run side by side. ``Executor.LOCAL`` runs them in fit's own process, one after the other (from ``BESIDE_FRAMES``
training frames on, with two cores, the logic in a second process while fit trains: ``beside``); ``PROCESSES`` and
``SLURM`` run them as the two jobs of a Snakemake workflow, on this machine's cores or as cluster jobs through
Snakemake's SLURM executor (with a profile, as `mlnseq sweep --executor slurm` takes one). Each job is fit's own
code (``mlnseq.pipeline.fit.run_part``) in a process of the same installation; what it returns comes back through
a file, so the model file is the one a local run writes.

The workflow lives in ``WORKDIR/.fit/``: the plan (fit's options and folds, as the driver made them), the
Snakefile, each part's result and each job's log (``logs/PART.log``), which stay there for reading; the plan and
the results are removed once read. The workdir must be on a file system the cluster's nodes share. A local fit's
logic beside it is the same job without Snakemake (``logic_beside``), its plan, result and log in the same folder.
"""

from __future__ import annotations

import enum
import os
import pickle
import shlex
import shutil
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput, MlnseqError

FOLDER = ".fit"  # in the workdir
PLAN = "plan.pickle"
PARTS = ("logic", "network")
# what a cluster schedules each part with; a profile's set-resources / set-threads override them
RESOURCES = {"logic": {"mem_mb": 4000, "runtime": 60}, "network": {"mem_mb": 4000, "runtime": 240}}

TEMPLATE = '''\
# Written by `mlnseq fit --executor {executor}`: fit's two independent parts, each a job running fit's own code.
# fit writes this file again on every run.
localrules: all

rule all:
    input: {results}
{rules}'''

RULE = '''
rule {part}:
    output: "{part}.pickle"
    log: "logs/{part}.log"
    threads: 1
    resources: {resources}
    shell: "cd {cwd} && {python} -c 'import sys; from mlnseq.pipeline.fit import run_part; "
           "run_part(sys.argv[1], sys.argv[2])' {part} {workdir} > {out}/{{log}} 2>&1"
'''


BESIDE_FRAMES = 20_000  # training frames from which a local fit runs the logic in a second process (two cores)


class Executor(enum.Enum):
    """Where fit's parts run."""

    LOCAL = "local"  # in fit's own process, one after the other; from BESIDE_FRAMES on, the logic beside (``beside``)
    PROCESSES = "processes"  # side by side, as processes on this machine (Snakemake's local executor)
    SLURM = "slurm"  # as SLURM jobs (Snakemake's SLURM executor, with --profile)


def check(executor: Executor, profile: Path | None) -> None:
    """What can be checked before any work: Snakemake (and its SLURM executor) installed, the profile readable."""
    from mlnseq.pipeline import sweep
    from mlnseq.catalog import errors

    if executor is Executor.LOCAL:
        if profile is not None:
            raise BadInput("--profile is for --executor slurm: leave it out, or add --executor slurm")
        return
    if executor is Executor.SLURM and profile is None:
        raise BadInput("--executor slurm needs --profile DIR, a Snakemake profile for the cluster "
                       "(examples/sweep/slurm-profile is one for a one-node cluster)")
    if not sweep.installed("snakemake"):
        raise BadInput(f"--executor {executor.value} runs fit's parts on Snakemake, which is not installed: "
                       f"{errors.install_hint('sweep')}")
    if executor is Executor.SLURM and not sweep.installed("snakemake_executor_plugin_slurm"):
        raise BadInput(f"--executor slurm needs Snakemake's SLURM executor: {errors.install_hint('sweep')}")
    if profile is not None:
        sweep.check_profile(Path(profile))


def beside(frames: Any) -> bool:
    """Whether a local fit of ``frames`` (the collected table) runs its logic in a second process while it trains
    the networks: from BESIDE_FRAMES training frames on, where the process has two cores or more. Smaller fits
    take seconds, and a second process's start-up (about a second) and two parts slowing each other on shared cores
    would eat what it gains."""
    return len(os.sched_getaffinity(0)) >= 2 and int((frames["split"] == "train").sum()) >= BESIDE_FRAMES


@contextmanager
def logic_beside(workdir: Path, plan: Any) -> Iterator[Callable[[], Any]]:
    """fit's logic part as a second process of this installation (``run_part``, by ``plan`` as ``write_plan`` keeps
    it) while the caller trains; what it gives waits for the logic's result, or raises the error it stopped with.
    The process is stopped on leaving, whatever it was doing."""
    import subprocess

    out = write_plan(workdir, plan)
    log = out / "logs" / "logic.log"
    with log.open("w") as said:
        process = subprocess.Popen([sys.executable, "-c", "import sys; from mlnseq.pipeline.fit import run_part; "
                                    "run_part(sys.argv[1], sys.argv[2])", "logic", str(workdir)],
                                   stdout=said, stderr=subprocess.STDOUT)

    def result() -> Any:
        code = process.wait()
        if code != 0:
            _raise_own_error(out, "logic")
            raise MlnseqError(f"fit's logic part failed (exit {code}): {_last_line(log) or 'no output'}; "
                              f"its log: {log}")
        done = _taken(out, "logic")
        (out / PLAN).unlink(missing_ok=True)
        return done

    try:
        yield result
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def folder(workdir: Path) -> Path:
    return Path(workdir) / FOLDER


def write_plan(workdir: Path, plan: Any) -> Path:
    """A fresh ``WORKDIR/.fit`` (an earlier run's results and Snakemake's records gone) holding ``plan``."""
    out = folder(workdir)
    shutil.rmtree(out, ignore_errors=True)
    (out / "logs").mkdir(parents=True)
    with artifacts.atomic_path(out / PLAN) as staged:
        staged.write_bytes(pickle.dumps(plan))
    return out


def read_plan(workdir: Path) -> Any:
    return pickle.loads((folder(workdir) / PLAN).read_bytes())


def write_result(workdir: Path, part: str, result: Any) -> None:
    """A job's result (or ``PART.error``: the error it stopped with), whole or not at all (Snakemake takes the file
    for the job's end)."""
    with artifacts.atomic_path(folder(workdir) / f"{part}.pickle") as staged:
        staged.write_bytes(pickle.dumps(result))


def snakefile(workdir: Path, executor: Executor) -> str:
    python, cwd = shlex.quote(sys.executable), shlex.quote(str(Path.cwd()))
    out = shlex.quote(str(folder(workdir).resolve()))  # the job runs in this folder; fit's paths as they were given
    rules = "".join(RULE.format(part=part, python=python, cwd=cwd, workdir=shlex.quote(str(workdir)), out=out,
                                resources=", ".join(f"{k}={v}" for k, v in RESOURCES[part].items()))
                    for part in PARTS)
    results = ", ".join(f'"{part}.pickle"' for part in PARTS)
    return TEMPLATE.format(executor=executor.value, results=results, rules=rules)


def command(out: Path, executor: Executor, profile: Path | None) -> list[str]:
    out = out.resolve()
    base = [sys.executable, "-m", "snakemake", "--snakefile", str(out / "Snakefile"), "--directory", str(out)]
    if executor is Executor.SLURM:
        return base + ["--executor", "slurm", "--profile", str(Path(profile).resolve())]
    return base + ["--cores", str(len(PARTS))]


def run(workdir: Path, executor: Executor, profile: Path | None) -> dict[str, Any]:
    """Run the parts of the plan in ``WORKDIR/.fit`` (``write_plan``) through Snakemake; each part's result. A job
    that fails is an error naming its part, why and its log."""
    from mlnseq.sweeps import running

    out = folder(workdir)
    artifacts.write_text(out / "Snakefile", snakefile(workdir, executor))
    ran = running.run_snakemake(command(out, executor, profile), out / "snakemake.log", lambda _: None)
    if ran.code != 0:
        for part in PARTS:
            _raise_own_error(out, part)
        raise MlnseqError(failed(ran, out))
    results = {part: _taken(out, part) for part in PARTS}
    (out / PLAN).unlink(missing_ok=True)
    return results


def _raise_own_error(out: Path, part: str) -> None:
    """A part's own error (bad input), raised as a local run raises it, where it stopped with one."""
    said = out / f"{part}.error.pickle"
    if said.is_file():
        raise pickle.loads(said.read_bytes())


def _taken(out: Path, part: str) -> Any:
    """A part's result, read and its file removed."""
    path = out / f"{part}.pickle"
    result = pickle.loads(path.read_bytes())
    path.unlink()
    return result


def _last_line(log: Path) -> str:
    """A job log's last line that is not blank, stripped ('' where it has none or cannot be read)."""
    from mlnseq.sweeps import results, running

    return running.last_line(results.last_lines(log, 1))


def failed(ran: Any, out: Path) -> str:
    """One line: which part failed and why, with its log and its last line; or Snakemake's own last line."""
    for error in ran.errors:
        log = out / "logs" / f"{error.rule}.log"
        return f"fit's {error.rule} part {error.reason()}: {_last_line(log) or 'no output'}; its log: {log}"
    return (f"fit's parts' workflow failed (snakemake exit {ran.code}): {ran.last_line or 'no output'}; "
            f"see {out / 'snakemake.log'}")
