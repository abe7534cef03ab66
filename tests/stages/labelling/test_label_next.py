"""label_next: the recordings given without labels in a fitted workdir ranked by what labelling each would teach, with a
reason each, and their predicted phases as intervals that --labels reads back."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from mlnseq import collect
from mlnseq.catalog import artifacts
from mlnseq.labelling import label_next
from mlnseq.recognition.recognizer import Recognizer
from mlnseq.sources import SourceOptions
from mlnseq.sources.recording import TableColumns


@pytest.fixture(scope="module")
def proposal(fitted) -> label_next.Proposal:
    frames, meta = artifacts.read_table(fitted["workdir"] / artifacts.FRAMES, "frames")
    return label_next.propose(Recognizer.load(fitted["model"]), frames, meta["episode_names"],
                              meta["unlabelled_episodes"])


def test_every_unlabelled_recording_is_ranked_with_a_reason(proposal):
    ranked = proposal.ranked
    assert ranked.columns == ["episode", "rank", "reason", *label_next.MEASURES, "score"]
    assert sorted(ranked["episode"]) == ["episode_4", "episode_5", "episode_6"]
    assert ranked["rank"].to_list() == [1, 2, 3] and ranked["score"].is_sorted(descending=True)
    for row in ranked.iter_rows(named=True):  # each reason: its measure's value and its true place among the 3
        measure = next(m for m in label_next.MEASURES if f"{row[m]:.2f}" in row["reason"] or (
            m == "disagreement" and f"{row[m]:.0%}" in row["reason"]) or (m == "restarts" and f"{row[m]:.0f} time"
                                                                             in row["reason"]))
        values = ranked[measure].to_numpy()
        assert row["reason"].endswith(f"({label_next.place(values, list(ranked['episode']).index(row['episode']))})")
    lines = proposal.first()
    assert len(lines) == 3 and lines[0].startswith(f"1. {ranked['episode'][0]}: ")


def test_the_recording_unlike_the_labelled_ones_is_the_farthest(proposal):
    ranked = proposal.ranked
    farthest = ranked.sort("distance", descending=True)
    assert farthest["episode"][0] == "episode_4"  # five times the payload: its efforts unlike any labelled one's
    assert farthest["distance"][0] > farthest["distance"][1]  # standardised over every recording, the heavy one too


def test_predicted_phases_cover_every_frame_and_read_back_as_labels(proposal, fitted, tmp_path):
    frames, meta = artifacts.read_table(fitted["workdir"] / artifacts.FRAMES, "frames")
    given_none = [meta["episode_names"].index(name) for name in meta["unlabelled_episodes"]]
    bare = frames.filter(pl.col("episode").is_in(given_none))  # labelled by alignment: their split is train
    segments = proposal.intervals
    assert (segments["end"] - segments["start"] + 1).sum() == bare.height
    assert set(segments["label"]) <= set(meta["classes"])
    written = label_next.write(tmp_path, proposal)
    assert [p.name for p in written] == [artifacts.LABEL_NEXT, artifacts.UNLABELLED_INTERVALS]
    assert pl.read_csv(written[0])["episode"].to_list() == proposal.ranked["episode"].to_list()
    back = collect.collect(collect.CollectOptions(  # the file says its unit; --classes: a phase one proposal alone has
        env="rosbag", source=fitted["bags"], recordings=SourceOptions(labels=written[1]),
        columns=TableColumns(classes=tuple(meta["classes"]))))
    assert artifacts.labelled(back.frames).height == bare.height  # the proposal, corrected or not, is labels
    names = np.asarray(back.meta["classes"])[artifacts.labelled(back.frames)["label"].to_numpy()]
    expected = np.concatenate([np.repeat(r["label"], r["end"] - r["start"] + 1) for r in segments.iter_rows(
        named=True)])
    assert list(names) == list(expected)


def test_a_model_of_other_features_is_refused(fitted):
    frames, meta = artifacts.read_table(fitted["workdir"] / artifacts.FRAMES, "frames")
    with pytest.raises(ValueError, match="the model reads"):
        label_next.propose(Recognizer.load(fitted["model"]), frames.drop(artifacts.feature_columns(frames)[-1]),
                           meta["episode_names"], meta["unlabelled_episodes"])


def test_a_reason_says_its_place_and_ties_and_alike_ones_are_said():
    values = np.array([0.17, 0.21, 0.05, 0.21, 0.1])
    assert label_next.place(values, 0) == "3rd most of 5"
    assert label_next.place(values, 1) == "the most of 5, tied"
    assert label_next.place(np.zeros(5), 2) == "as all 5"
    table = pl.DataFrame({"episode": list("abcde"), "entropy": values, "disagreement": [0.0] * 5,
                          "restarts": [0.0] * 5, "distance": [1.0, 2.0, 3.0, 4.0, 5.0]})
    reasons = dict(label_next.ranked(table).select("episode", "reason").iter_rows())
    assert reasons["e"] == "it is the least like the labelled recordings: distance 5.00 (the most of 5)"
    assert reasons["b"].startswith("the chain is unsure: mean posterior entropy 0.21 nats (the most of 5, tied)")


def test_a_distance_keeps_its_scale_when_one_more_recording_is_labelled():
    rng = np.random.default_rng(3)
    recordings = [rng.normal(size=(200, 4)) * (1 + 0.1 * k) + 0.05 * k for k in range(6)]
    one = label_next.distances(recordings[2:], recordings[:1])
    two = label_next.distances(recordings[2:], recordings[:2])
    assert np.all(two <= one + 1e-12) and np.all(one < 5 * two)  # nearer or as near, never hundreds of times


def test_proposed_phases_have_no_run_shorter_than_the_shortest_phase():
    classes = np.array([0] * 20 + [1] + [0] * 3 + [1] * 30 + [2, 1, 2] + [2] * 25)
    smoothed = label_next.without_short_runs(classes, 10)
    starts, lengths = label_next.runs_of(smoothed)
    assert lengths.min() >= 10 and list(smoothed[starts]) == [0, 1, 2]
    assert np.mean(smoothed == classes) > 0.9
    assert label_next.without_short_runs(np.array([0, 1, 1]), 10).tolist() == [1, 1, 1]  # shorter than it: one run
    assert label_next.shortest_phase([np.array([0, 0, 1, 1, 1]), np.array([2] * 9)]) == 2
    assert label_next.shortest_run([np.array([0] * 80 + [1] * 95)]) == 40  # half: phases last longer in one than another


def test_the_labels_fit_trained_on_are_proposed_unless_the_decoding_cross_validates_better():
    assert label_next.chosen(None, 90.0)[0] is label_next.Proposed.ESTIMATES  # nothing checks them
    assert label_next.chosen(0.95, 90.0)[0] is label_next.Proposed.ESTIMATES
    proposed, why = label_next.chosen(0.85, 90.0)
    assert proposed is label_next.Proposed.DECODING and why == "85.0 % right when checked, the decoding 90.0 % " \
                                                             "cross-validated"
