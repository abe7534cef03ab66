"""Self-training: the agreement threshold chosen on the labelled folds' out-of-fold probabilities, and the frames
of unlabelled recordings where the network and the MLN agree with it, as intervals --labels reads back."""

from __future__ import annotations

import numpy as np
import polars as pl

from mlnseq import collect
from mlnseq.catalog import artifacts
from mlnseq.labelling import self_training
from mlnseq.recognition.recognizer import Recognizer
from mlnseq.sources import SourceOptions


def test_out_of_fold_rows_are_the_training_rows(fitted):
    network, mln, labels = self_training.out_of_fold(fitted["workdir"])
    frames, _ = artifacts.read_table(fitted["workdir"] / artifacts.FRAMES, "frames")
    assert network.shape == mln.shape == (artifacts.labelled(frames).height, 5) and len(labels) == len(network)
    assert np.allclose(np.exp(network).sum(axis=1), 1, atol=1e-4) and np.allclose(np.exp(mln).sum(axis=1), 1)


def test_the_threshold_chosen_is_the_lowest_right_enough_out_of_fold(fitted):
    network, mln, labels = self_training.out_of_fold(fitted["workdir"])
    right = {}
    for threshold in self_training.THRESHOLDS:
        classes, sure = self_training.agreed(network, mln, threshold)
        if sure.any():
            right[threshold] = float(np.mean(classes[sure] == labels[sure]))
    target = max(right.values()) - 1e-9  # a precision one threshold at least reaches on these 3-epoch folds
    chosen = self_training.choose_threshold(network, mln, labels, precision=target)
    assert chosen.threshold == min(t for t, r in right.items() if r >= target)
    classes, sure = self_training.agreed(network, mln, chosen.threshold)
    assert chosen.coverage == sure.mean() and (np.exp(network.max(axis=1))[sure] >= chosen.threshold).all()
    assert (np.exp(mln.max(axis=1))[sure] >= chosen.threshold).all() and "out of fold" in chosen.said()
    never = self_training.choose_threshold(network, mln, (labels + 1) % 5)  # every label wrong: none chosen
    assert never.threshold is None and "not learned from" in never.said()


def test_agreed_runs_become_intervals_that_label_only_those_frames(fitted, tmp_path):
    frames, meta = artifacts.read_table(fitted["workdir"] / artifacts.FRAMES, "frames")
    model = Recognizer.load(fitted["model"])
    bare = frames.filter(pl.col("split") == "unlabelled")
    rows = []
    for (episode,), part in bare.partition_by("episode", as_dict=True, maintain_order=True).items():
        scores = model.scored(part.select(artifacts.feature_columns(frames)).to_numpy().astype(np.float64))
        classes, sure = self_training.agreed(scores.log_p_network, scores.log_p_mln, 0.3)
        rows += self_training.runs_as_intervals(meta["episode_names"][episode], classes, sure, model.classes, 5)
    assert rows and all(last - first + 1 >= 5 for _, first, last, _ in rows)
    labels = tmp_path / "pseudo.csv"
    pl.DataFrame(rows, schema=["episode", "start", "end", "label"], orient="row").write_csv(labels)
    back = collect.collect(collect.CollectOptions(env="rosbag", source=fitted["bags"], recordings=SourceOptions(
        labels=labels, labels_unit="frames")))
    assert artifacts.labelled(back.frames).height == sum(last - first + 1 for _, first, last, _ in rows)


def test_a_workdir_without_folds_chooses_no_threshold(fitted, tmp_path):
    import shutil

    bare = tmp_path / "work"
    shutil.copytree(fitted["workdir"], bare)
    assert self_training.chosen(bare).folds
    (bare / artifacts.FOLD_WEIGHTS).unlink()
    none = self_training.chosen(bare)
    assert none.threshold is None and not none.folds and none.said().startswith("no folds")
