"""Tables and collect options a user gets wrong, through the real CLI: each is one error line, exit 2, no
workdir written; never a silent wrap, a silent simulation or a MemoryError. Features are the real DESK
motion channels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app

runner = CliRunner()


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


@pytest.fixture(scope="module")
def motion(shared_data) -> np.ndarray:
    return np.loadtxt(shared_data / "desk-taurus" / "taurus_motion_train.txt")


def refused(*args, needles: tuple[str, ...] = ()) -> str:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, (args, result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def table(motion: np.ndarray, labels, path: Path) -> Path:
    n = len(labels)
    rows = np.arange(n) % len(motion)  # the recording repeated as often as the labels need
    pl.DataFrame({"frame": np.arange(n), "label": labels, "arm_distance": motion[rows, 0],
                  "left_gripper": motion[rows, 1]}).write_csv(path)
    return path


def test_more_text_classes_than_int16_holds_are_refused_not_wrapped(motion, tmp_path):
    source = table(motion, [f"class_{k:05d}" for k in range(40_000)], tmp_path / "many.csv")
    refused("collect", "--env", "table", "--source", source, "-w", tmp_path / "work",
            needles=("many.csv", "40,000 classes", "at most 32,768"))
    assert not (tmp_path / "work" / "frames.parquet").exists()


@pytest.mark.parametrize("huge", [40_000, 2_000_000_000])
def test_a_numeric_label_past_int16_is_refused_before_naming_its_classes(motion, tmp_path, huge):
    labels = [0, 1] * 500
    labels[700] = huge
    source = table(motion, labels, tmp_path / "huge.csv")
    refused("collect", "--env", "table", "--source", source, "-w", tmp_path / "work",
            needles=("huge.csv:702", f"label {huge}", "below 32,768"))


def test_source_without_env_is_refused_rather_than_simulating_fetch(motion, tmp_path):
    source = table(motion, [0, 1] * 50, tmp_path / "mine.csv")
    refused("collect", "--source", source, "-w", tmp_path / "work", needles=("--source", "--env table", "fetch"))
    assert not (tmp_path / "work").exists()


def test_a_project_file_nested_fifty_thousand_deep_is_one_line_naming_it(tmp_path):
    config = tmp_path / "mlnseq.toml"
    config.write_text("[collect]\nepisodes = " + "[" * 50_000 + "]" * 50_000 + "\n")
    refused("--config", config, "collect", "-w", tmp_path / "work", needles=("mlnseq.toml", "nested too deep"))
