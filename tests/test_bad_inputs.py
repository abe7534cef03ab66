"""A corpus of bad inputs, each run through the real CLI against a workdir of good DESK artifacts.

Every case must give one clear error line on stderr, exit 2 (bad input) and leave every file in the
workdir byte-identical: no artifact replaced, no half-written or temporary file left behind.
"""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

import polars as pl
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from refusals import refused_in, snapshot
from mlnseq.catalog import artifacts
from mlnseq import binarize, collect

runner = CliRunner()
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
needs_non_root = pytest.mark.skipif(IS_ROOT, reason="root reads and writes regardless of permissions")


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


@pytest.fixture
def workdir(tmp_path, desk_full_workdir) -> Path:
    """A private copy of every artifact of the DESK pipeline."""
    return Path(shutil.copytree(desk_full_workdir, tmp_path / "work"))


def refused(workdir: Path, *args, needles: tuple[str, ...] = ()) -> str:
    """Run ``mlnseq ARGS -w WORKDIR``; assert exit 2, one error line, no traceback, workdir unchanged."""
    return refused_in(workdir, *args, "-w", workdir, needles=needles)


def rewrite_frames(workdir: Path, change) -> None:
    """Edit frames.parquet's rows as a user might with polars, keeping its mlnseq metadata."""
    path = workdir / artifacts.FRAMES
    table = pq.read_table(path)
    edited = change(pl.from_arrow(table)).to_arrow().replace_schema_metadata(table.schema.metadata)
    pq.write_table(edited, path)


def at_row(row: int, column: str, value):
    return lambda frames: frames.with_columns(
        pl.when(pl.int_range(pl.len()) == row).then(pl.lit(value)).otherwise(pl.col(column))
        .cast(frames[column].dtype).alias(column))


# ---- frames.parquet damaged or edited by hand --------------------------------------------------------

FRAME_CASES = {
    "truncated": (None, ("frames.parquet", "not a readable Parquet file", "mlnseq collect")),
    "empty file": (None, ("frames.parquet", "not a readable Parquet file")),
    "zero rows": (lambda f: f.head(0), ("holds no frames",)),
    "string feature": (lambda f: f.with_columns(pl.col("arm_distance").cast(pl.String)),
                       ("'arm_distance' is String, expected Float32",)),
    "float labels": (lambda f: f.with_columns(pl.col("label").cast(pl.Float64)), ("'label' is Float64, expected Int16",)),
    "missing split": (lambda f: f.drop("split"), ("no column 'split'",)),
    "unknown split": (at_row(7, "split", "validation"), ("split 'validation' at row 7",)),
    "NaN feature": (at_row(5, "left_gripper", float("nan")), ("'left_gripper' is empty, NaN or infinite at row 5",)),
    "inf feature": (at_row(900, "arm_distance", float("inf")), ("'arm_distance'", "row 900 (episode 0, frame 900)")),
    "empty feature": (at_row(3, "right_gripper", None), ("'right_gripper' is empty, NaN or infinite at row 3",)),
    "single class": (lambda f: f.with_columns(pl.lit(2, pl.Int16).alias("label")), ("single class",)),
    "duplicate frame index": (at_row(10, "frame", 9), ("row 10 (episode 0, frame 9) repeats the previous frame",)),
    "non-monotone frames": (at_row(10, "frame", 3), ("row 10 (episode 0, frame 3) goes back in time",)),
    "episode in two runs": (at_row(20, "episode", 1), ("episode 0 is split into separate runs",)),
    "unknown class in test": (
        lambda f: f.with_columns(pl.when(pl.col("split") == "test").then(pl.lit(9, pl.Int16))
                                 .otherwise(pl.col("label")).alias("label")),
        ("label 9 at row 1405 (episode 1, frame 0), outside its 7 classes",),
    ),
    "features unlike its metadata": (lambda f: f.rename({"left_gripper": "left_grip"}), ("metadata lists",)),
}


