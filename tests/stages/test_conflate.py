"""conflate: eq. 16 by hand, and predictions of every method on the real DESK frames."""

import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts, methods, notes
from mlnseq import conflate, train
from mlnseq.choosing import network_weight, workdir_inputs
from mlnseq.fusion import fuse
from mlnseq.catalog.errors import BadInput, MissingArtifact


@pytest.fixture(scope="module")
def predicted(tmp_path_factory, desk_mln_workdir):
    workdir = tmp_path_factory.mktemp("conflate")
    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
        shutil.copy(desk_mln_workdir / name, workdir / name)
    train.run(workdir, train.TrainOptions(epochs=3))
    train.run(workdir, train.TrainOptions(method="priorlayer", epochs=3, mode="stream", folds=0))
    result = conflate.run(workdir, conflate.ConflateOptions())
    return workdir, result


def test_every_method_is_predicted_and_conflation_matches_its_parts(predicted):
    workdir, result = predicted
    assert result.methods == ["lstm", "mln", "priorlayer", "conflation", "combined"]
    table, meta = artifacts.read_table(result.path, "predictions")
    assert table.height == 22_329 and table["split"].to_list().count("train") == 1405
    assert meta["modes"] == {"lstm": "segment", "mln": "frame", "priorlayer": "stream",
                             "conflation": "segment", "combined": "stream"}
    probs = {m: table.select(artifacts.prob_columns(m, 7)).to_numpy().astype(np.float64) for m in result.methods}
    np.testing.assert_allclose(probs["lstm"].sum(1), 1.0, rtol=1e-4)
    np.testing.assert_allclose(probs["conflation"], fuse.conflation(probs["lstm"], probs["mln"]), rtol=1e-4)
    assert (table["combined_pred"].to_numpy() == probs["combined"].argmax(1)).all()
    assert table["lstm_pred"].dtype == pl.Int16


def test_mln_alone_needs_only_weights_and_names_missing_models(tmp_path, desk_mln_workdir):
    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
        shutil.copy(desk_mln_workdir / name, tmp_path / name)
    result = conflate.run(tmp_path, conflate.ConflateOptions(mln_mode="exact"))
    assert result.methods == ["mln"]
    assert any(n.code == notes.MISSING_INPUT and "train --method lstm" in n.text for n in result.notes)


def test_conflate_with_nothing_trained_names_the_stages(tmp_path, desk_frames_workdir):
    shutil.copy(desk_frames_workdir / artifacts.FRAMES, tmp_path / artifacts.FRAMES)
    with pytest.raises(MissingArtifact, match="learn-weights.*train"):
        conflate.run(tmp_path, conflate.ConflateOptions())
    assert not (tmp_path / artifacts.PREDICTIONS).exists()


def test_a_checkpoint_from_another_feature_set_is_refused(predicted, tmp_path):
    workdir, _ = predicted
    frames, meta = artifacts.read_table(workdir / artifacts.FRAMES, "frames")
    renamed = frames.rename({"left_gripper": "left_grip"})
    artifacts.write_table(renamed, tmp_path / artifacts.FRAMES, "frames", {**meta, "features": renamed.columns[4:]})
    shutil.copytree(workdir / artifacts.MODELS_DIR, tmp_path / artifacts.MODELS_DIR)
    with pytest.raises(BadInput, match="features"):
        conflate.run(tmp_path, conflate.ConflateOptions())


def test_unknown_mln_mode_is_refused():
    with pytest.raises(BadInput, match="--mln-mode"):
        conflate.ConflateOptions(mln_mode="fast").validate()


def test_every_decoding_is_predicted_with_its_weight_chosen_on_validation(desk_stream_workdir):
    table, meta = artifacts.read_table(desk_stream_workdir / artifacts.PREDICTIONS, "predictions")
    assert meta["methods"] == methods.method_names()
    for name in meta["methods"]:
        probabilities = table.select(artifacts.prob_columns(name, 7)).to_numpy().astype(np.float64)
        if name != "conflation" and name != "combined":  # eq. 16 is not renormalised
            np.testing.assert_allclose(probabilities.sum(1), 1.0, atol=1e-4)
        method, decode = methods.parse_method(name)
        assert meta["modes"][name] == meta["modes"][method]
    chosen = meta["network_weights"]
    assert set(chosen) == {f"{m}+{d}" for m in ("lstm", "priorlayer", "conflation", "combined") for d in ("filter", "viterbi")}
    for choice in chosen.values():
        assert choice["weight"] in network_weight.NETWORK_WEIGHTS and choice["validation_frame_accuracy"] == max(choice["tried"].values())
    assert set(meta["validation_frame_accuracy"]) == set(meta["methods"])
    # the decoded MLN beats the per-frame one on the held-out part of the training split
    assert meta["validation_frame_accuracy"]["mln+viterbi"] > meta["validation_frame_accuracy"]["mln"]


