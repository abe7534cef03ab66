"""`mlnseq binarize` through the CLI: the bare command after collect, and its errors."""

from __future__ import annotations

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts

runner = CliRunner()


@pytest.fixture(scope="module")
def desk_workdir(tmp_path_factory, shared_data):
    workdir = tmp_path_factory.mktemp("desk")
    result = runner.invoke(
        app, ["collect", "--env", "desk", "--source", str(shared_data / "desk-taurus"), "-w", str(workdir)]
    )
    assert result.exit_code == 0, result.output
    return workdir


def test_bare_binarize_after_collect_writes_the_paper_predicates(desk_workdir):
    result = runner.invoke(app, ["binarize", "-w", str(desk_workdir), "--table"])
    assert result.exit_code == 0, result.output
    output = " ".join(result.output.split())  # rich wraps at the terminal width
    assert "predicates.parquet (4 predicates, 38 columns, 22,329 frames" in output
    assert "grippers_closed_closed 4.5%" in output  # a --table row: both grippers closed
    predicates, meta = artifacts.read_table(desk_workdir / artifacts.PREDICATES, "predicates")
    frames, frames_meta = artifacts.read_table(desk_workdir / artifacts.FRAMES, "frames")
    assert predicates.select(artifacts.KEY_COLUMNS).equals(frames.select(artifacts.KEY_COLUMNS))
    assert meta["classes"] == frames_meta["classes"] and meta["source"] == "desk"
    assert meta["spec"]["path"].endswith("stages/specs/desk.binarize.toml") and "previous_scale" in meta["spec"]["text"]
    assert set(meta["inputs"]) == {artifacts.FRAMES, meta["spec"]["path"]}
    assert set(meta["predicates"]) == {"arm_distance", "left_gripper", "right_gripper", "grippers"}
    assert predicates.columns[4:] == [c for name in ("arm_distance", "left_gripper", "right_gripper", "grippers")
                                      for c in meta["predicates"][name]]
    assert all(dtype == pl.Boolean for dtype in predicates.select(pl.exclude(artifacts.KEY_COLUMNS)).dtypes)


def test_missing_frames_says_to_run_collect(tmp_path):
    result = runner.invoke(app, ["binarize", "-w", str(tmp_path)])
    assert result.exit_code == 2
    assert "run `mlnseq collect` first" in result.stderr and "Traceback" not in result.output


def test_a_bad_spec_is_one_line_with_file_and_line_and_writes_nothing(desk_workdir, tmp_path):
    spec = tmp_path / "bad.binarize.toml"
    spec.write_text('[[predicate]]\nname = "g"\nkind = "change"\nchannel = "left_gripper"\nthreshold = -1\n')
    before = sorted(p.name for p in desk_workdir.iterdir())
    result = runner.invoke(app, ["binarize", "-w", str(desk_workdir), "--spec", str(spec)])
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines() == [
        f"error: {spec}:5: key 'threshold' of [[predicate]] 'g': must be at least 0, got -1"
    ]
    assert sorted(p.name for p in desk_workdir.iterdir()) == before


def test_an_absent_spec_file_is_a_usage_error(desk_workdir, tmp_path):
    result = runner.invoke(app, ["binarize", "-w", str(desk_workdir), "--spec", str(tmp_path / "nope.toml")])
    assert result.exit_code == 2 and "nope.toml not found" in result.stderr


@pytest.mark.mujoco
def test_fetch_frames_get_the_paper_spec_by_default_and_the_rich_one_on_request(tmp_path, repo_root):
    result = runner.invoke(app, ["collect", "--env", "fetch", "--episodes", "2", "--goals", "-w", str(tmp_path)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["binarize", "-w", str(tmp_path)])
    assert result.exit_code == 0, result.output
    _, meta = artifacts.read_table(tmp_path / artifacts.PREDICATES, "predicates")
    assert meta["predicates"] == {"gripper": ["gripper_static", "gripper_increase", "gripper_decrease"]}
    rich = repo_root / "examples" / "fetch-rich.binarize.toml"
    result = runner.invoke(app, ["binarize", "-w", str(tmp_path), "--spec", str(rich)])
    assert result.exit_code == 0, result.output
    predicates, meta = artifacts.read_table(tmp_path / artifacts.PREDICATES, "predicates")
    assert meta["spec"]["path"] == str(rich) and "object_to_goal" in meta["predicates"]
    for columns in meta["predicates"].values():
        assert predicates.select(pl.sum_horizontal(columns) == 1).to_series().all()