@pytest.mark.parametrize("command", [("binarize",), ("train", "--epochs", 1), ("conflate",)],
                         ids=lambda c: c[0])
@pytest.mark.parametrize("case", list(FRAME_CASES))
def test_damaged_frames_are_refused_by_every_reader(workdir, case, command):
    change, needles = FRAME_CASES[case]
    path = workdir / artifacts.FRAMES
    if case == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif case == "empty file":
        path.write_bytes(b"")
    else:
        rewrite_frames(workdir, change)
    refused(workdir, *command, needles=needles)


def test_a_truncated_checkpoint_and_truncated_predictions_are_refused(workdir):
    model = artifacts.checkpoint_path(workdir, "lstm")
    model.write_bytes(model.read_bytes()[:1000])
    refused(workdir, "conflate", needles=("lstm.pt is not an mlnseq checkpoint", "mlnseq train --method lstm"))
    predictions = workdir / artifacts.PREDICTIONS
    predictions.write_bytes(predictions.read_bytes()[:-100])
    refused(workdir, "eval", needles=("predictions.parquet is not a readable Parquet file", "mlnseq conflate"))


def test_an_artifact_that_is_a_folder_is_refused(workdir, desk_full_workdir):
    (workdir / artifacts.FRAMES).unlink()
    (workdir / artifacts.FRAMES).mkdir()
    refused(workdir, "binarize", needles=("frames.parquet", "is a directory"))
    refused(workdir, "eval", needles=("cannot read", "frames.parquet, an input of", "predictions.parquet"))
    (workdir / artifacts.FRAMES).rmdir()
    shutil.copy(desk_full_workdir / artifacts.FRAMES, workdir / artifacts.FRAMES)
    (workdir / artifacts.METRICS).unlink()
    (workdir / artifacts.METRICS).mkdir()
    refused(workdir, "eval", needles=("cannot write", "metrics.parquet"))


# ---- a checkpoint and frames with different feature sets ---------------------------------------------


@pytest.fixture(scope="module")
def kinematics_frames(tmp_path_factory, shared_data) -> Path:
    """DESK frames with the 14 kinematics channels instead of the 3 motion channels."""
    folder = tmp_path_factory.mktemp("kinematics")
    collect.run(folder, collect.CollectOptions(env="desk", source=shared_data / "desk-taurus", channels="kinematics"))
    return folder / artifacts.FRAMES


def test_swapped_frames_with_other_features_are_refused_downstream(workdir, kinematics_frames):
    shutil.copy(kinematics_frames, workdir / artifacts.FRAMES)
    refused(workdir, "conflate", needles=("predicates.parquet", "rerun `mlnseq binarize`"))
    refused(workdir, "eval", needles=("predictions.parquet", "rerun `mlnseq conflate`"))
    refused(workdir, "train", "--method", "priorlayer", "--epochs", 1, needles=("rerun `mlnseq binarize`",))
    for name in (artifacts.PREDICATES, artifacts.WEIGHTS):  # with the model alone, the model itself refuses
        (workdir / name).unlink()
    refused(workdir, "conflate", needles=("lstm.pt was trained on features", "rerun `mlnseq train --method lstm`"))


# ---- a user's own table (collect --env table) ---------------------------------------------------------

GOOD_CSV = "frame,label,a,b\n0,0,1.0,2.0\n1,0,1.5,2.5\n2,1,1.7,2.1\n3,1,1.9,2.0\n"

