"""The recogniser: a model file exported from a workdir recognises that workdir's test recording as conflate
did, whole or one frame at a time, decoded or not; broken model files and bad frames are refused in one line."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts, methods
from mlnseq import export
from mlnseq.model import model_file
from mlnseq.fusion import decoding
from mlnseq.catalog.errors import BadInput
from mlnseq.recognition.recognizer import Recognizer

STEPPED_FRAMES = 1500  # one frame at a time is checked on the first frames of the 20,924-frame recording


NAMES = methods.method_names()  # lstm ... combined, lstm+filter ... combined+viterbi


@pytest.fixture(scope="module")
def models(tmp_path_factory, desk_stream_workdir) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("models")
    exported = {}
    for name in NAMES:
        method, decode = methods.parse_method(name)
        options = export.ExportOptions(method=method, decode=decode, output=folder / f"{name}.mlnseq")
        exported[name] = export.run(desk_stream_workdir, options).path
    return exported


@pytest.fixture(scope="module")
def desk_test_frames(desk_stream_workdir) -> tuple[pl.DataFrame, pl.DataFrame]:
    frames = pl.read_parquet(desk_stream_workdir / artifacts.FRAMES).filter(pl.col("split") == "test")
    predictions = pl.read_parquet(desk_stream_workdir / artifacts.PREDICTIONS).filter(pl.col("split") == "test")
    return frames, predictions


@pytest.mark.parametrize("method", NAMES)
def test_a_model_file_recognises_the_test_recording_as_conflate_did(models, desk_test_frames, method):
    frames, predictions = desk_test_frames
    model = Recognizer.load(models[method])
    if method.endswith("+viterbi"):  # offline only: a step filters, checked with the +filter model
        probabilities, predicted = model.predict(frames.select(model.features).to_numpy())
        assert (predicted == predictions[artifacts.pred_column(method)].to_numpy()).all()
        np.testing.assert_allclose(probabilities, predictions.select(artifacts.prob_columns(method, 7)), atol=1e-5)
        return
    expected = predictions.select(artifacts.prob_columns(method, 7)).to_numpy().astype(np.float64)
    features = frames.select(model.features).to_numpy()
    probabilities, predicted = model.predict(features)
    np.testing.assert_allclose(probabilities, expected, atol=1e-5)
    assert (predicted == predictions[artifacts.pred_column(method)].to_numpy()).all()
    stepped = [model.step(frame) for frame in features[:STEPPED_FRAMES]]
    np.testing.assert_allclose([s.probabilities for s in stepped], expected[:STEPPED_FRAMES], atol=1e-5)
    assert [s.label for s in stepped] == predicted[:STEPPED_FRAMES].tolist()
    assert stepped[-1].frame == STEPPED_FRAMES - 1 and stepped[0].name == model.classes[stepped[0].label]


def test_reset_starts_a_new_episode_and_frames_may_be_mappings(models, desk_test_frames):
    frames, _ = desk_test_frames
    model = Recognizer.load(models["combined"])
    rows = frames.select(model.features).to_dicts()[:20]
    first = [model.step(row).probabilities for row in rows]
    model.reset()
    again = [model.step({**row, "timestamp": 1.0}).probabilities for row in rows]  # unused keys are ignored
    np.testing.assert_array_equal(first, again)


@pytest.mark.parametrize(("frame", "needle"), [
    ({"arm_distance": 1.0, "left_gripper": 0.5}, "missing feature 'right_gripper'"),
    ({"arm_distance": 1.0, "left_gripper": float("nan"), "right_gripper": 0.5}, "'left_gripper' is nan"),
    ({"arm_distance": "far", "left_gripper": 0.5, "right_gripper": 0.5}, "'arm_distance' is 'far', not a number"),
    ([1.0, 0.5], "3 feature values"),
])
def test_a_bad_frame_is_refused_naming_the_feature(models, frame, needle):
    model = Recognizer.load(models["combined"])
    with pytest.raises(BadInput, match=needle):
        model.step(frame)


def test_every_part_is_in_the_file_and_lstm_alone_carries_no_mln(models):
    with zipfile.ZipFile(models["combined"]) as archive:
        assert set(archive.namelist()) == {"manifest.json", "binarize.toml", "weights.parquet", "network.npz",
                                           "audit.json"}  # what audit checks against (auditing/profile.py)
        manifest = json.loads(archive.read("manifest.json"))
    assert manifest["format"] == model_file.MODEL_FORMAT and manifest["network"]["name"] == "priorlayer"
    assert manifest["features"] == ["arm_distance", "left_gripper", "right_gripper"] and len(manifest["classes"]) == 7
    assert set(manifest["inputs"]) == {"frames.parquet", "priorlayer.pt", "predicates.parquet", "weights.parquet"}
    with zipfile.ZipFile(models["lstm"]) as archive:
        assert set(archive.namelist()) == {"manifest.json", "network.npz", "audit.json"}


def test_exporting_twice_writes_the_same_bytes(desk_stream_workdir, tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    paths = [export.run(desk_stream_workdir, export.ExportOptions(method="conflation", output=tmp_path / f"{i}.mlnseq")).path
             for i in range(2)]
    assert paths[0].read_bytes() == paths[1].read_bytes()


def test_broken_and_foreign_model_files_are_refused_in_one_line(models, tmp_path):
    truncated = tmp_path / "truncated.mlnseq"
    truncated.write_bytes(models["combined"].read_bytes()[:-200])
    foreign = tmp_path / "foreign.mlnseq"
    foreign.write_text("name,value\n")
    future = tmp_path / "future.mlnseq"
    with zipfile.ZipFile(models["lstm"]) as source, zipfile.ZipFile(future, "w") as target:
        for name in source.namelist():
            data = source.read(name)
            if name == "manifest.json":
                data = json.dumps({**json.loads(data), "format": 99, "mlnseq_version": "9.0"}).encode()
            target.writestr(name, data)
    partial = tmp_path / "partial.mlnseq"
    with zipfile.ZipFile(models["combined"]) as source, zipfile.ZipFile(partial, "w") as target:
        for name in source.namelist():
            if name != "weights.parquet":
                target.writestr(name, source.read(name))
    for path, needle in ((truncated, "not an mlnseq model file"), (foreign, "not an mlnseq model file"),
                         (partial, "lacks weights.parquet, which its manifest declares"),
                         (future, f"format 99 from mlnseq 9.0; this mlnseq .* reads format {model_file.MODEL_FORMAT}"),
                         (tmp_path / "absent.mlnseq", "not found")):
        with pytest.raises(BadInput, match=needle) as error:
            Recognizer.load(path)
        assert "\n" not in str(error.value)


def test_a_segment_mode_network_is_exported_with_a_note(desk_full_workdir, tmp_path):
    exported = export.run(desk_full_workdir, export.ExportOptions(method="lstm", output=tmp_path / "m.mlnseq"))
    assert any("segment mode" in note for note in exported.manifest.notes)
    assert exported.manifest.network.mode == "segment"


def test_decoding_refuses_an_unknown_kind(desk_stream_workdir):
    from mlnseq.mln import chain

    factors = chain.ChainFactors(np.zeros((3, 2)), np.zeros((1, 2, 2)), np.array([-1, 0, 0]))
    assert decoding.decode(factors, "viterbi").path.shape == (3,)
    with pytest.raises(BadInput, match="unknown decoding 'blur'"):
        decoding.decode(factors, "blur")
    assert decoding.decode(factors, "smooth-legal@1").path.shape == (3,)
