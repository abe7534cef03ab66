"""`mlnseq collect` through the CLI: the DESK and Fetch runs, and every bad input it refuses."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts
from mlnseq.sources import desk

runner = CliRunner()
TRAIN, TEST = desk.MOTION_FILES


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    """Errors as users see them: one line, no traceback (another test may have set --verbose)."""
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


def small_desk_copy(shared_data: Path, folder: Path, line: int | None = None, text: str = "", name: str = TRAIN) -> Path:
    """The first 6 lines of each DESK motion file in ``folder``, with 1-based ``line`` of ``name`` replaced."""
    folder.mkdir()
    for each in (TRAIN, TEST):
        lines = (shared_data / "desk-taurus" / each).read_text().splitlines()[:6]
        if each == name and line is not None:
            lines[line - 1] = text
        (folder / each).write_text("\n".join(lines) + "\n")
    return folder


def invoke(*args: str):
    return runner.invoke(app, ["collect", *args])


def test_desk_import_through_the_cli(tmp_path, shared_data):
    result = invoke("--env", "desk", "--source", str(shared_data / "desk-taurus"), "-w", str(tmp_path))
    assert result.exit_code == 0, result.output
    output = " ".join(result.output.split())
    assert "22,329 frames, 2 episodes, 1,405 train / 20,924 test, 3 features" in output
    assert "succeeded" not in output
    assert pl.read_parquet(tmp_path / artifacts.FRAMES).height == 22_329


@pytest.mark.mujoco
def test_fetch_collection_through_the_cli(tmp_path):
    result = invoke("--env", "fetch", "--episodes", "2", "--seed", "5", "--train-frames", "60", "--goals",
                    "-w", str(tmp_path))
    assert result.exit_code == 0, result.output
    output = " ".join(result.output.split())
    assert "100 frames, 2 episodes, 60 train / 40 test, 31 features" in output
    frames, meta = artifacts.read_table(tmp_path / artifacts.FRAMES, "frames")
    assert f"episodes that succeeded: {meta['success_rate']:.1%}" in output
    assert meta["options"]["seed"] == 5 and frames.height == 100


# (flags after the workdir, with {src} the DESK folder made for the case; words the one error line must hold)
BAD_INPUTS = {
    "unknown env": (lambda d, tmp: ["--env", "kitchen"], ["--env", "kitchen", "fetch, desk"]),
    "no source": (lambda d, tmp: ["--env", "desk"], ["--env desk needs --source"]),
    "source not there": (lambda d, tmp: ["--env", "desk", "--source", str(tmp / "nowhere")], ["--source", "nowhere"]),
    "empty folder": (
        lambda d, tmp: ["--env", "desk", "--source", str(mkdir(tmp / "empty"))], [f"empty/{TRAIN} not found"]),
    "unknown channels": (
        lambda d, tmp: ["--env", "desk", "--source", str(small_desk_copy(d, tmp / "src")), "--channels", "video"],
        ["--channels", "video"]),
    "wrong column count": (
        lambda d, tmp: ["--env", "desk", "--source", str(small_desk_copy(d, tmp / "src", 3, "1 2 3 4 5 6"))],
        [f"{TRAIN}:3:", "expected 7 columns, found 6"]),
    "non-numeric value": (
        lambda d, tmp: ["--env", "desk", "--source",
                        str(small_desk_copy(d, tmp / "src", 2, "0.5 1 0.9 1 abc 2 0", name=TEST))],
        [f"{TEST}:2:", "non-numeric", "abc"]),
    "NaN": (
        lambda d, tmp: ["--env", "desk", "--source", str(small_desk_copy(d, tmp / "src", 4, "nan 1 0.9 1 0.9 2 0"))],
        [f"{TRAIN}:4:", "NaN"]),
    "infinity": (
        lambda d, tmp: ["--env", "desk", "--source",
                        str(small_desk_copy(d, tmp / "src", 5, "0.5 1 inf 1 0.9 2 0", name=TEST))],
        [f"{TEST}:5:", "infinite"]),
    "label out of range": (
        lambda d, tmp: ["--env", "desk", "--source", str(small_desk_copy(d, tmp / "src", 2, "0.5 1 0.9 1 0.9 2 7"))],
        [f"{TRAIN}:2:", "label 7", "0..6"]),
    "zero episodes": (lambda d, tmp: ["--env", "fetch", "--episodes", "0"], ["--episodes", "at least 1"]),
}


def mkdir(path: Path) -> Path:
    path.mkdir()
    return path


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_is_one_line_exit_2_and_writes_nothing(case, tmp_path, shared_data, desk_frames_workdir):
    flags, words = BAD_INPUTS[case]
    args = flags(shared_data, tmp_path)
    fresh, existing = tmp_path / "fresh", tmp_path / "existing"
    existing.mkdir()
    before = (desk_frames_workdir / artifacts.FRAMES).read_bytes()
    (existing / artifacts.FRAMES).write_bytes(before)

    for workdir in (fresh, existing):
        result = invoke(*args, "-w", str(workdir))
        assert result.exit_code == 2, result.output
        lines = result.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
        assert all(word in lines[0] for word in words), lines[0]
        assert "Traceback" not in result.output
    assert not fresh.exists() or list(fresh.iterdir()) == []
    assert [p.name for p in existing.iterdir()] == [artifacts.FRAMES]
    assert (existing / artifacts.FRAMES).read_bytes() == before


@pytest.mark.parametrize(("labels", "classes", "line"), [
    ("names", "grasp,approach,lift,release",
     "classes in label order (as --classes lists them): grasp, approach, lift, release"),
    ("names", None, "classes in label order (label names sorted alphabetically; give --classes to choose the order): "
                    "approach, grasp, lift, release"),
    ("indices", None, "classes in label order (numeric labels: label k is class k): 0, 1, 2, 3"),
])
def test_collect_prints_the_classes_in_label_order_and_how_they_were_ordered(tmp_path, own_data_glitch, labels,
                                                                             classes, line):
    recordings = pl.read_csv(own_data_glitch["csv"])
    if labels == "indices":
        order = {"approach": 0, "grasp": 1, "lift": 2, "release": 3}
        recordings = recordings.with_columns(pl.col("phase").replace_strict(order, return_dtype=pl.Int64))
    source = tmp_path / "recordings.csv"
    recordings.write_csv(source)
    args = ["--env", "table", "--source", str(source), "--episode-column", "trial", "--time-column", "t",
            "--label-column", "phase", "-w", str(tmp_path / "work")] + (["--classes", classes] if classes else [])
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    assert line in " ".join(result.output.split())
