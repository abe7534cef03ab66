"""Hostile lines in a live stream: each is named on one error line and skipped, the frames around it answered;
every answer is valid JSON. Frames are the DESK test recording, the model a real DESK lstm."""

from __future__ import annotations

import io
import json
from pathlib import Path

import polars as pl
import pytest

from mlnseq import export
from mlnseq import stream as stage

FEATURES = ("arm_distance", "left_gripper", "right_gripper")


@pytest.fixture(scope="module")
def model(tmp_path_factory, desk_full_workdir) -> Path:
    return export.run(desk_full_workdir, export.ExportOptions(
        method="lstm", output=tmp_path_factory.mktemp("stream-model") / "lstm.mlnseq")).path


@pytest.fixture(scope="module")
def frames(desk_test_recording) -> list[dict]:
    return pl.read_csv(desk_test_recording).head(6).select(FEATURES).to_dicts()


def run(model: Path, lines: list[str]) -> tuple[list[dict], list[str]]:
    """The stream's answers (each parsed as strict JSON) and its error lines."""
    emitted, warned = [], []
    stage.run(stage.StreamOptions(model=model), io.BytesIO(("\n".join(lines) + "\n").encode()), emitted.append,
              warned.append)
    def strict(text: str) -> dict:
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"not JSON: {c} in {text}"))
    return [strict(line) for line in emitted], [w for w in warned if w.startswith("error:")]


def as_json(frame: dict, **extra) -> str:
    return json.dumps({**frame, **extra})


@pytest.mark.parametrize("hostile, needle", [
    ('{"arm_distance": 1' + "0" * 400 + ', "left_gripper": 0.5, "right_gripper": 0.5}', "line 2"),
    ("[" * 200_000 + "]" * 200_000, "line 2: not JSON (nested too deep)"),
    ('{"x": ' + "[" * 200_000 + "]" * 200_000 + "}", "line 2: not JSON (nested too deep)"),
], ids=["400-digit integer", "nested 200,000 deep", "object nested 200,000 deep"])
def test_a_hostile_json_line_is_named_and_skipped(model, frames, hostile, needle):
    answers, errors = run(model, [as_json(frames[0]), hostile, as_json(frames[1])])
    assert len(answers) == 2 and len(errors) == 1 and needle in errors[0], errors


def test_a_csv_field_over_128_kib_is_named_and_skipped(model, frames):
    rows = [",".join(FEATURES), *(",".join(str(f[n]) for n in FEATURES) for f in frames[:2])]
    answers, errors = run(model, [rows[0], rows[1], "1" * 200_000 + ",0.5,0.5", rows[2]])
    assert len(answers) == 2 and len(errors) == 1 and errors[0].startswith("error: line 3: not a CSV row"), errors


def test_a_log_banner_before_json_lines_does_not_make_them_csv_and_is_one_error_line(model, frames):
    answers, errors = run(model, ["robot feed v2.1 starting (2026-12-01 20:00:00)", *(as_json(f) for f in frames)])
    assert len(answers) == len(frames)
    assert errors == ["error: line 1: not JSON (text before the first JSON frame); skipped"]


def test_an_episode_of_nan_is_a_bad_line_not_an_answer_that_is_not_json(model, frames):
    lines = [as_json(frames[0], episode=1), '{"episode": NaN, "arm_distance": 0.1, "left_gripper": 0.5, '
             '"right_gripper": 0.5}', '{"episode": Infinity, "arm_distance": 0.1, "left_gripper": 0.5, '
             '"right_gripper": 0.5}', as_json(frames[1], episode=1)]
    answers, errors = run(model, lines)
    assert [a["episode"] for a in answers] == [1, 1] and [a["frame"] for a in answers] == [0, 1]
    assert len(errors) == 2 and "line 2: episode nan is not an id" in errors[0], errors
