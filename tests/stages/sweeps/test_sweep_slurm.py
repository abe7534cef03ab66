"""The tiny sweep through a real one-node SLURM cluster (Snakemake's SLURM executor, one cluster job per rule, the
example profile's settings): one of cell-tcn's eval jobs cancelled with scancel as it runs fails that config alone,
in one line naming it and its log, the rest finishing; the rerun submits only what is missing, and gives the same
results table as the same sweep run locally. And `mlnseq fit --executor slurm` on six short episodes of the generated
arm: its logic and its networks as two cluster jobs, the model the local run writes (``arm_fit``, tests/conftest.py;
here, one cluster per test file).

In `make test`, and alone in `make test-slurm` (about a minute on a free machine, several when loaded: the
executor's status checks wait 2 s, then 10 s more at a time while no job has finished; marker slurm). Without
slurm-wlm, munge or root it skips with the reason, except under CI (CI=true), where it fails."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import polars as pl
import pytest

from slurm_cluster import Unavailable, one_node_cluster
from sweep_files import TINY_GRID, mlnseq, write_sweep

pytestmark = pytest.mark.slurm

PROFILE = """executor: slurm
jobs: 4
latency-wait: 10
slurm-status-command: squeue
slurm-init-seconds-before-status-checks: 2
slurm-no-account: true
slurm-keep-successful-logs: true
default-resources:
  slurm_partition: debug
  mem_mb: 500
  runtime: 30
"""


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    try:
        with one_node_cluster(tmp_path_factory.mktemp("slurm")) as env:
            yield env
    except Unavailable as reason:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"the SLURM cluster cannot start under CI: {reason}")
        pytest.skip(f"no SLURM cluster here: {reason}")


def cancel_a_job(env: dict[str, str], config: str, rules: tuple[str, ...] = ("train", "conflate"),
                 timeout: float = 600) -> tuple[str, str]:
    """scancel the first running cluster job of one of ``rules`` for ``config`` (the executor's comment names the
    rule and the wildcards); its (job id, rule)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        listed = subprocess.run(["squeue", "-h", "-o", "%i|%k|%T"], env=env, capture_output=True, text=True).stdout
        for line in listed.splitlines():
            job, comment, state = line.split("|")
            rule = comment.removeprefix("rule_").split("_wildcards_")[0]
            if state == "RUNNING" and rule in rules and f"_{config}_" in f"{comment}_":
                subprocess.run(["scancel", job], env=env, check=True)
                return job, rule
        time.sleep(0.2)
    raise TimeoutError(f"no {' or '.join(rules)} job of {config} ran on the cluster within {timeout:g} s")


def started(command: list[str], folder: Path, env: dict[str, str]) -> subprocess.Popen:
    """``command`` running in ``folder``, its output to out.txt and err.txt there."""
    with open(folder / "out.txt", "w") as out, open(folder / "err.txt", "w") as err:
        return subprocess.Popen(command, cwd=folder, env=env, stdout=out, stderr=err, text=True)


