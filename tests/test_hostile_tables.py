"""Tables and collect options a user gets wrong, through the real CLI: each is one error line, exit 2, no
workdir written; never a silent wrap, a silent simulation or a MemoryError. Features are the real DESK
motion channels."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from refusals import refused

runner = CliRunner()


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


@pytest.fixture(scope="module")
def motion(shared_data) -> np.ndarray:
    return np.loadtxt(shared_data / "desk-taurus" / "taurus_motion_train.txt")


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


def motion_table(motion: np.ndarray, rows: slice) -> pl.DataFrame:
    part = motion[rows]
    return pl.DataFrame({"frame": np.arange(len(part)), "arm_distance": part[:, 0], "left_gripper": part[:, 1],
                         "right_gripper": part[:, 2]})


def halves_labels(path: Path, ids: list[str], n: int) -> Path:
    path.write_text("episode,start,end,label\n" + "".join(f"{e},0,{n // 2 - 1},reach\n{e},{n // 2},{n - 1},lift\n"
                                                            for e in ids))
    return path


def test_episode_ids_with_leading_zeros_match_the_labels_as_written(motion, tmp_path):
    folder = tmp_path / "trials"
    folder.mkdir()
    for k, name in enumerate(("001", "002", "010")):
        motion_table(motion, slice(k * 200, k * 200 + 200)).write_csv(folder / f"{name}.csv")
    labels = halves_labels(tmp_path / "labels.csv", ["001", "002", "010"], 200)
    result = runner.invoke(app, ["collect", "--env", "table", "--source", str(folder), "--labels", str(labels),
                                 "-w", str(tmp_path / "work")])
    assert result.exit_code == 0, result.output
    meta = json.loads(pq.read_schema(tmp_path / "work" / "frames.parquet").metadata[b"mlnseq"])
    assert meta["episode_names"] == ["001", "002", "010"]


def test_a_numeric_episode_column_still_matches_labels_written_with_leading_zeros(motion, tmp_path):
    table = pl.concat([motion_table(motion, slice(k * 200, k * 200 + 200)).with_columns(trial=pl.lit(k + 1))
                       for k in range(2)])
    table.write_csv(tmp_path / "trials.csv")
    labels = halves_labels(tmp_path / "labels.csv", ["001", "002"], 200)
    result = runner.invoke(app, ["collect", "--env", "table", "--source", str(tmp_path / "trials.csv"),
                                 "--episode-column", "trial", "--labels", str(labels), "-w", str(tmp_path / "work")])
    assert result.exit_code == 0, result.output


def test_an_empty_column_is_left_out_with_a_note(motion, tmp_path):
    source = tmp_path / "t.csv"
    table = motion_table(motion, slice(0, 200)).with_columns(label=pl.Series([0, 1] * 100), torque=pl.lit(None))
    table.write_csv(source)
    result = runner.invoke(app, ["collect", "--env", "table", "--source", str(source), "-w", str(tmp_path / "work")])
    assert result.exit_code == 0, result.output
    assert "note: columns without a value left out: torque" in result.output


def test_a_latin1_csv_is_refused_not_read_as_mojibake(motion, tmp_path):
    source = tmp_path / "latin1.csv"
    text = motion_table(motion, slice(0, 100)).with_columns(label=pl.Series([0, 1] * 50)).write_csv()
    source.write_bytes(text.replace("left_gripper", "pince_gauche_ferm\u00e9e", 1).encode("latin-1"))
    refused("collect", "--env", "table", "--source", source, "-w", tmp_path / "work",
            needles=("latin1.csv:1: not UTF-8 text (byte 0xe9)", "iconv"))
