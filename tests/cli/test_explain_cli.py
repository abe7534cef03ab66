"""`mlnseq explain`, `predict --explain` and `stream --explain` on a DESK model built like the reproduction's
desk-temporal (the paper's predicates, examples/temporal.mln learned, PriorLayer trained in stream mode): the formulas
are printed as the model's formulas write them, with the user's line; their contributions are the hand computation
from the weights table and the frame's predicates; the stream gives the frames' explanations predict gives."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq import export
from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.recognition.recognizer import Recognizer
from mlnseq_cli.main import app

runner = CliRunner()
REPO = Path(__file__).resolve().parents[2]
FRAME = 5_000  # a frame of the DESK test recording
HAS = re.compile(r'^Has\("(?P<word>[^"]+)",p\) => Topic\("(?P<class>[^"]+)",p\)$')


@pytest.fixture(scope="module")
def model(tmp_path_factory, desk_stream_workdir) -> Path:
    options = export.ExportOptions(method="combined", decode="filter",
                                   output=tmp_path_factory.mktemp("explain") / "combined+filter.mlnseq")
    return export.run(desk_stream_workdir, options).path


def explained(*args: str) -> list[dict]:
    done = runner.invoke(app, ["explain", *args, "--json"])
    assert done.exit_code == 0, done.output
    return [json.loads(line) for line in done.stdout.splitlines()]


def test_each_formula_as_written_and_its_contribution_by_hand(model, desk_stream_workdir, desk_test_recording):
    [found] = explained(str(model), "--source", str(desk_test_recording), "--frame", str(FRAME))
    weights = pl.read_parquet(desk_stream_workdir / artifacts.WEIGHTS)
    weight = {(row["formula"]): row["weight"] for row in weights.iter_rows(named=True)}
    predicates = pl.read_parquet(desk_stream_workdir / artifacts.PREDICATES).filter(pl.col("split") == "test")
    true_words = [w for w in artifacts.feature_columns(predicates) if predicates[w][FRAME]]
    a, b = found["class"], found["versus"]
    by_hand = {}  # Has(w) => Topic(c): weight x Has(w) x ([c is a] - [c is b]), for the words true at the frame
    for word in true_words:
        for klass, sign in ((a, 1.0), (b, -1.0)):
            text = f'Has("{word}",p) => Topic("{klass}",p)'
            if weight.get(text, 0.0):
                by_hand[text] = sign * weight[text]
    formulas = {t["text"]: t for t in found["terms"] if t["kind"] == "formula"}
    assert formulas.keys() == by_hand.keys() and len(formulas) >= 4
    template = next(n for n, line in enumerate((REPO / "examples" / "temporal.mln").read_text().splitlines(), 1)
                    if line.startswith("0.0 Has(+w, p)"))
    for text, term in formulas.items():
        assert abs(term["contribution"] - by_hand[text]) < 1e-9
        assert term["text"] in weight and term["line"] == template
        assert term["written"] == "0.0 Has(+w, p) => Topic(+c, p)"
        assert Path(term["file"]).name == "temporal.mln" and HAS.match(text)
    per_word = {}
    for text, value in by_hand.items():
        per_word[HAS.match(text)["word"]] = per_word.get(HAS.match(text)["word"], 0.0) + value
    for word, value in per_word.items():  # each predicate's contribution, summed over its formulas
        assert abs(sum(t["contribution"] for x, t in formulas.items() if HAS.match(x)["word"] == word) - value) < 1e-9
    assert abs(sum(t["contribution"] for t in found["terms"] if t["contribution"] is not None) - found["margin"]) < 1e-6
    assert {t["kind"] for t in found["terms"]} >= {"formula", "network", "past"}


def test_the_table_prints_each_formula_as_written_within_80_columns(model, desk_test_recording):
    done = runner.invoke(app, ["explain", str(model), "--source", str(desk_test_recording), "--frame", str(FRAME)])
    assert done.exit_code == 0, done.output
    assert max(len(line) for line in done.stdout.splitlines()) <= 80
    flat = " ".join(done.stdout.split())
    [found] = explained(str(model), "--source", str(desk_test_recording), "--frame", str(FRAME))
    for term in found["terms"]:
        if term["kind"] == "formula" and abs(term["contribution"]) > 0.01 * abs(found["margin"]):
            assert " ".join(term["text"].split()) in flat
    assert "the margin" in flat and f"{found['margin']:+.3f}" in flat


def test_what_if_scores_the_frame_again_and_segments_say_what_held_and_ended_them(model, desk_test_recording):
    source = ["--source", str(desk_test_recording)]
    first, again = explained(str(model), *source, "--frame", str(FRAME), "--what-if", "left_gripper=closed")
    assert again["what_if"] == "left_gripper=closed" and again["flips"] == (again["class"] != first["class"])
    assert abs(sum(t["contribution"] for t in again["terms"] if t["contribution"] is not None) - again["margin"]) < 1e-6
    assert any('Has("left_gripper_closed",p)' in t["text"] for t in again["terms"])
    [segment] = explained(str(model), *source, "--segment", "2")
    assert segment["segment"] == 2 and segment["held_by"] and segment["ended_by"]["versus"] == segment["class"]
    assert segment["ended_by"]["frame"] == segment["last_frame"] + 1


def test_predict_and_stream_give_the_same_explanations(model, desk_test_recording, tmp_path):
    head = tmp_path / "head.csv"
    head.write_text("".join(desk_test_recording.read_text().splitlines(keepends=True)[:401]))
    out, spans = tmp_path / "p.parquet", tmp_path / "i.csv"
    done = runner.invoke(app, ["predict", str(model), "--source", str(head), "-o", str(out), "--explain", "3",
                               "--intervals", str(spans)])
    assert done.exit_code == 0, done.output
    table = pl.read_parquet(out)
    why = [json.loads(text) for text in table["why"]]
    assert all(len(terms) == 3 for terms in why)
    intervals = pl.read_csv(spans)
    assert intervals.columns == ["episode", "start", "end", "label", "why"]
    assert intervals["why"].str.contains("held by").all()
    rr = pytest.importorskip("rerun", reason="the [recordings] extra is not installed")
    recording = tmp_path / "view.rrd"
    done = runner.invoke(app, ["predict", str(model), "--source", str(head), "-o", str(tmp_path / "q.parquet"),
                               "--explain", "2", "--rerun", str(recording)])
    assert done.exit_code == 0, done.output
    logged = sum(chunk.num_rows for chunk in rr.chunk.RrdReader(recording).stream()
                 if chunk.entity_path.endswith("/why"))
    assert logged == intervals.height  # one text log entry per segment
    features = pl.read_csv(head).drop("frame", "label").write_csv()
    streamed = runner.invoke(app, ["stream", str(model), "--explain", "3"], input=features)
    assert streamed.exit_code == 0, streamed.output
    lines = [json.loads(line) for line in streamed.stdout.splitlines()]
    assert len(lines) == table.height
    for line, terms in zip(lines, why):
        assert [t["text"] for t in line["why"]] == [t["text"] for t in terms]
        assert np.allclose([t["contribution"] for t in line["why"]], [t["contribution"] for t in terms], atol=2e-6)
    assert "why" not in json.loads(runner.invoke(app, ["stream", str(model)], input=features).stdout.splitlines()[0])
    as_json = "\n".join(json.dumps(row) for row in pl.read_csv(head).drop("frame", "label").to_dicts()) + "\n"
    streamed = runner.invoke(app, ["stream", str(model), "--explain", "3"], input=as_json)  # JSON lines: the same
    assert [json.loads(line)["why"] for line in streamed.stdout.splitlines()] == [line["why"] for line in lines]


def test_the_python_api_explains_a_row_a_recording_or_a_frame(model, desk_test_recording):
    recognizer = Recognizer.load(model)
    features = pl.read_csv(desk_test_recording).select(recognizer.features).to_numpy()[:300]
    with pytest.raises(BadInput, match="call predict first"):
        recognizer.explain(3)
    _, predicted = recognizer.predict(features)
    found = recognizer.explain(250, versus=recognizer.classes[0] if predicted[250] else recognizer.classes[1])
    assert found.chosen == recognizer.classes[predicted[250]] and abs(found.total() - found.margin) < 1e-6
    every = recognizer.explain(features)
    assert [e.chosen for e in every] == [recognizer.classes[k] for k in predicted]
    alone = recognizer.explain(dict(zip(recognizer.features, features[0])))
    assert alone.frame == 0 and any(t.kind == "start" for t in alone.terms)
    for decode in ("smooth-legal@5", "lagviterbi@3", "posterior", "viterbi"):  # the class explained is predict's
        _, predicted = recognizer.predict(features, decode=decode)
        every = recognizer.explain(features, decode=decode)
        assert [e.chosen for e in every] == [recognizer.classes[k] for k in predicted]
        assert all(abs(e.total() - e.margin) < 1e-6 for e in every if e.margin is not None)
        assert any(t.kind == "future" for t in every[0].terms)


def test_a_lagged_stream_explains_each_frame_when_it_decides_it_as_a_whole_recording_does(model, desk_test_recording):
    from mlnseq.model import model_file

    entries = model_file.read_model(model)
    manifest = json.loads(entries.pop("manifest.json"))
    manifest.update(decode="smooth-legal", lag=3, latency_s=None)
    for key in ("members", "format"):
        manifest.pop(key)
    recognizer = Recognizer(model_file.seal(manifest, entries))
    features = pl.read_csv(desk_test_recording).select(recognizer.features).to_numpy()[:400]
    whole = recognizer.explain(features)
    recognizer.reset()
    recognizer.explain_steps(4)
    decided = []
    for start in range(0, len(features), 7):  # frames read together, decided together
        for frame in features[start:start + 7]:
            recognizer.step(frame, decide=False)
        decided += recognizer.decide()
    decided += recognizer.finish()
    assert [p.frame for p in decided] == list(range(len(features)))
    for prediction, found in zip(decided, whole):
        assert prediction.name == found.chosen
        assert [t["text"] for t in prediction.why] == [t.text for t in found.largest(4)]
        assert np.allclose([t["contribution"] or 0.0 for t in prediction.why],
                           [t.contribution or 0.0 for t in found.largest(4)], atol=2e-6)  # a hard rule's: None
    assert any(t.kind == "future" for t in whole[100].terms)


@pytest.mark.parametrize(("args", "needle"), [
    (["--frame", "1", "--time", "2"], "give one of --frame T, --time S or --segment K, not --frame and --time"),
    ([], "give one of --frame T, --time S or --segment K"),
    (["--frame", "99999999"], "--frame 99999999: the episode's frames are 0-20923"),
    (["--time", "20924"], "--time 20924: outside the episode (its times run 0-20923); give a time within it"),
    (["--time", "-1"], "--time -1: outside the episode (its times run 0-20923)"),
    (["--segment", "99999"], "--segment 99999: episode desk-test has"),
    (["--frame", "3", "--versus", "S9"], "--versus 'S9' is not a class of the model"),
    (["--frame", "3", "--what-if", "left_gripper=shut"], "left_gripper is one of open, closed"),
    (["--frame", "3", "--what-if", "nothing"], "write PREDICATE=VALUE"),
    (["--frame", "3", "--episode", "other"], "--episode 'other': the recording's episodes are desk-test"),
])
def test_bad_usage_is_one_line_and_exit_2(model, desk_test_recording, args, needle):
    done = runner.invoke(app, ["explain", str(model), "--source", str(desk_test_recording), *args])
    assert done.exit_code == 2, done.output
    assert done.stderr.strip().count("\n") == 0 and needle in done.stderr