def test_the_tiny_sweep_through_slurm_fails_a_cancelled_config_alone_and_the_rerun_gives_the_local_table(
        cluster, tiny_desk_workdir, request, tmp_path):
    path = write_sweep(tmp_path, tiny_desk_workdir, TINY_GRID)
    profile = tmp_path / "profile"
    profile.mkdir()
    (profile / "config.yaml").write_text(PROFILE)
    command = [str(Path(sys.executable).with_name("mlnseq")), "sweep", str(path), "--executor", "slurm", "--profile",
               str(profile)]
    sweep = started(command, tmp_path, cluster)
    try:
        with ThreadPoolExecutor(1) as watcher:  # cell-tcn's last job (eval): its rerun submits one job
            cancelled = watcher.submit(cancel_a_job, cluster, "cell-tcn", ("eval",))
            local_sweep = request.getfixturevalue("local_sweep")  # run while the executor waits between status checks
            job, rule = cancelled.result()
    finally:
        sweep.wait(timeout=900)
    err = (tmp_path / "err.txt").read_text()
    assert sweep.returncode == 1, err[-3000:]
    errors = [line for line in err.splitlines() if line.startswith("error: config")]
    assert len(errors) == 1 and errors[0].startswith(f"error: config cell-tcn failed: {rule} of seed "), err
    assert f"ended on the cluster with status CANCELLED (SLURM job {job}); its log: {tmp_path}/sweep/runs/" in errors[0]
    assert f"(the cluster's: {tmp_path}/sweep/.snakemake/slurm_logs/rule_{rule}/" in errors[0]
    assert any(line.startswith("    | ") and f"JOB {job} " in line and "CANCELLED" in line for line in err.splitlines())
    cancelled = pl.read_parquet(tmp_path / "sweep" / "results.parquet")
    assert cancelled["status"].to_list() == ["done", "failed"]
    local = pl.read_parquet(local_sweep["out"] / "results.parquet").drop("deploy")
    assert cancelled.drop("deploy").row(0) == local.row(0)
    before = set((tmp_path / "sweep" / ".snakemake" / "slurm_logs").glob("rule_*/*/*.log"))
    done = mlnseq(*command[1:], cwd=tmp_path, env=cluster, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    jobs = set((tmp_path / "sweep" / ".snakemake" / "slurm_logs").glob("rule_*/*/*.log"))
    assert {p.parts[-3] for p in jobs} == {"rule_train", "rule_conflate", "rule_eval"} and len(before) == 12
    assert all("cell-tcn" in p.parts[-2] for p in jobs - before) and len(jobs - before) == 1  # its missing job alone
    through_slurm = pl.read_parquet(tmp_path / "sweep" / "results.parquet")
    assert through_slurm.drop("deploy").equals(local)
    assert through_slurm["deploy"].str.contains(str(tmp_path / "sweep" / "runs")).all()
    assert done.stdout.strip().splitlines()[-1].split("; deploy it")[0] == \
        local_sweep["result"].stdout.strip().splitlines()[-1].split("; deploy it")[0]


def test_fit_through_slurm_writes_the_model_a_local_run_writes(cluster, arm_fit_args, request, tmp_path):
    import zipfile

    profile = tmp_path / "profile"
    profile.mkdir()
    (profile / "config.yaml").write_text(PROFILE)
    done = started([str(Path(sys.executable).with_name("mlnseq")), *arm_fit_args, "-w", "cluster", "--executor",
                    "slurm", "--profile", str(profile)], tmp_path, cluster)
    try:
        arm_fit = request.getfixturevalue("arm_fit")  # run while the executor waits between status checks
    finally:
        done.wait(timeout=900)
    assert done.returncode == 0, (tmp_path / "err.txt").read_text()[-3000:]
    local = arm_fit["workdir"]
    jobs = {p.parts[-2] for p in (tmp_path / "cluster" / ".fit" / ".snakemake" / "slurm_logs").glob("rule_*/*.log")}
    assert jobs == {"rule_logic", "rule_network"}
    for name in ("predicates.parquet", "weights.parquet", "predictions.parquet", "models/lstm.oof.parquet"):
        assert pl.read_parquet(local / name).equals(pl.read_parquet(tmp_path / "cluster" / name)), name
    with zipfile.ZipFile(local / "model.mlnseq") as a, zipfile.ZipFile(tmp_path / "cluster" / "model.mlnseq") as b:
        assert a.read("network.npz") == b.read("network.npz") and a.read("binarize.toml") == b.read("binarize.toml")
    said = (tmp_path / "out.txt").read_text()
    assert said.splitlines()[-1].replace("cluster", "local") == arm_fit["stdout"].splitlines()[-1]


def test_the_example_profile_is_the_one_tested():
    """examples/sweep/slurm-profile holds the settings this test runs with (the status command, accounts)."""
    import yaml

    from sweep_files import REPO

    example = yaml.safe_load((REPO / "examples" / "sweep" / "slurm-profile" / "config.yaml").read_text())
    tested = yaml.safe_load(PROFILE)
    for key in ("executor", "slurm-status-command", "slurm-no-account", "slurm-init-seconds-before-status-checks"):
        assert example[key] == tested[key]