def test_without_temporal_formulas_decoding_says_so_and_filters_the_exact_mln(tmp_path, desk_mln_workdir):
    from mlnseq.mln import chain, classifier

    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
        shutil.copy(desk_mln_workdir / name, tmp_path / name)
    result = conflate.run(tmp_path, conflate.ConflateOptions(decode=("filter",)))
    assert [n.code for n in result.notes] == [notes.MISSING_INPUT, notes.MISSING_INPUT, notes.UNIFORM_TRANSITIONS]
    assert "no temporal formula" in result.notes[-1].text
    table = pl.read_parquet(result.path)
    frames, meta = artifacts.read_table(tmp_path / artifacts.FRAMES, "frames")
    scores = workdir_inputs.mln_class_scores(tmp_path, frames, meta["classes"])[0]  # weights name the classes so
    expected = np.exp(classifier.class_log_probs(scores, "exact", "clamp"))
    # each chain's first frame also weighs the start distribution fitted on the training split's episodes
    starts = chain.chain_starts(frames["episode"].to_numpy(), frames["split"].to_numpy() == "test")
    primed = expected[starts] * np.exp(artifacts.read_metadata(result.path, "predictions")["start"])
    expected[starts] = primed / primed.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(table.select(artifacts.prob_columns("mln+filter", 7)).to_numpy(), expected, atol=1e-5)


def test_a_fixed_network_weight_is_used_as_given(tmp_path, desk_stream_workdir):
    workdir = Path(shutil.copytree(desk_stream_workdir, tmp_path / "work"))
    result = conflate.run(workdir, conflate.ConflateOptions(decode=("viterbi",), network_weight=1.0))
    _, meta = artifacts.read_table(result.path, "predictions")
    assert result.choices == {} and meta["network_weights"] == {} and meta["network_weight_option"] == 1.0
    assert "combined+viterbi" in meta["methods"]


def test_decoding_needs_the_mln_and_known_names(tmp_path, desk_stream_workdir):
    for name in (artifacts.FRAMES, artifacts.MODELS_DIR):
        (shutil.copytree if name == artifacts.MODELS_DIR else shutil.copy)(desk_stream_workdir / name, tmp_path / name)
    with pytest.raises(BadInput, match="--decode filter needs the MLN's factors: run `mlnseq learn-weights`"):
        conflate.run(tmp_path, conflate.ConflateOptions(decode=("filter",)))
    with pytest.raises(BadInput, match="--decode"):
        conflate.ConflateOptions(decode=("blur",)).validate()
    with pytest.raises(BadInput, match="--lags"):
        conflate.ConflateOptions(decode=("smooth",), lags=(-1,)).validate()
    assert conflate.parse_decode("all")[:3] == ("none", "filter", "filter-legal") and "smooth" in conflate.parse_decode("all")
    assert conflate.ConflateOptions(decode=("smooth", "viterbi"), lags=(0, 4)).decodes == ("none", "smooth@4", "viterbi")
    assert conflate.parse_decode("none, viterbi") == ("none", "viterbi")
    with pytest.raises(BadInput, match="--network-weight"):
        conflate.parse_network_weight("heavy")


def test_a_frame_that_breaks_a_hard_rule_restarts_the_chain_with_a_note(tmp_path, own_data_glitch):
    shutil.copytree(own_data_glitch["workdir"], tmp_path, dirs_exist_ok=True)
    result = conflate.run(tmp_path, conflate.ConflateOptions(decode=("filter", "viterbi")))
    for name in ("mln+filter", "mln+viterbi"):
        assert [n.text for n in result.notes if n.text.startswith(f"{name}: the chain restarted at 1 frame(s)")] == [
            f"{name}: the chain restarted at 1 frame(s) that no allowed transition reaches (a missed episode boundary, "
            f"or evidence that breaks a hard rule): episode 11 frame {own_data_glitch['frame']}"]


def test_the_command_lines_decoders_bring_their_lags_and_lags_are_given_once():
    assert conflate.options_from("paper", "smooth-legal@5,conflation+lagviterbi@2").lags == (5, 2)
    both = conflate.options_from("exact", "all", "0,5", "2.5")
    assert both.lags == (0, 5) and "viterbi" in both.decode and both.network_weight == 2.5
    with pytest.raises(BadInput, match="give the lags once"):
        conflate.options_from("paper", "smooth@5", "1,2")
