"""Cross-validation: the folds, the fold networks' out-of-fold predictions, the network factor's weight learned by
exact CLL on them, the cross-validated figures conflate records, and `export --method auto`."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts
from mlnseq.model import checkpoints
from mlnseq import conflate, export, learn_weights, train
from mlnseq.choosing import folds
from mlnseq.choosing.cross_validation import FIGURES
from mlnseq.catalog.errors import BadInput, StaleArtifact

from choice_rule import expected_choice  # tests/choice_rule.py


def desk_keys(workdir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    frames = pl.read_parquet(workdir / artifacts.FRAMES, columns=["episode", "split", "label"])
    return frames["episode"].to_numpy(), frames["split"].to_numpy(), frames["label"].to_numpy()


def test_desk_has_one_training_recording_so_its_folds_are_blocks_cut_where_a_trial_restarts(desk_frames_workdir):
    episodes, splits, labels = desk_keys(desk_frames_workdir)
    cut = folds.assign(episodes, splits, labels, 5)
    assert cut.kind == "blocks" and cut.k == 5 and cut.describe() == "5 folds by block at task restarts"
    assert (cut.fold[splits == "test"] == -1).all() and (cut.fold[splits == "train"] >= 0).all()
    # the cuts of 5 equal blocks (281, 562, 843, 1124) moved to the nearest frames where the surgeme returns to S1
    assert cut.record()["spans"] == [[0, 217], [217, 476], [476, 865], [865, 1131], [1131, 1405]]
    assert cut.record()["cut"] == "restarts"
    train = labels[splits == "train"]
    assert all(train[a] == 0 != train[a - 1] for a, _ in cut.record()["spans"][1:])
    assert folds.assign(episodes, splits, labels, 5).record() == cut.record()  # deterministic
    # each fold: its fit rows the other folds' and its held-out rows its own, as the splits a fold's models see
    held = np.zeros(len(labels), dtype=int)
    for k, fold in enumerate(cut.masks()):
        assert np.array_equal(fold.fit, cut.splits(k) == "train")
        assert np.array_equal(fold.held, cut.splits(k) == "heldout")
        held += fold.held
    assert np.array_equal(held, splits == "train")  # every training frame held out once, never a test frame


def test_blocks_never_cut_a_segment_where_the_task_restarts_too_rarely():
    labels = np.repeat([0, 1, 2, 1, 2, 1, 2], [10, 30, 20, 25, 15, 30, 20])  # one start of class 0
    cut = folds.assign(np.zeros(150, dtype=int), np.array(["train"] * 150), labels, 3)
    starts = [a for a, _ in cut.record()["spans"][1:]]
    assert cut.record()["cut"] == "segments" and all(labels[a] != labels[a - 1] for a in starts)
    assert starts == [40, 100]  # the segment ends nearest 50 and 100
    flat = folds.assign(np.zeros(60, dtype=int), np.array(["train"] * 60), np.zeros(60, dtype=int), 3)
    assert flat.record()["cut"] == "frames" and flat.describe() == "3 folds by block inside segments"


def test_folds_are_whole_episodes_when_there_are_enough():
    episodes = np.repeat([3, 1, 2, 7], 30)
    splits = np.array(["train"] * 90 + ["test"] * 30)
    labels = np.tile(np.repeat([0, 1], 15), 4)
    cut = folds.assign(episodes, splits, labels, 3)
    assert cut.kind == "episodes" and [s[:2] for s in cut.record()["spans"]] == [[0, 30], [30, 60], [60, 90]]
    blocks = folds.assign(episodes, splits, labels, 4)  # 3 training episodes: 4 folds are blocks, cut at restarts
    assert blocks.kind == "blocks" and [a for a, _ in blocks.record()["spans"][1:]] == [30, 45, 60]
    assert blocks.describe() == "4 folds by block at task restarts and segment ends"


@pytest.mark.parametrize("k", [1, 71])
def test_a_k_the_split_cannot_make_names_the_largest(desk_frames_workdir, k):
    episodes, splits, labels = desk_keys(desk_frames_workdir)
    with pytest.raises(BadInput, match=f"--folds {k}: .* at most 70; use --folds 5 \\(5 folds by block"):
        folds.assign(episodes, splits, labels, k)


def test_out_of_fold_predictions_cover_every_training_frame_with_its_fold(desk_folds_workdir):
    table, meta = artifacts.read_table(artifacts.out_of_fold_path(desk_folds_workdir, "lstm"), "out_of_fold")
    checkpoint = checkpoints.load_checkpoint(desk_folds_workdir, "lstm")
    assert meta["folds"] == checkpoint.config["folds"] and meta["folds"]["k"] == 3
    assert checkpoint.config["n_val_units"] == 0  # the deployed network is refit on the whole training split
    assert table.height == 1405 and table["fold"].to_list() == np.repeat([0, 1, 2], [476, 521, 408]).tolist()
    log_probs = table.select(artifacts.log_prob_columns(7)).to_numpy()
    np.testing.assert_allclose(np.exp(log_probs).sum(1), 1.0, atol=1e-4)
    fold_weights, weights_meta = artifacts.read_table(desk_folds_workdir / artifacts.FOLD_WEIGHTS, "fold_weights")
    assert weights_meta["folds"] == meta["folds"] and fold_weights["fold"].unique().sort().to_list() == [0, 1, 2]


def test_conflate_learns_the_network_weight_and_cross_validates_every_method(desk_folds_workdir):
    meta = artifacts.read_metadata(desk_folds_workdir / artifacts.PREDICTIONS, "predictions")
    cv = meta["cross_validation"]
    assert set(cv["figures"]) == set(meta["methods"])
    for figures in cv["figures"].values():
        assert set(FIGURES) <= set(figures) <= {*FIGURES, "log_likelihood", "forbidden_transitions"}
        assert 0 <= figures["segment_accuracy"] <= 100
    for name in ("lstm+filter", "conflation+viterbi", "combined+filter"):
        assert meta["network_weights"][name]["how"] == "learned"
        assert len(cv["fold_network_weights"][name]) == 3
    # the same weight decodes test online and offline: it is learned by likelihood, not per decoding
    assert meta["network_weights"]["conflation+filter"] == meta["network_weights"]["conflation+viterbi"]


def test_the_learned_weight_follows_how_informative_the_network_is(desk_folds_workdir):
    from mlnseq.mln import cll
    from mlnseq.mln.factors import MLNFactors

    predicates, _ = artifacts.read_table(desk_folds_workdir / artifacts.PREDICATES, "predicates")
    weights, meta = artifacts.read_table(desk_folds_workdir / artifacts.WEIGHTS, "weights")
    train_rows = predicates.filter(pl.col("split") == "train")
    columns = artifacts.feature_columns(predicates)
    labels = train_rows["label"].to_numpy().astype(np.int64)
    mln = MLNFactors.from_weights(weights, columns, meta["classes"])
    factors = mln.chain(train_rows.select(columns).to_numpy().astype(bool), np.r_[True, np.zeros(len(labels) - 1, bool)])
    honest = np.log(np.where(np.eye(7)[labels] > 0, 0.5, 0.5 / 6))  # half its mass on the true class
    shuffled = honest[np.random.default_rng(0).permutation(len(labels))]
    assert cll.network_weight(factors, honest, labels) > 0.5
    assert cll.network_weight(factors, shuffled, labels) < 0.05


def test_export_auto_picks_the_best_cross_validated_method(desk_folds_workdir, tmp_path):
    exported = export.run(desk_folds_workdir, export.ExportOptions(method="auto", decode="viterbi",
                                                                    output=tmp_path / "auto.mlnseq"))
    chosen = exported.manifest.chosen_by_cross_validation
    cross = artifacts.read_metadata(desk_folds_workdir / artifacts.PREDICTIONS)["cross_validation"]
    best = expected_choice({n: f for n, f in cross["figures"].items() if n.endswith("+viterbi")},
                           cross["fold_frame_accuracy"])
    assert chosen.name == best and exported.manifest.method == best.partition("+")[0]
    assert exported.manifest.decode == "viterbi"


def test_export_auto_without_folds_says_to_train_with_folds(desk_stream_workdir, tmp_path):
    with pytest.raises(BadInput, match=r"train --folds K"):
        export.run(desk_stream_workdir, export.ExportOptions(method="auto", decode="filter", output=tmp_path / "m"))
    with pytest.raises(BadInput, match=r"train --folds K"):  # auto without --decode: any decoder, as any lag
        export.run(desk_stream_workdir, export.ExportOptions(method="auto", output=tmp_path / "m"))


def test_out_of_fold_predictions_of_another_training_are_stale(desk_folds_workdir, tmp_path):
    workdir = Path(shutil.copytree(desk_folds_workdir, tmp_path / "work"))
    other = Path(shutil.copytree(desk_folds_workdir, tmp_path / "other"))
    train.run(other, train.TrainOptions(method="lstm", mode="stream", epochs=1, folds=3, seed=5))
    shutil.copy(artifacts.out_of_fold_path(other, "lstm"), artifacts.out_of_fold_path(workdir, "lstm"))
    before = (workdir / artifacts.PREDICTIONS).read_bytes()
    with pytest.raises(StaleArtifact, match="rerun `mlnseq train --method lstm --folds 3`"):
        conflate.run(workdir, conflate.ConflateOptions())
    assert (workdir / artifacts.PREDICTIONS).read_bytes() == before


def test_priorlayer_fold_networks_need_the_folds_mln_weights(desk_folds_workdir, tmp_path):
    workdir = Path(shutil.copytree(desk_folds_workdir, tmp_path / "work"))
    (workdir / artifacts.FOLD_WEIGHTS).unlink()
    with pytest.raises(BadInput, match="learn-weights --folds 3"):
        train.run(workdir, train.TrainOptions(method="priorlayer", mode="stream", epochs=1, folds=3))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions(folds=2))
    with pytest.raises(BadInput, match="other folds"):
        train.run(workdir, train.TrainOptions(method="priorlayer", mode="stream", epochs=1, folds=3))


def test_a_fold_lacking_a_class_is_a_warning_naming_fold_and_class():
    labels = np.r_[np.zeros(20, int), np.ones(40, int)]  # class a only in fold 0
    cut = folds.assign(np.zeros(60, dtype=int), np.array(["train"] * 60), labels, 3)
    assert folds.missing_classes(cut, labels, ["a", "b"]) == [
        "fold 0: its fit part lacks class a; its out-of-fold predictions are written all the same"]


def test_train_refuses_a_bad_k_before_training(desk_frames_workdir, tmp_path):
    shutil.copy(desk_frames_workdir / artifacts.FRAMES, tmp_path / artifacts.FRAMES)
    for k in (1, 71):
        with pytest.raises(BadInput, match=f"--folds {k}: .* at most 70; use --folds 5"):
            train.run(tmp_path, train.TrainOptions(mode="stream", epochs=1, folds=k))
    assert not (tmp_path / artifacts.MODELS_DIR).exists()



def test_a_single_recording_is_cut_into_blocks_only_where_its_task_restarts(desk_frames_workdir):
    frames, _ = artifacts.read_table(desk_frames_workdir / artifacts.FRAMES, "frames")
    episodes, splits, labels = (frames[c].to_numpy() for c in ("episode", "split", "label"))
    assert folds.suggested(episodes, splits, labels=labels) == 5  # DESK: one recording, the task restarting in it
    first = np.flatnonzero(labels != labels[0])[0]
    once = np.arange(len(labels)) < np.flatnonzero((labels == labels[0]) & (np.arange(len(labels)) > first))[0]
    assert folds.suggested(episodes[once], splits[once]) == 5  # blocks of one run of the task, without the labels
    assert folds.suggested(episodes[once], splits[once], labels=labels[once]) == 0  # not with them


def test_export_takes_the_weight_conflate_learned_while_its_inputs_stand(desk_folds_workdir, tmp_path):
    """export of a decoded network method takes the network factor's weight conflate learned, where conflate's record
    still stands (none of predictions.parquet's inputs changed): the weight that learning it again gives, to the bit;
    not once the weights changed since."""
    from mlnseq.catalog.errors import StaleArtifact
    from mlnseq.catalog.methods import Method, WeightSource
    from mlnseq.choosing.network_weight import WeightDecision
    from mlnseq.choosing.workdir_inputs import read_workdir
    from mlnseq.mln.factors import MLNFactors

    recorded, notes = export.conflated_weight(desk_folds_workdir, "conflation+filter")
    inputs = read_workdir(desk_folds_workdir, (Method.NETWORK,))
    again = WeightDecision(inputs, MLNFactors.from_weights(inputs.mln.weights, inputs.mln.columns, inputs.classes))
    assert recorded == again.choice(Method.CONFLATION, "filter") and recorded.how == WeightSource.LEARNED
    assert notes == again.notes([Method.NETWORK])
    copy = tmp_path / "copy"
    shutil.copytree(desk_folds_workdir, copy)
    weights = pl.read_parquet(copy / artifacts.WEIGHTS)
    artifacts.write_table(weights.with_columns(pl.col("weight") * 1.01), copy / artifacts.WEIGHTS, "weights",
                          artifacts.read_metadata(copy / artifacts.WEIGHTS))
    with pytest.raises(StaleArtifact, match="predictions.parquet was made from an older weights.parquet"):
        export.conflated_weight(copy, "conflation+filter")


def test_fold_networks_are_the_mean_of_members_on_little_data_and_one_network_at_scale():
    from mlnseq.choosing.fold_networks import ALONE_FRAMES, fold_members

    episodes = np.repeat(np.arange(40), 630)  # 40 recordings of 630 frames, as the generated arm's
    splits = np.where(episodes < 35, "train", "test")
    labels = np.tile(np.repeat(np.arange(5), 126), 40)
    big = folds.assign(episodes, splits, labels, 5)
    assert (big.fold >= 0).sum() == 35 * 630 >= ALONE_FRAMES and fold_members(3, big) == 1
    small = folds.assign(episodes[: 6 * 630], splits[: 6 * 630], labels[: 6 * 630], 5)
    assert fold_members(3, small) == 3 and fold_members(1, small) == 1