TABLE_CASES = {
    "empty.csv": ("", ("empty.csv", "cannot read it as csv")),
    "header-only.csv": ("frame,label,a,b\n", ("header-only.csv has no rows",)),
    "nan.csv": (GOOD_CSV.replace("1.5", "NaN"), ("nan.csv:3", "'a'")),
    "inf.csv": (GOOD_CSV.replace("1.5", "inf"), ("inf.csv:3", "'a' is empty, NaN or infinite")),
    "blank-cell.csv": (GOOD_CSV.replace("1.5", ""), ("blank-cell.csv:3", "'a'")),
    "typo.csv": (GOOD_CSV.replace("1.5", "1..5"), ("typo.csv:3", "column 'a' is numeric but holds '1..5'")),
    "single-class.csv": (GOOD_CSV.replace(",1,", ",0,"), ("single class",)),
    "duplicate-frames.csv": (GOOD_CSV.replace("\n2,", "\n1,"), ("duplicate-frames.csv:4", "repeats the previous frame")),
    "non-monotone.csv": (GOOD_CSV.replace("\n2,", "\n0,"), ("non-monotone.csv:4", "goes back in time")),
    "fractional-label.csv": (GOOD_CSV.replace(",1,1.7", ",1.5,1.7"), ("fractional-label.csv:4", "not a class index")),
    "binary.csv": (None, ("binary.csv",)),
    "float32-overflow.csv": (GOOD_CSV.replace("1.5", "1e308"), ("float32-overflow.csv:3", "'a'", "float32 range")),
    "duplicate-column.csv": (GOOD_CSV.replace(",b\n", ",a\n"), ("duplicate-column.csv", "'a' appears more than once")),
}


@pytest.mark.parametrize("name", list(TABLE_CASES))
def test_a_bad_table_leaves_the_frames_as_they_were(workdir, tmp_path, name):
    text, needles = TABLE_CASES[name]
    source = tmp_path / name
    if text is None:
        source.write_bytes(bytes(range(256)) * 4)
    else:
        source.write_text(text)
    refused(workdir, "collect", "--env", "table", "--source", source, needles=needles)


def test_bad_parquet_tables_leave_the_frames_as_they_were(workdir, tmp_path):
    zero = tmp_path / "zero.parquet"
    pl.DataFrame(schema={"frame": pl.Int64, "label": pl.Int64, "a": pl.Float64}).write_parquet(zero)
    refused(workdir, "collect", "--env", "table", "--source", zero, needles=("zero.parquet has no rows",))
    repeated = tmp_path / "repeated.parquet"
    pq.write_table(pl.read_csv(GOOD_CSV.encode()).to_arrow().rename_columns(["frame", "label", "a", "a"]), repeated)
    refused(workdir, "collect", "--env", "table", "--source", repeated,
            needles=("repeated.parquet", "'a' appears more than once"))
    truncated = tmp_path / "truncated.parquet"
    pl.read_csv(GOOD_CSV.encode()).write_parquet(truncated)
    truncated.write_bytes(truncated.read_bytes()[:-20])
    refused(workdir, "collect", "--env", "table", "--source", truncated,
            needles=("truncated.parquet: cannot read it as parquet",))


def test_unknown_classes_and_mixed_feature_sets_are_refused(workdir, tmp_path):
    named = tmp_path / "named.csv"
    named.write_text("frame,label,a\n0,reach,1\n1,reach,2\n2,lift,3\n")
    refused(workdir, "collect", "--env", "table", "--source", named, "--classes", "reach,grasp",
            needles=("named.csv:4", "'lift' is not one of --classes"))
    folder = tmp_path / "episodes"
    folder.mkdir()
    (folder / "e1.csv").write_text(GOOD_CSV)
    (folder / "e2.csv").write_text(GOOD_CSV.replace(",b", ",c"))
    refused(workdir, "collect", "--env", "table", "--source", folder, needles=("e2.csv", "differ from"))


def test_a_class_only_in_the_test_split_trains_with_a_warning(tmp_path):
    """Not an error: the user is told the model cannot predict it (and eval scores it as missed)."""
    source = tmp_path / "robot.csv"
    rows = ["episode,frame,label,split,a"]
    for episode, (split, labels) in enumerate([("train", [0, 1]), ("train", [1, 0]), ("test", [0, 2])]):
        rows += [f"{episode},{i},{labels[i // 5]},{split},{(i % 5) * 0.1 + labels[i // 5]}" for i in range(10)]
    source.write_text("\n".join(rows) + "\n")
    work = tmp_path / "w"
    assert runner.invoke(app, ["collect", "--env", "table", "--source", str(source), "-w", str(work)]).exit_code == 0
    result = runner.invoke(app, ["train", "--epochs", "1", "-w", str(work)])
    assert result.exit_code == 0, result.output
    assert "classes [2] occur in the test split but not in the training frames" in " ".join(result.output.split())


