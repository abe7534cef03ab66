"""train on the real DESK frames: sequences, learning, determinism, selection, bad input."""

import shutil

import numpy as np
import polars as pl
import pytest
import torch

from mlnseq.catalog import artifacts
from mlnseq.model import checkpoints
from mlnseq.choosing import training_rows as rows
from mlnseq.timeline import sequences
from mlnseq import train
from mlnseq.catalog.errors import BadInput, MissingArtifact


@pytest.fixture
def desk_workdir(tmp_path, desk_frames_workdir):
    shutil.copy(desk_frames_workdir / artifacts.FRAMES, tmp_path / artifacts.FRAMES)
    return tmp_path


@pytest.fixture(scope="module")
def desk_data(desk_frames_workdir):
    frames, _ = artifacts.read_table(desk_frames_workdir / artifacts.FRAMES, "frames")
    return train.FrameData.from_frames(frames)


def test_segment_and_stream_modes_cut_different_sequences(desk_data):
    d = desk_data
    segments = sequences.sequences("segment", d.episodes, d.splits, d.labels)
    streams = sequences.sequences("stream", d.episodes, d.splits, d.labels)
    assert len(segments) == 775  # 50 train + 725 test segments, as the data README states
    assert len(streams) == 2  # one training and one test episode
    windows = sequences.training_units("stream", d.episodes, d.splits, d.labels, 64)
    assert len([w for w in windows if d.splits[w.start] == "train"]) == 22  # ceil(1405 / 64)


def test_validation_part_is_the_last_fifth_of_training_segments(desk_data):
    options = train.TrainOptions(select="val_accuracy")
    parts, fit_units, val_units = rows.assign_parts(desk_data, options)
    assert (len(fit_units), len(val_units)) == (40, 10)
    assert val_units[0].start == fit_units[-1].stop
    assert set(parts[desk_data.splits == "test"]) == {"test"}
    half = rows.assign_parts(desk_data, train.TrainOptions(train_fraction=0.5))[1]
    assert len(half) == 25


def test_a_few_epochs_learn_better_than_chance_and_are_deterministic(desk_workdir):
    options = train.TrainOptions(epochs=12, seed=3)
    first = train.run(desk_workdir, options)
    log, _ = artifacts.read_table(first.log, "train_log")
    test = log.filter(pl.col("split") == "test")["accuracy"]
    assert test[-1] > 2 / 7  # chance over 7 classes is about 1/7
    assert log.filter(pl.col("split") == "train")["accuracy"][-1] > 0.3
    weights = checkpoints.load_checkpoint(desk_workdir, "lstm").network.weights
    second = train.run(desk_workdir, options)
    again = checkpoints.load_checkpoint(desk_workdir, "lstm")
    for name, value in again.network.weights.items():
        np.testing.assert_array_equal(value, weights[name], err_msg=name)
    assert artifacts.read_table(second.log, "train_log")[0].equals(log)
    config = again.config
    assert config["features"] == ["arm_distance", "left_gripper", "right_gripper"]
    assert len(config["classes"]) == 7 and config["mode"] == "segment" and config["seed"] == 3
    train_rows = pl.read_parquet(desk_workdir / artifacts.FRAMES).filter(pl.col("split") == "train")
    np.testing.assert_allclose(config["mean"][0], train_rows["arm_distance"].mean(), rtol=1e-4)


def test_select_keeps_the_best_validation_epoch_and_logs_val(desk_workdir):
    result = train.run(desk_workdir, train.TrainOptions(epochs=4, select="val_accuracy", mode="stream"))
    log = result.trained.log
    val = log.filter(pl.col("split") == "val")
    assert val.height == 4
    assert result.trained.kept_epoch == int(val["epoch"][int(np.argmax(val["accuracy"].to_numpy()))])


def test_progress_reports_every_epoch_as_the_log_records_it(desk_workdir):
    done = []
    result = train.run(desk_workdir, train.TrainOptions(epochs=3, select="val_accuracy"), progress=done.append)
    assert [(d.epoch, d.epochs) for d in done] == [(1, 3), (2, 3), (3, 3)]
    log = result.trained.log
    for d in done:
        logged = {row["split"]: row for row in log.filter(pl.col("epoch") == d.epoch).iter_rows(named=True)}
        assert (d.train_accuracy, d.loss, d.val_accuracy) == (
            logged["train"]["accuracy"], logged["train"]["loss"], logged["val"]["accuracy"])
    without_val = []
    train.run(desk_workdir, train.TrainOptions(epochs=1), progress=without_val.append)
    assert without_val[0].val_accuracy is None


