"""``fit --executor processes``: the logic (binarize, formulas, learn-weights) and the networks (train) as two
processes side by side through Snakemake, on six short episodes of the generated arm (tests/arm_bags.py, 15 Hz)
fitted for 2 epochs, write the model a local run writes (``arm_fit``, tests/conftest.py: the same predicates,
weights, network and predictions) and say the same lines; a part that fails names itself and its log; --executor and
--profile are checked first.
The same through a one-node SLURM cluster: tests/sweeps/test_sweep_slurm.py (one cluster per test file)."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest

pytest.importorskip("torch", reason="the [train] extra is not installed")
pytest.importorskip("snakemake", reason="the [sweep] extra is not installed")


def mlnseq(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(Path(sys.executable).with_name("mlnseq")), *args], cwd=cwd, capture_output=True,
                          text=True, timeout=900)


def same_model(one: Path, other: Path) -> None:
    """The same stages' tables and the same network: what a model file is made of."""
    import zipfile

    for name in ("predicates.parquet", "weights.parquet", "weights.folds.parquet", "predictions.parquet",
                 "models/lstm.oof.parquet"):
        assert pl.read_parquet(one / name).equals(pl.read_parquet(other / name)), name
    with zipfile.ZipFile(one / "model.mlnseq") as a, zipfile.ZipFile(other / "model.mlnseq") as b:
        assert a.namelist() == b.namelist()
        for name in set(a.namelist()) - {"manifest.json"}:  # the manifest names its workdir
            if name.endswith(".parquet"):  # the tables but for their "file" column (it names the workdir too)
                tables = [pl.read_parquet(io.BytesIO(z.read(name))).drop("file", strict=False) for z in (a, b)]
                assert tables[0].equals(tables[1]), name
            else:
                assert a.read(name) == b.read(name), name


@pytest.fixture(scope="module")
def arm_table(arm_fit_args) -> Path:
    return Path(arm_fit_args[arm_fit_args.index("--source") + 1])


def test_the_parts_side_by_side_write_the_model_a_local_run_writes(arm_fit_args, arm_fit, tmp_path):
    apart = mlnseq(*arm_fit_args, "-w", "apart", "--executor", "processes", cwd=tmp_path)
    assert apart.returncode == 0, apart.stderr[-3000:]
    same_model(arm_fit["workdir"], tmp_path / "apart")
    said = [line.replace("apart", "local") for line in apart.stdout.splitlines()]
    assert said[2].startswith("binarize, formulas and learn-weights, and train, as processes side by side "
                              "(their logs: local/.fit/logs)")
    assert said[:2] + said[3:] == [line for line in arm_fit["stdout"].splitlines() if not line.startswith("training")]
    logs = tmp_path / "apart" / ".fit" / "logs"
    assert sorted(p.name for p in logs.iterdir()) == ["logic.log", "network.log"]
    assert not list((tmp_path / "apart" / ".fit").glob("*.pickle"))  # the results, read, are gone


def test_a_part_that_fails_says_what_a_local_run_says_and_options_are_checked_first(arm_table, tmp_path):
    spec = tmp_path / "bad.binarize.toml"  # a predicate on a channel the frames lack: the logic part fails
    spec.write_text('[[predicate]]\nname = "hand"\nkind = "bins"\nchannel = "no_such_channel"\nedges = [0.5]\n'
                    'values = ["low", "high"]\n')
    said = []
    for executor in ("local", "processes"):
        done = mlnseq("fit", "--env", "table", "--source", str(arm_table), "-w", executor, "--epochs", "1", "--spec",
                      str(spec), "--executor", executor, cwd=tmp_path)
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-3000:]
        said.append(done.stderr.strip().splitlines()[-1])
    assert said[0] == said[1] and "no_such_channel" in said[0] and said[0].startswith("error: ")
    for flags, said in ((["--executor", "slurm"], "--executor slurm needs --profile DIR"),
                        (["--profile", str(tmp_path)], "--profile is for --executor slurm"),
                        (["--executor", "cloud"], "unknown --executor 'cloud': choose one of local, processes, slurm")):
        refused = mlnseq("fit", "--env", "table", "--source", str(arm_table), "-w", "never", *flags, cwd=tmp_path)
        assert refused.returncode == 2 and said in refused.stderr and not (tmp_path / "never").exists(), \
            refused.stderr