# ---- files the user cannot read, folders the stage cannot write, a full disk ---------------------------


@needs_non_root
def test_unreadable_inputs_are_refused(workdir, tmp_path):
    frames = workdir / artifacts.FRAMES
    frames.chmod(0)
    try:
        refused(workdir, "binarize", needles=("frames.parquet", "Permission denied"))
        refused(workdir, "eval", needles=("frames.parquet", "Permission denied"))  # an input of predictions
    finally:
        frames.chmod(0o644)
    spec = tmp_path / "locked.binarize.toml"
    spec.write_text(binarize.default_spec_path("desk").read_text())
    spec.chmod(0)
    folder = tmp_path / "episodes"
    folder.mkdir()
    (folder / "a.csv").write_text(GOOD_CSV)
    source = folder / "locked.csv"
    source.write_text(GOOD_CSV)
    source.chmod(0)
    before = snapshot(workdir)
    result = runner.invoke(app, ["binarize", "--spec", str(spec), "-w", str(workdir)])
    assert result.exit_code == 2 and "readable" in result.stderr and "Traceback" not in result.output
    assert snapshot(workdir) == before  # click refuses the option itself, in its usage box
    refused(workdir, "collect", "--env", "table", "--source", folder, needles=("locked.csv", "Permission denied"))


@needs_non_root
def test_a_read_only_workdir_is_refused_and_left_as_it_was(workdir):
    for folder in (workdir, workdir / artifacts.MODELS_DIR):
        folder.chmod(0o555)
    try:
        refused(workdir, "eval", needles=("cannot write", "metrics.parquet", "writable --workdir"))
        refused(workdir, "train", "--epochs", 1, needles=("cannot write", "lstm"))
        refused(workdir, "learn-weights", needles=("cannot write",))
    finally:
        for folder in (workdir, workdir / artifacts.MODELS_DIR):
            folder.chmod(0o755)


def write_half_then_fill_the_disk(real_write):
    def write(*args, **kwargs):
        target = args[1] if len(args) > 1 else kwargs.get("where", kwargs.get("f"))
        real_write(*args, **kwargs)
        if hasattr(target, "flush"):  # an open file (torch.save in save_checkpoint)
            target.flush()
            target = target.name
        target = Path(target)
        target.write_bytes(target.read_bytes()[: target.stat().st_size // 2])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    return write


def test_a_full_disk_mid_write_leaves_every_artifact_as_it_was(workdir, monkeypatch):
    """ENOSPC half-way through writing the temporary file, for Parquet artifacts and a checkpoint."""
    monkeypatch.setattr(artifacts.pq, "write_table", write_half_then_fill_the_disk(pq.write_table))
    refused(workdir, "eval", needles=("cannot write", "metrics.parquet", "No space left on device"))
    refused(workdir, "conflate", needles=("No space left on device",))
    refused(workdir, "learn-weights", needles=("No space left on device",))  # weights.parquet and learned.mln
    refused(workdir, "train", "--epochs", 1, needles=("No space left on device",))  # the log and the model
    monkeypatch.undo()

    import torch

    monkeypatch.setattr(torch, "save", write_half_then_fill_the_disk(torch.save))  # train's checkpoint
    refused(workdir, "train", "--epochs", 1, needles=("cannot write", "lstm.pt", "No space left on device"))


def test_a_bad_project_file_is_refused_before_any_stage_runs(workdir):
    (workdir / "mlnseq.toml").write_text("[train]\nepochs = 'many'\n")
    refused(workdir, "train", needles=("mlnseq.toml:2",))
