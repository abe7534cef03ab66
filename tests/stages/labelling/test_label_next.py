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
    assert all(reason and "(most of 3)" in reason for reason in ranked["reason"])
    lines = proposal.first()
    assert len(lines) == 3 and lines[0].startswith(f"1. {ranked['episode'][0]}: ")


def test_the_recording_unlike_the_labelled_ones_is_the_farthest(proposal):
    ranked = proposal.ranked
    farthest = ranked.sort("distance", descending=True)
    assert farthest["episode"][0] == "episode_4"  # five times the payload: its efforts unlike any labelled one's
    assert farthest["distance"][0] > 1.5 * farthest["distance"][1]


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
    back = collect.collect(collect.CollectOptions(env="rosbag", source=fitted["bags"], recordings=SourceOptions(
        labels=written[1], labels_unit="frames")))
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
