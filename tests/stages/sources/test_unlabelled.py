"""Recordings without labels in the same --source (a bag without /phase, a table without the label column, an
episode --labels does not name that has no labels of its own): read unlabelled, in a split of their own with a null
label, said in one line; and with few labelled recordings, every one of them trains (Holdout.UNLESS_FEW). On the
generated arm's bags (tests/arm_bags.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq import collect
from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.parts import Part
from mlnseq.choosing import folds as folding
from mlnseq.sources import SourceOptions
from mlnseq.sources.splits import FEW_LABELLED, Holdout
from mlnseq_cli.main import app

pytest.importorskip("rosbags")

SEED = 4100  # the bags' seeds: SEED + k


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    """``mixed``: bags 1 and 4 without /phase, 2, 3, 5 and 6 with it; ``labelled``: bags 2, 3, 5, 6 alone."""
    import arm_bags

    root = tmp_path_factory.mktemp("unlabelled")
    robot = arm_bags.ROBOTS["panda"]
    for k in range(6):
        arm_bags.write_bag(root / "mixed" / f"episode_{k + 1}", robot, SEED + k, phases=k not in (0, 3))
        if k not in (0, 3):
            arm_bags.write_bag(root / "labelled" / f"episode_{k + 1}", robot, SEED + k)
    return {"mixed": root / "mixed", "labelled": root / "labelled"}


def bag_frames(source: Path, holdout: Holdout = Holdout.SHARE, **options) -> collect.Collected:
    return collect.collect(collect.CollectOptions(env="rosbag", source=source, holdout=holdout,
                                                  recordings=SourceOptions(label_topic="/phase", **options)))


def test_bags_without_the_label_topic_are_read_unlabelled(bags):
    mixed, alone = bag_frames(bags["mixed"]), bag_frames(bags["labelled"])
    frames = mixed.frames
    bare = frames.filter(pl.col("split") == Part.UNLABELLED)
    assert bare["episode"].unique().sort().to_list() == [0, 3] and bare["label"].null_count() == bare.height
    assert mixed.meta["unlabelled_episodes"] == ["episode_1", "episode_4"]
    assert "2 recordings without labels: used unlabelled (never in a test split or a score)" in mixed.meta["notes"]
    labelled = artifacts.labelled(frames)
    assert labelled.drop("episode").equals(alone.frames.drop("episode"))  # the labelled frames and split as alone
    assert labelled["label"].null_count() == 0 and set(labelled["split"]) == {"train", "test"}


def test_frames_with_unlabelled_recordings_are_written_and_read_back(bags, tmp_path):
    _, collected = collect.run(tmp_path, collect.CollectOptions(env="rosbag", source=bags["mixed"],
                                                                recordings=SourceOptions(label_topic="/phase")))
    frames, _ = artifacts.read_table(tmp_path / artifacts.FRAMES, "frames")
    assert frames.equals(collected.frames) and (frames["split"] == Part.UNLABELLED).sum() > 0
    bad = frames.with_columns(label=pl.col("label").fill_null(1))  # a label on an unlabelled row
    artifacts.write_table(bad, tmp_path / "bad" / artifacts.FRAMES, "frames", {"classes": collected.meta["classes"]})
    with pytest.raises(BadInput, match="column 'label' is set on an unlabelled row at row 0"):
        artifacts.read_table(tmp_path / "bad" / artifacts.FRAMES, "frames")


def test_collect_says_the_unlabelled_recordings_in_one_line(bags, tmp_path):
    done = CliRunner().invoke(app, ["collect", "--env", "rosbag", "--source", str(bags["mixed"]), "--label-topic",
                                    "/phase", "-w", str(tmp_path)])
    assert done.exit_code == 0, done.output
    text = " ".join(done.output.split())
    assert "unlabelled, 22 features" in text and "note: 2 recordings without labels: used unlabelled" in text


def test_a_source_without_any_label_is_refused_as_before(bags):
    with pytest.raises(BadInput, match=r"episode_1: no topic '/nothing'; its topics are"):
        collect.collect(collect.CollectOptions(env="rosbag", source=bags["mixed"],
                                               recordings=SourceOptions(label_topic="/nothing")))


def table_of(bags, tmp_path: Path) -> Path:
    """The mixed bags as CSV files: the unlabelled ones without the label column."""
    frames = bag_frames(bags["mixed"]).frames
    folder = tmp_path / "tables"
    folder.mkdir()
    for episode in range(6):
        rows = frames.filter(pl.col("episode") == episode).drop("episode", "split")
        if rows["label"].null_count():
            rows = rows.drop("label")
        rows.write_csv(folder / f"episode_{episode + 1}.csv")
    return folder


def test_tables_without_the_label_column_and_episodes_absent_from_labels_are_unlabelled(bags, tmp_path):
    folder = table_of(bags, tmp_path)
    read = collect.collect(collect.CollectOptions(env="table", source=folder))
    assert read.meta["unlabelled_episodes"] == ["episode_1", "episode_4"]
    assert artifacts.labelled(read.frames).height == bag_frames(bags["labelled"]).frames.height
    labels = tmp_path / "labels.csv"  # intervals for episode 2 alone: 3, 5, 6 keep their own label column
    labels.write_text("episode,start,end,label\nepisode_2,0,99,0\nepisode_2,100,200,1\n")
    relabelled = collect.collect(collect.CollectOptions(env="table", source=folder, recordings=SourceOptions(
        labels=labels)))
    assert relabelled.meta["unlabelled_episodes"] == ["episode_1", "episode_4"]
    names = {name: np.asarray(found.meta["classes"])[artifacts.labelled(found.frames)["label"].to_numpy()]
             for name, found in (("read", read), ("relabelled", relabelled))}
    by_episode = {name: artifacts.labelled(found.frames)["episode"].to_numpy()
                  for name, found in (("read", read), ("relabelled", relabelled))}
    second = by_episode["relabelled"] == 1
    assert second.sum() == 201 and set(names["relabelled"][second]) == {"0", "1"}  # the file's, on its frames
    for episode in (2, 4, 5):  # episodes 3, 5, 6: their own labels, frame for frame
        assert list(names["relabelled"][by_episode["relabelled"] == episode]) == list(
            names["read"][by_episode["read"] == episode])


def test_a_labels_file_naming_one_bag_keeps_the_label_topic_of_the_others(bags, tmp_path):
    """The loop label_next.csv starts: a recording fit proposed, labelled and given back with --labels; the bags
    labelled by /phase keep their labels, and the one the file does not name and has no /phase stays unlabelled."""
    import arm_bags

    phase = arm_bags.episode_signals(arm_bags.ROBOTS["panda"], SEED)["phase"]
    change = np.r_[0, np.flatnonzero(phase[1:] != phase[:-1]) + 1, len(phase)]
    labels = tmp_path / "episode_1.csv"
    labels.write_text("episode,start,end,label\n" + "".join(
        f"episode_1,{a},{b - 1},{arm_bags.PHASES[phase[a]]}\n" for a, b in zip(change, change[1:])))
    given = bag_frames(bags["mixed"], labels=labels, labels_unit="frames")
    assert given.meta["unlabelled_episodes"] == ["episode_4"]
    names = np.asarray(given.meta["classes"])
    first = given.frames.filter(pl.col("episode") == 0)
    assert list(names[first["label"].to_numpy()]) == [arm_bags.PHASES[k] for k in phase]
    topic = bag_frames(bags["mixed"])
    for episode in (1, 2, 4, 5):
        own = given.frames.filter(pl.col("episode") == episode)["label"].to_numpy()
        read = topic.frames.filter(pl.col("episode") == episode)["label"].to_numpy()
        assert list(names[own]) == list(np.asarray(topic.meta["classes"])[read])


def test_a_labels_file_naming_no_recording_is_refused_in_one_line(bags, tmp_path):
    labels = tmp_path / "labels.csv"
    labels.write_text("episode,start,end,label\nrun_1,0,99,reach\nrun_1,100,200,grasp\n")
    with pytest.raises(BadInput, match=r"^--labels .*labels.csv names no recording of --source \(its episodes: "
                                       r"run_1; the recordings': episode_1, episode_2, .*\)"):
        bag_frames(bags["mixed"], labels=labels, labels_unit="frames")


def test_with_few_labelled_recordings_every_one_trains_and_folds_are_recordings(bags):
    few = bag_frames(bags["mixed"], Holdout.UNLESS_FEW).frames  # 4 labelled < FEW_LABELLED
    assert FEW_LABELLED == 5
    labelled = artifacts.labelled(few)
    assert set(labelled["split"]) == {"train"} and (few["split"] == Part.UNLABELLED).sum() > 0
    episodes, splits, labels = (labelled[c].to_numpy() for c in ("episode", "split", "label"))
    k = folding.suggested(episodes, splits)
    assert k == 4 and folding.assign(episodes, splits, labels, k).kind == "episodes"
    one = artifacts.labelled(few).filter(pl.col("episode") == 1)  # one recording of one run of the task:
    episodes, splits, labels = (one[c].to_numpy() for c in ("episode", "split", "label"))
    assert folding.suggested(episodes, splits) == 5 and folding.suggested(episodes, splits, labels=labels) == 0
    shared = bag_frames(bags["mixed"], Holdout.SHARE).frames  # collect's own default keeps 70 % of them
    assert set(artifacts.labelled(shared)["split"]) == {"train", "test"}


def test_from_five_labelled_recordings_a_test_split_is_kept(bags, tmp_path):
    import shutil

    import arm_bags

    five = tmp_path / "five"
    shutil.copytree(bags["labelled"], five)
    arm_bags.write_bag(five / "episode_9", arm_bags.ROBOTS["panda"], SEED + 9)
    frames = bag_frames(five, Holdout.UNLESS_FEW).frames
    assert frames.equals(bag_frames(five, Holdout.SHARE).frames)
    assert np.unique(frames.filter(pl.col("split") == "test")["episode"]).tolist() == [4]