def test_priorlayer_trains_on_the_learned_mln_weights(tmp_path, desk_mln_workdir):
    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
        shutil.copy(desk_mln_workdir / name, tmp_path / name)
    result = train.run(tmp_path, train.TrainOptions(method="priorlayer", prior="paper", epochs=2))
    checkpoint = checkpoints.load_checkpoint(tmp_path, "priorlayer")
    assert checkpoint.config["prior"] == "paper" and "prior.weight" in checkpoint.network.weights
    assert set(checkpoint.config["inputs"]) == {artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS}
    assert result.trained.log.height == 2  # the last epoch (measure's default) x (train, test)


def test_priorlayer_before_learn_weights_names_the_stage(desk_workdir):
    with pytest.raises(MissingArtifact, match="binarize|learn-weights"):
        train.run(desk_workdir, train.TrainOptions(method="priorlayer", epochs=1))
    assert not artifacts.checkpoint_path(desk_workdir, "priorlayer").exists()


def test_train_before_collect_names_collect(tmp_path):
    with pytest.raises(MissingArtifact, match="mlnseq collect"):
        train.run(tmp_path, train.TrainOptions(epochs=1))


@pytest.mark.parametrize("change", [{"mode": "video"}, {"train_fraction": 0.0}, {"train_fraction": 1.5},
                                    {"method": "tcn"}, {"epochs": 0}, {"optimizer": "rmsprop"}, {"members": 0},
                                    {"updates": -1}, {"learning_rate": 0.0}])
def test_bad_options_are_refused(change):
    with pytest.raises(BadInput):
        train.TrainOptions(**change).validate()


def test_interrupted_save_keeps_the_previous_checkpoint(desk_workdir, monkeypatch):
    train.run(desk_workdir, train.TrainOptions(epochs=1))
    path = artifacts.checkpoint_path(desk_workdir, "lstm")
    before = path.read_bytes()

    def interrupted_save(obj, file):
        file.write(b"partial")  # save_checkpoint hands torch.save the open temporary file
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", interrupted_save)
    with pytest.raises(KeyboardInterrupt):
        train.run(desk_workdir, train.TrainOptions(epochs=1, seed=1))
    assert path.read_bytes() == before
    assert checkpoints.load_checkpoint(desk_workdir, "lstm").config["seed"] == 0


def test_select_last_holds_out_a_validation_part_and_keeps_the_last_epoch(desk_workdir):
    result = train.run(desk_workdir, train.TrainOptions(epochs=3, select="last", mode="stream",
                                                            measure="every-epoch"))
    trained = result.trained
    assert trained.kept_epoch == 3 and trained.n_val_units > 0
    assert trained.log.filter(pl.col("split") == "val").height == 3
    spans = checkpoints.load_checkpoint(desk_workdir, "lstm").config["val_spans"]
    assert [tuple(s) for s in spans] == trained.val_spans and spans


