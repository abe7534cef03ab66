"""A live model with a lag, end to end on DESK: conflate scores lagged decoders, export picks one within a budget,
and stream, predict and the Python API give conflate's classes, frame t once frame t + lag has arrived."""

from __future__ import annotations

import dataclasses
import io
import json
import shutil
import zipfile

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq import conflate, export, predict, stream
from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.recognition.recognizer import Recognizer
from mlnseq_cli.main import app

from choice_rule import expected_choice  # tests/choice_rule.py

LAGS = (0, 3)
FRAMES = 1500  # of the test recording


@pytest.fixture(scope="module")
def live_workdir(tmp_path_factory, desk_folds_workdir):
    """desk_folds_workdir conflated again with lagged and legal decoders at LAGS."""
    workdir = tmp_path_factory.mktemp("desk-live")
    for path in desk_folds_workdir.iterdir():
        (shutil.copytree if path.is_dir() else shutil.copy)(path, workdir / path.name)
    conflate.run(workdir, conflate.ConflateOptions(decode=("filter", "smooth", "smooth-legal", "posterior"), lags=LAGS))
    return workdir


@pytest.fixture(scope="module")
def recording(tmp_path_factory, live_workdir):
    frames = pl.read_parquet(live_workdir / "frames.parquet").filter(pl.col("split") == "test").head(FRAMES)
    path = tmp_path_factory.mktemp("recording") / "desk-test.csv"
    frames.select("frame", "label", "arm_distance", "left_gripper", "right_gripper").write_csv(path)
    return path, frames


@pytest.fixture(scope="module")
def lagged_model(tmp_path_factory, live_workdir):
    path = tmp_path_factory.mktemp("model") / "live.mlnseq"
    options = export.ExportOptions(method="conflation", decode="smooth-legal", lag=3, output=path)
    return export.run(live_workdir, options)


def test_conflate_scores_every_decoder_at_every_lag_with_forbidden_transitions(live_workdir):
    meta = artifacts.read_metadata(live_workdir / artifacts.PREDICTIONS, "predictions")
    figures = meta["cross_validation"]["figures"]
    for name in ("conflation+filter", "conflation+smooth@3", "conflation+smooth-legal@3", "mln+posterior"):
        assert name in meta["methods"] and name in figures and figures[name]["log_likelihood"] < 0
    # no hard rule in these formulas: no transition is forbidden, so every decoded method counts 0 on the folds and
    # on test; an undecoded method has no chain to break (no count)
    assert meta["hard_rules"] is False and set(meta["forbidden_transitions"]) == {m for m in meta["methods"] if "+" in m}
    assert {name: f.get("forbidden_transitions") for name, f in figures.items()} == {
        name: (0 if "+" in name else None) for name in figures}
    assert set(meta["forbidden_transitions"].values()) == {0}
    # lag 0 smoothing is the filter (and its legal form filter-legal)
    assert "conflation+smooth@0" not in meta["methods"] and "conflation+smooth-legal@0" not in meta["methods"]
    assert len(meta["start"]) == len(meta["classes"]) and meta["lags"] == list(LAGS)
    table = pl.read_parquet(live_workdir / artifacts.PREDICTIONS)
    assert "conflation+smooth@3_pred" in table.columns and "conflation+smooth@3_p0" not in table.columns


def test_auto_chooses_within_the_budget_and_refuses_what_cannot_fit(live_workdir, tmp_path):
    auto = export.run(live_workdir, export.ExportOptions(method="auto", lag=3, output=tmp_path / "auto.mlnseq"))
    chosen = auto.manifest.chosen_by_cross_validation
    assert chosen.budget_frames == 3 and auto.manifest.lag <= 3
    assert all("viterbi" not in name and "posterior" not in name for name in chosen.candidates)
    cross = artifacts.read_metadata(live_workdir / artifacts.PREDICTIONS)["cross_validation"]
    fold_frames = cross["fold_frame_accuracy"]
    assert chosen.name == expected_choice(chosen.candidates, fold_frames)
    assert auto.manifest.latency_s is None or auto.manifest.lag == 0  # DESK's frame rate is unknown
    for options, needle in (
        (export.ExportOptions(method="auto", latency=1.0), "frame rate .* not known; give the budget as --lag"),
        (export.ExportOptions(method="auto", decode="smooth", lag=2), r"no cross-validated smooth candidate .* 2 fr"),
        (export.ExportOptions(method="conflation", decode="smooth", lag=5), r"no conflation\+smooth@5 predictions"),
        (export.ExportOptions(method="conflation", decode="lagviterbi", lag=3), r"conflate --decode lagviterbi"),
        (export.ExportOptions(method="conflation", decode="smooth"), "give --lag FRAMES"),
        (export.ExportOptions(method="auto", lag=-1), "at least 0 frames"),
    ):
        with pytest.raises(BadInput, match=needle) as error:
            export.run(live_workdir, options.__class__(**{**options.__dict__, "output": tmp_path / "no.mlnseq"}))
        assert "\n" not in str(error.value)
    assert not (tmp_path / "no.mlnseq").exists()


