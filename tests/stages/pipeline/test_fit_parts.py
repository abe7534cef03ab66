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

BAD_SPEC = ('[[predicate]]\nname = "hand"\nkind = "bins"\nchannel = "no_such_channel"\nedges = [0.5]\n'
            'values = ["low", "high"]\n')  # a predicate on a channel the frames lack: the logic part fails


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


def test_a_local_fit_of_many_frames_runs_its_logic_beside_the_networks_and_writes_the_same_model(
        arm_table, arm_fit, tmp_path, monkeypatch):
    """From parts.BESIDE_FRAMES training frames on (here lowered to this table's), a local fit learns the logic in a
    second process while it trains: the same model as one after the other."""
    from mlnseq.collect import CollectOptions
    from mlnseq.pipeline import fit as pipeline
    from mlnseq.pipeline import parts

    heard = []

    class Heard(pipeline.Observer):
        def binarized(self, step):
            heard.append("binarized")

        def training(self, epochs, folds):
            heard.append("training")  # before the logic's stages: they finish in the other process
            return super().training(epochs, folds)

        def trained(self, step):
            heard.append("trained")

    monkeypatch.setattr(parts, "BESIDE_FRAMES", 1)
    monkeypatch.chdir(tmp_path)
    pipeline.fit(CollectOptions(env="table", source=arm_table), "beside", pipeline.FitOptions(epochs=2), Heard())
    assert heard == ["training", "binarized", "trained"]
    same_model(arm_fit["workdir"], tmp_path / "beside")


def test_a_part_that_fails_says_what_a_local_run_says_and_options_are_checked_first(arm_table, tmp_path):
    spec = tmp_path / "bad.binarize.toml"
    spec.write_text(BAD_SPEC)
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


def test_a_logic_beside_the_networks_that_fails_raises_what_a_local_run_raises(arm_fit, tmp_path):
    import shutil

    from mlnseq.catalog.errors import BadInput
    from mlnseq.pipeline import fit as pipeline
    from mlnseq.pipeline import parts

    work = tmp_path / "work"
    work.mkdir()
    shutil.copy(arm_fit["workdir"] / "frames.parquet", work)
    spec = tmp_path / "bad.binarize.toml"
    spec.write_text(BAD_SPEC)
    options = pipeline.FitOptions(spec=spec, epochs=2)
    with pytest.raises(BadInput) as local:
        pipeline.logic_part(work, options, 3)
    with parts.logic_beside(work, (options, 3)) as logic, pytest.raises(BadInput) as beside:
        logic()
    assert str(beside.value) == str(local.value) and "no_such_channel" in str(local.value)
    assert (work / ".fit" / "logs" / "logic.log").is_file()