def test_the_paper_floor_is_chosen_at_train_time_and_conflate_floors_the_mln_with_it(tmp_path, desk_mln_workdir):
    """--paper-floor is recorded in the checkpoint (default: the dataset's, clamp for DESK, shift for the Fetch
    simulation); conflate floors the MLN's sums as the networks were trained, and refuses networks that disagree."""
    from mlnseq import conflate
    from mlnseq.catalog.methods import PaperFloor
    from mlnseq.mln import classifier

    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
        shutil.copy(desk_mln_workdir / name, tmp_path / name)
    assert PaperFloor.for_recordings("fetch") == "shift" and PaperFloor.for_recordings("desk") == "clamp"
    train.run(tmp_path, train.TrainOptions(method="priorlayer", mode="stream", epochs=1, folds=0, paper_floor="shift"))
    config = checkpoints.load_checkpoint(tmp_path, "priorlayer").config
    assert config["paper_floor"] == config["options"]["paper_floor"] == "shift"
    conflate.run(tmp_path, conflate.ConflateOptions())
    predictions, meta = artifacts.read_table(tmp_path / artifacts.PREDICTIONS, "predictions")
    scores = classifier.class_scores(pl.read_parquet(tmp_path / artifacts.PREDICATES),
                                     pl.read_parquet(tmp_path / artifacts.WEIGHTS), meta["classes"])
    mln = predictions.select(artifacts.prob_columns("mln", 7)).to_numpy()
    assert meta["paper_floor"] == "shift"
    assert np.allclose(mln, np.exp(classifier.class_log_probs(scores, "paper", "shift")), atol=1e-6)
    assert not np.allclose(mln, np.exp(classifier.class_log_probs(scores, "paper", "clamp")), atol=1e-3)
    train.run(tmp_path, train.TrainOptions(method="network", mode="stream", epochs=1, folds=0))
    assert checkpoints.load_checkpoint(tmp_path, "lstm").config["paper_floor"] == "clamp"  # DESK's
    with pytest.raises(BadInput, match="trained with different --paper-floor"):
        conflate.run(tmp_path, conflate.ConflateOptions())


def test_measuring_every_epoch_or_the_last_trains_the_same_network(desk_workdir):
    """--measure changes what the log holds, never the network: the same weights, and the last-epoch log is the
    every-epoch log's last epoch; progress reports scores only after the epochs measured."""
    done = []
    every = train.run(desk_workdir, train.TrainOptions(epochs=3, mode="stream", measure="every-epoch"))
    weights = checkpoints.load_checkpoint(desk_workdir, "lstm").network.weights
    last = train.run(desk_workdir, train.TrainOptions(epochs=3, mode="stream"), progress=done.append)
    for name, value in checkpoints.load_checkpoint(desk_workdir, "lstm").network.weights.items():
        np.testing.assert_array_equal(value, weights[name], err_msg=name)
    assert every.trained.log.height == 6 and set(every.trained.log["epoch"]) == {1, 2, 3}
    assert last.trained.log.equals(every.trained.log.filter(pl.col("epoch") == 3))
    assert [d.loss is None for d in done] == [True, True, False]
    _, meta = artifacts.read_table(last.log, "train_log")
    assert meta["measured"] == "last-epoch" and "measure" not in meta["options"]


def test_select_val_accuracy_measures_every_epoch_and_refuses_measuring_the_last_only():
    assert train.TrainOptions(select="val_accuracy").measured == "every-epoch"
    assert train.TrainOptions(select="last").measured == "last-epoch"
    with pytest.raises(BadInput, match="--measure every-epoch"):
        train.TrainOptions(select="val_accuracy", measure="last-epoch").validate()
    with pytest.raises(BadInput):
        train.TrainOptions(measure="sometimes").validate()


def test_settled_training_keeps_the_epoch_its_fold_networks_stopped_at_and_repeats(desk_workdir):
    """fit's training (Adam over a budget of updates, 2 networks averaged per seed): the fold networks train first and
    say where to stop; the network kept is the members merged into one of twice the units, at that epoch, and a rerun
    writes the same weights and out-of-fold predictions."""
    options = train.TrainOptions(mode="stream", folds=3, epochs=30, optimizer="adam", members=2)
    first = train.run(desk_workdir, options)
    checkpoint = checkpoints.load_checkpoint(desk_workdir, "lstm")
    kept = first.trained.kept_epoch
    assert 1 <= kept <= 30 and set(first.trained.log["epoch"]) == {kept}
    assert checkpoint.config["model"]["hidden_size"] == 64 and checkpoint.config["kept_epoch"] == kept
    assert checkpoint.config["options"]["optimizer"] == "adam" and checkpoint.config["options"]["members"] == 2
    assert first.trained.log.filter(pl.col("split") == "train")["accuracy"][0] > 2 / 7
    oof = pl.read_parquet(artifacts.out_of_fold_path(desk_workdir, "lstm"))
    train.run(desk_workdir, options)
    for name, value in checkpoints.load_checkpoint(desk_workdir, "lstm").network.weights.items():
        np.testing.assert_array_equal(value, checkpoint.network.weights[name], err_msg=name)
    assert pl.read_parquet(artifacts.out_of_fold_path(desk_workdir, "lstm")).equals(oof)
