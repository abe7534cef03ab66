"""`mlnseq stream` as a real subprocess with pipes (combined+filter): each frame answered at once, equal to
`predict` frame by frame; bad lines said with their number and skipped (or fatal with --strict); Ctrl-C
answers what it read."""

from __future__ import annotations

import io
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts
from mlnseq import export, predict
from mlnseq import stream as stage
from mlnseq.recognition.reading import ReadOptions

MLNSEQ = str(Path(sys.executable).parent / "mlnseq")
FRAMES = 2000  # of the DESK test recording, through the pipe
TIMEOUT_S = 120


@pytest.fixture(scope="module")
def model(tmp_path_factory, desk_stream_workdir) -> Path:
    return export.run(desk_stream_workdir, export.ExportOptions(
        method="combined", decode="filter", output=tmp_path_factory.mktemp("model") / "combined+filter.mlnseq")).path


@pytest.fixture(scope="module")
def recording(tmp_path_factory, desk_test_recording) -> Path:
    path = tmp_path_factory.mktemp("stream") / "head.csv"
    pl.read_csv(desk_test_recording).head(FRAMES).write_csv(path)
    return path


def stream(model: Path, text: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([MLNSEQ, "stream", str(model), *args], input=text, capture_output=True, text=True,
                          timeout=TIMEOUT_S)


def test_a_csv_stream_equals_predict_frame_by_frame(model, recording, tmp_path):
    done = stream(model, recording.read_text())
    assert done.returncode == 0, done.stderr
    answers = [json.loads(line) for line in done.stdout.splitlines()]
    expected = predict.run(predict.PredictOptions(model=model, source=recording, output=tmp_path / "p.parquet")).table
    assert len(answers) == FRAMES == expected.height
    assert [a["class"] for a in answers] == expected["class"].to_list()
    assert [a["frame"] for a in answers] == list(range(FRAMES)) and {a["episode"] for a in answers} == {0}
    classes = list(answers[0]["probabilities"])
    got = np.array([[a["probabilities"][c] for c in classes] for a in answers])
    np.testing.assert_allclose(got, expected.select(artifacts.class_probability_column(c) for c in classes).to_numpy(), atol=1e-5)
    assert "keys the model does not use are ignored: frame, label" in done.stderr


def test_json_lines_with_episodes_and_bad_lines_go_on(model, recording):
    rows = pl.read_csv(recording).head(6).to_dicts()
    lines = [json.dumps({**rows[0], "episode": "a"}), "not json", json.dumps({**rows[1], "episode": "a"}),
             json.dumps({"episode": "a", "arm_distance": 1.0}), '{"episode": "a", "arm_distance": NaN, '
             '"left_gripper": 1, "right_gripper": 1}', json.dumps({**rows[2], "arm_distance": "far", "episode": "a"}),
             json.dumps({**rows[0], "episode": "b"}), "[1, 2]", json.dumps({**rows[1], "episode": "b"})]
    done = stream(model, "\n".join(lines) + "\n")
    assert done.returncode == 0, done.stderr
    answers = [json.loads(line) for line in done.stdout.splitlines()]
    assert [(a["episode"], a["frame"]) for a in answers] == [("a", 0), ("a", 1), ("b", 0), ("b", 1)]
    assert answers[2]["probabilities"] == answers[0]["probabilities"]  # b restarts as a did
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert [e.split(":")[1].strip() for e in errors] == ["line 2", "line 4", "line 5", "line 6", "line 8"]
    assert "missing feature 'left_gripper', 'right_gripper'" in errors[1] and "is nan" in errors[2]
    assert "'far', not a number" in errors[3] and "not JSON" in errors[0]


def test_strict_stops_at_the_first_bad_line(model, recording):
    text = recording.read_text().splitlines()
    done = stream(model, "\n".join([*text[:4], "1,2,oops,0.5,0.5", *text[4:8]]) + "\n", "--strict")
    assert done.returncode == 2
    assert len(done.stdout.splitlines()) == 3
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "line 5" in errors[0] and "'arm_distance' is 'oops'" in errors[0]


def test_each_frame_is_answered_before_the_next_is_read_and_ctrl_c_exits_130(model, recording):
    lines = recording.read_text().splitlines()
    process = subprocess.Popen([MLNSEQ, "stream", str(model)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, bufsize=1)
    try:
        process.stdin.write(lines[0] + "\n")
        for line in lines[1:51]:
            process.stdin.write(line + "\n")
            process.stdin.flush()
            assert json.loads(process.stdout.readline())["class"]  # answered while stdin stays open
        time.sleep(0.5)
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=TIMEOUT_S)
    finally:
        process.kill()
    assert process.returncode == 130, err
    assert out == "" and "interrupted; every frame read so far was answered" in err


def test_a_truncated_model_file_is_one_line_and_exit_2(model, tmp_path):
    broken = tmp_path / "broken.mlnseq"
    broken.write_bytes(model.read_bytes()[:500])
    done = stream(broken, "")
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and "not an mlnseq model file" in done.stderr


class Trickle(io.RawIOBase):
    """A pipe that hands out at most ``size`` bytes per read, as a slow feed does."""

    def __init__(self, data: bytes, size: int):
        self.data, self.size = data, size

    def readable(self) -> bool:
        return True

    def read1(self, n: int = -1) -> bytes:
        piece, self.data = self.data[: min(n, self.size)], self.data[min(n, self.size):]
        return piece


@pytest.mark.parametrize("size", [1, 3, 7, 64, 2**16])
def test_lines_are_cut_the_same_whatever_the_chunks(size):
    text = b"a,b\r\n\n1,2\n" + b"x" * 40 + b"\n" + "é,ü\n".encode() + b"\xff\n" + b"y" * 41 + b"\nlast"
    got = [str(line) if isinstance(line, stage.InputLine) else line for line in stage.lines_of(Trickle(text, size), 40)]
    assert got == ["a,b", "", "1,2", "x" * 40, "é,ü",
                   "line 6: not UTF-8 text ('utf-8' codec can't decode byte 0xff in position 0: invalid start byte)",
                   "line 7: 41 bytes, over --max-line-bytes 40 (raise it to read such lines); skipped", "last"]


def test_a_line_over_the_limit_is_named_and_skipped_and_the_stream_goes_on(model, recording):
    rows = pl.read_csv(recording).head(3).to_dicts()
    long = json.dumps({**rows[1], "padding": " " * 2**21})
    done = stream(model, "\r\n".join([json.dumps(rows[0]), long, json.dumps(rows[2])]))  # CRLF, no final newline
    assert done.returncode == 0, done.stderr
    assert [json.loads(line)["frame"] for line in done.stdout.splitlines()] == [0, 1]
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert errors == [f"error: line 2: {len(long) + 1:,} bytes, over --max-line-bytes 1,048,576 (raise it to read such "
                      "lines); skipped"]
    small = stream(model, "\n".join(json.dumps(r) for r in rows) + "\n", "--max-line-bytes", "60")
    assert small.stdout == "" and small.stderr.count("over --max-line-bytes 60 (raise it to read such lines)") == 3


def test_a_feed_without_newlines_is_one_skipped_line_and_strict_stops_at_the_limit(model, recording):
    done = stream(model, " " * 3_000_000)
    assert done.returncode == 0 and done.stdout == ""
    assert ("error: line 1: 3,000,000 bytes, over --max-line-bytes 1,048,576 (raise it to read such lines); skipped"
            in done.stderr)
    rows = pl.read_csv(recording).head(2).to_dicts()
    strict = stream(model, json.dumps(rows[0]) + "\n" + " " * 2**21 + "\n" + json.dumps(rows[1]) + "\n", "--strict")
    assert strict.returncode == 2 and len(strict.stdout.splitlines()) == 1
    assert strict.stderr.strip().splitlines()[-1] == ("error: line 2: over --max-line-bytes 1,048,576 bytes (raise it "
                                                      "to read such lines)")
    assert stream(model, "", "--max-line-bytes", "0").returncode == 2


def test_text_before_json_is_an_error_line_and_a_headerless_csv_says_its_first_row_became_the_header(model, recording):
    rows = pl.read_csv(recording).head(2).to_dicts()
    done = stream(model, "\n".join(["not json at all", *map(json.dumps, rows)]) + "\n")
    assert done.returncode == 0 and len(done.stdout.splitlines()) == 2, done.stderr
    assert done.stderr.splitlines() == ["error: line 1: not JSON (text before the first JSON frame); skipped",
                                        "note: line 2: keys the model does not use are ignored: frame, label"]
    strict = stream(model, "\n".join(["not json at all", *map(json.dumps, rows)]) + "\n", "--strict")
    assert strict.returncode == 2 and strict.stdout == ""
    headerless = stream(model, "\n".join(recording.read_text().splitlines()[1:4]) + "\n")
    first = recording.read_text().splitlines()[1].split(",")
    notes = [line for line in headerless.stderr.splitlines() if line.startswith("note: line 1 was read")]
    assert notes == [f"note: line 1 was read as the CSV header ({', '.join(first[:3])}, ...) "
                     "and names none of the model's features: a CSV stream starts with a header line of feature names "
                     "(arm_distance, left_gripper, right_gripper)"], headerless.stderr


def test_decode_streams_as_predict_decodes(model, recording, tmp_path):
    done = stream(model, recording.read_text(), "--decode", "smooth@3")
    assert done.returncode == 0, done.stderr
    answers = [json.loads(line) for line in done.stdout.splitlines()]
    expected = predict.run(predict.PredictOptions(model=model, source=recording, output=tmp_path / "p.parquet",
                                                  reading=ReadOptions(decode="smooth@3"))).table
    plain = predict.run(predict.PredictOptions(model=model, source=recording, output=tmp_path / "q.parquet")).table
    assert {a["lag"] for a in answers} == {3} and len(answers) == FRAMES
    assert [a["class"] for a in answers] == expected["class"].to_list() != plain["class"].to_list()
    bad = stream(model, "", "--decode", "smooth")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--decode 'smooth'" in bad.stderr


def test_decode_is_one_option_on_predict_stream_and_ros(model, recording):
    """The same --decode on the three commands: the same names, the same refusal of a bad one, before any work."""
    said = set()
    for command in (["predict", str(model), "--source", str(recording)], ["stream", str(model)],
                    ["ros", str(model), "--ros", "1"]):
        done = subprocess.run([MLNSEQ, *command, "--decode", "smooth-legal"], capture_output=True, text=True,
                              timeout=TIMEOUT_S, input="")
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        said.add(done.stderr)
    assert said == {"error: --decode 'smooth-legal': smooth-legal needs a lag in frames, e.g. smooth-legal@5\n"}