def test_stream_answers_frame_t_once_t_plus_lag_arrived_as_predict_and_conflate(lagged_model, recording, live_workdir):
    path, frames = recording
    assert lagged_model.manifest.lag == 3 and lagged_model.manifest.decode == "smooth-legal"
    lines: list[str] = []
    text = "frame,time,arm_distance,left_gripper,right_gripper\n" + "".join(
        f"{row['frame']},{0.5 * i},{row['arm_distance']},{row['left_gripper']},{row['right_gripper']}\n"
        for i, row in enumerate(frames.iter_rows(named=True)))
    summary = stream.run(stream.StreamOptions(model=lagged_model.path), io.BytesIO(text.encode()), lines.append,
                         lambda _: None)
    answers = [json.loads(line) for line in lines]
    assert summary.frames == FRAMES and [a["frame"] for a in answers] == list(range(FRAMES))
    assert answers[10]["time"] == 5.0 and {a["lag"] for a in answers} == {3}
    predicted = predict.run(predict.PredictOptions(model=lagged_model.path, source=path,
                                                   output=path.parent / "p.parquet", force=True))
    assert [a["class"] for a in answers] == predicted.table["class"].to_list()
    stored = pl.read_parquet(live_workdir / "predictions.parquet").filter(pl.col("split") == "test").head(FRAMES)
    classes = np.array(lagged_model.manifest.classes)[stored["conflation+smooth-legal@3_pred"].to_numpy()]
    # conflate decoded the whole test recording: its last 3 frames here saw later frames
    assert (classes[:-3] == np.array(predicted.table["class"].to_list())[:-3]).all()


class Feed(io.RawIOBase):
    """Input handed out ``lines`` lines a read, as a live feed (1) or a backlog does; notes at each read how many
    lines it had handed out and how many answers the stream had emitted by then."""

    def __init__(self, text: str, lines: int, answers: list):
        all_lines = text.splitlines(keepends=True)
        self.pieces = ["".join(all_lines[i:i + lines]).encode() for i in range(0, len(all_lines), lines)]
        self.given, self.answers, self.seen = 0, answers, []

    def readable(self) -> bool:
        return True

    def read1(self, size: int = -1) -> bytes:
        self.seen.append((self.given, len(self.answers)))
        piece = self.pieces.pop(0) if self.pieces else b""
        self.given += piece.count(b"\n")
        return piece


