"""The tiny sweep through a real one-node SLURM cluster (Snakemake's SLURM executor, one cluster job per rule, the
example profile's settings) gives the same results table as the same sweep run locally.

In `make test`, and alone in `make test-slurm` (about a minute on a free machine, several when loaded: the
executor's status checks wait 2 s, then 10 s more at a time while no job has finished; marker slurm). Without
slurm-wlm, munge or root it skips with the reason, except under CI (CI=true), where it fails."""

from __future__ import annotations

import os

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


def test_the_tiny_sweep_through_slurm_gives_the_local_table(cluster, local_sweep, tiny_desk_workdir, tmp_path):
    path = write_sweep(tmp_path, tiny_desk_workdir, TINY_GRID)
    profile = tmp_path / "profile"
    profile.mkdir()
    (profile / "config.yaml").write_text(PROFILE)
    done = mlnseq("sweep", str(path), "--executor", "slurm", "--profile", str(profile), cwd=tmp_path, env=cluster,
                  timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    jobs = list((tmp_path / "sweep" / ".snakemake" / "slurm_logs").glob("rule_*/*/*.log"))
    assert {p.parts[-3] for p in jobs} == {"rule_train", "rule_conflate", "rule_eval"} and len(jobs) == 12
    local = pl.read_parquet(local_sweep["out"] / "results.parquet").drop("deploy")
    through_slurm = pl.read_parquet(tmp_path / "sweep" / "results.parquet")
    assert through_slurm.drop("deploy").equals(local)
    assert through_slurm["deploy"].str.contains(str(tmp_path / "sweep" / "runs")).all()
    assert done.stdout.strip().splitlines()[-1].split("; deploy it")[0] == \
        local_sweep["result"].stdout.strip().splitlines()[-1].split("; deploy it")[0]


def test_the_example_profile_is_the_one_tested():
    """examples/sweep/slurm-profile holds the settings this test runs with (the status command, accounts)."""
    import yaml

    from sweep_files import REPO

    example = yaml.safe_load((REPO / "examples" / "sweep" / "slurm-profile" / "config.yaml").read_text())
    tested = yaml.safe_load(PROFILE)
    for key in ("executor", "slurm-status-command", "slurm-no-account", "slurm-init-seconds-before-status-checks"):
        assert example[key] == tested[key]