def test_a_stream_answers_frame_t_before_it_waits_for_input_after_t_plus_lag(lagged_model, recording):
    """Frames are decided when the stream has read all it had at hand: a live feed line by line gets frame t's
    answer before the stream waits for the line after t + 3; a backlog of 250 lines a read gets its decisions
    together, the same answers."""
    frames = recording[1].head(300)
    text = frames.select(Recognizer.load(lagged_model.path).features).write_csv()
    got = {}
    for lines in (1, 250):
        answers: list[str] = []
        feed = Feed(text, lines, answers)
        stream.run(stream.StreamOptions(model=lagged_model.path), feed, answers.append, lambda _: None)
        assert len(feed.seen) == 1 + -(-301 // lines) and feed.seen[-1][0] == 301  # a read a piece, and the end
        for given, answered in feed.seen:
            assert answered == max(0, given - 1 - 3)  # every frame with 3 frames after it, before the next read
        assert len(answers) == 300  # the last 3 at the end of the input
        got[lines] = answers
    assert got[1] == got[250]


def test_the_api_says_which_frames_became_final_at_each_step(lagged_model, recording):
    model = Recognizer.load(lagged_model.path)
    frames = recording[1].select(model.features).to_numpy()[:40]
    decided = []
    for t, row in enumerate(frames):
        step = model.step(row)
        assert step.frame == t and [p.frame for p in step.final] == ([t - 3] if t >= 3 else [])
        decided += step.final
    rest = model.finish()
    assert [p.frame for p in rest] == [37, 38, 39]
    batch = model.predict(frames)[1]
    assert [p.label for p in decided + rest] == batch.tolist()
    model.reset()
    held = [model.step(row, decide=False).final for row in frames[:30]]
    assert held == [()] * 30
    together = model.decide()
    assert [p.frame for p in together] == list(range(27)) and model.decide() == ()
    assert [p.label for p in together] == batch.tolist()[:27]
    for p, q in zip(together, decided):
        np.testing.assert_array_equal(p.probabilities, q.probabilities)


def test_a_malformed_lag_or_decoder_is_refused_on_load(lagged_model, tmp_path):
    for change, needle in (({"lag": -2}, "lag must be a whole number"), ({"lag": "x"}, "lag 'x'"),
                           ({"decode": "blur"}, "decoder 'blur'"), ({"lag": None}, "lag must be"),
                           ({"start": [0.0]}, "start is not a list of 7"), ({"latency_s": -1}, "latency_s -1")):
        broken = tmp_path / "broken.mlnseq"
        with zipfile.ZipFile(lagged_model.path) as source, zipfile.ZipFile(broken, "w") as target:
            for name in source.namelist():
                data = source.read(name)
                if name == "manifest.json":
                    data = json.dumps({**json.loads(data), **change}).encode()
                target.writestr(name, data)
        with pytest.raises(BadInput, match=needle) as error:
            Recognizer.load(broken)
        assert "\n" not in str(error.value) and str(broken) in str(error.value)


def test_a_model_file_without_the_lag_keys_decodes_as_before(lagged_model, recording, tmp_path):
    """A format-3 file written before the lag (no lag, latency_s, rate_hz, start): its filter, lag 0."""
    older = tmp_path / "older.mlnseq"
    with zipfile.ZipFile(lagged_model.path) as source, zipfile.ZipFile(older, "w") as target:
        for name in source.namelist():
            data = source.read(name)
            if name == "manifest.json":
                dropped = ("lag", "latency_s", "rate_hz", "start")
                values = {k: v for k, v in json.loads(data).items() if k not in dropped}
                data = json.dumps({**values, "decode": "filter"}).encode()
            target.writestr(name, data)
    model = Recognizer.load(older)
    assert model.decoding.name == "filter" and model.lag == 0 and model.start is None
    assert model.manifest.lag == 0 and model.manifest.start is None and model.manifest.rate_hz is None
    rows = recording[1].select(model.features).to_numpy()[:20]
    steps = [model.step(row) for row in rows]
    assert all([p.frame for p in s.final] == [s.frame] for s in steps) and model.finish() == []
    assert [s.label for s in steps] == model.predict(rows)[1].tolist()


def test_latency_without_a_rate_is_one_line_exit_2_nothing_written(live_workdir, tmp_path):
    output = tmp_path / "m.mlnseq"
    result = CliRunner().invoke(app, ["export", "--method", "auto", "--latency", "1", "-o", str(output),
                                      "-w", str(live_workdir)])
    assert result.exit_code == 2, result.output
    assert "give the budget as --lag FRAMES" in result.output and not output.exists()


def test_the_ros_live_recogniser_answers_a_frame_once_final_with_its_lag(lagged_model, recording):
    """The ROS path (messages on the model's clock, as `mlnseq ros` and `rostopic echo -p` feed it) with lag 3:
    a tick's frame is answered once 3 later ticks have been stepped, with its own tick time, the rest when the
    feed ends; the classes are the batch's over the same frames."""
    from mlnseq.recognition import live

    model = Recognizer.load(lagged_model.path)
    names = list(model.features)
    model.manifest = dataclasses.replace(model.manifest, reading={"env": "rosbag", "topics": ["/desk"], "rate": 10.0})
    model.features = [f"/desk/{name}" for name in names]  # the topic's fields, as a bag's frames name them
    rows = recording[1].select(names).to_numpy()[:40]
    feed = live.LiveRecognizer(model, lambda _: None)
    answered = []
    for k, row in enumerate(rows):  # a message every 100 ms: it closes the tick of the message before
        answered += feed.message("/desk", 10**9 + k * 10**8, dict(zip(model.features, row.tolist())))
        assert [a.prediction.frame for a in answered] == list(range(max(0, k - 3)))  # ticks 0..k-1 stepped
    answered += feed.finish()
    assert [a.prediction.frame for a in answered] == list(range(40)) and {a.lag for a in answered} == {3}
    assert [a.time for a in answered] == [10**9 + k * 10**8 for k in range(40)]
    assert answered[0].record(model.classes)["lag"] == 3
    batch = Recognizer.load(lagged_model.path).predict(rows)[1]
    assert [a.prediction.label for a in answered] == batch.tolist()


@pytest.mark.parametrize("signum, code", [("SIGTERM", 143), ("SIGINT", 130)])
def test_a_signal_decides_and_writes_every_frame_the_stream_holds_then_exits_with_its_code(lagged_model, recording,
                                                                                           tmp_path, signum, code):
    """200 frames in, the stdin left open: 197 are answered (each has 3 after it), the stream waits; then SIGTERM or
    SIGINT: the 3 frames it holds are decided and written as at the end of the input, and it exits 143 or 130."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    frames = recording[1].head(200)
    text = frames.select(Recognizer.load(lagged_model.path).features).write_csv()
    source = tmp_path / "head.csv"
    source.write_text(text)
    process = subprocess.Popen([str(Path(sys.executable).parent / "mlnseq"), "stream", str(lagged_model.path)],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        process.stdin.write(text)
        process.stdin.flush()
        answers = [json.loads(process.stdout.readline()) for _ in range(197)]
        process.send_signal(getattr(signal, signum))
        out, err = process.communicate(timeout=60)
    finally:
        process.kill()
    answers += [json.loads(line) for line in out.splitlines()]
    assert process.returncode == code, err
    assert [a["frame"] for a in answers] == list(range(200))
    predicted = predict.run(predict.PredictOptions(model=lagged_model.path, source=source, output=tmp_path / "p.parquet"))
    assert [a["class"] for a in answers] == predicted.table["class"].to_list()
    assert err.strip().splitlines()[-1].endswith("every frame read so far was answered")
