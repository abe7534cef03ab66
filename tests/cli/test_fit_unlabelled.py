"""`mlnseq fit` on a --source where some recordings have no labels: they are labelled by alignment to the labelled
ones and train (never in a test split), ranked by what labelling each would teach; with fewer than FEW_LABELLED
labelled recordings every one of them trains. On the generated arm's bags (tests/arm_bags.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq.catalog import artifacts
from mlnseq_cli.main import app

pytest.importorskip("rosbags")
pytest.importorskip("torch")


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> Path:
    import arm_bags

    root = tmp_path_factory.mktemp("fit-unlabelled")
    robot = arm_bags.ROBOTS["panda"]
    for k in range(6):
        arm_bags.write_bag(root / "mixed" / f"episode_{k + 1}", robot, 4100 + k, phases=k not in (0, 3))
        if k not in (0, 3):
            arm_bags.write_bag(root / "labelled" / f"episode_{k + 1}", robot, 4100 + k)
    (root / "hand.toml").write_text(arm_bags.hand_spec("panda"))
    return root


def fit(bags: Path, source: str, workdir: Path) -> str:
    done = CliRunner().invoke(app, ["fit", "--env", "rosbag", "--source", str(bags / source), "--label-topic", "/phase",
                                    "--spec", str(bags / "hand.toml"), "--epochs", "3", "-w", str(workdir)])
    assert done.exit_code == 0, done.output
    return " ".join(done.output.split())


def test_recordings_without_labels_are_labelled_by_alignment_and_ranked(bags, tmp_path):
    import arm_bags

    said = fit(bags, "mixed", tmp_path / "mixed")
    assert ("2 recordings without labels labelled by aligning each to the 4 labelled training recordings; aligned to "
            "each other, the labelled ones come out") in said
    assert "4 labelled recordings, fewer than 5: every one trains, none is spent on a test split" in said
    frames, meta = artifacts.read_table(tmp_path / "mixed" / artifacts.FRAMES, "frames")
    assert set(frames["split"]) == {"train"} and meta["unlabelled_episodes"] == ["episode_1", "episode_4"]
    for episode, k in ((0, 0), (3, 3)):  # their labels by alignment against the phases the bags were made with
        names = np.asarray(meta["classes"])[frames.filter(pl.col("episode") == episode)["label"].to_numpy()]
        truth = np.asarray(arm_bags.PHASES)[arm_bags.episode_signals(arm_bags.ROBOTS["panda"], 4100 + k)["phase"]]
        assert len(names) == len(truth) and np.mean(names == truth) > 0.93
    predictions = pl.read_parquet(tmp_path / "mixed" / artifacts.PREDICTIONS)
    assert predictions["episode"].unique().sort().to_list() == [0, 1, 2, 3, 4, 5]  # they train and are in the folds
    ranked = pl.read_csv(tmp_path / "mixed" / artifacts.LABEL_NEXT)
    assert sorted(ranked["episode"]) == ["episode_1", "episode_4"] and ranked["rank"].to_list() == [1, 2]
    first = ranked.row(0, named=True)
    assert f"label next ({tmp_path / 'mixed' / artifacts.LABEL_NEXT}" in said and f"1. {first['episode']}: " in said
    phases = pl.read_csv(tmp_path / "mixed" / artifacts.UNLABELLED_INTERVALS)
    assert set(phases["episode"]) == {"episode_1", "episode_4"} and phases.columns == ["episode", "start", "end",
                                                                                        "label", "unit"]
    labelled = frames.filter(~pl.col("episode").is_in([0, 3]))
    shortest = min(labelled.group_by("episode").agg(pl.col("label").rle().struct.field("len").min())["len"])
    assert (phases["end"] - phases["start"] + 1).min() >= shortest // 2  # no flicker: nothing under half a phase
    for _, own in phases.group_by("episode"):  # each proposal: the 5 phases once each, in order
        assert own.sort("start")["label"].to_list() == list(arm_bags.PHASES)
    estimated = frames.filter(pl.col("episode").is_in([0, 3])).height
    assert f"the folds score against {estimated:,} labelled frames fit estimated ({estimated:,} by alignment)" in said
    scored = CliRunner().invoke(app, ["eval", "-w", str(tmp_path / "mixed")])  # no test split to score
    assert scored.exit_code != 0 and "--holdout share keeps one" in scored.stderr
    said = fit(bags, "labelled", tmp_path / "mixed")  # a refit with nothing unlabelled: nothing ranked, none left
    assert not (tmp_path / "mixed" / artifacts.LABEL_NEXT).exists()
    assert not (tmp_path / "mixed" / artifacts.UNLABELLED_INTERVALS).exists() and "estimated" not in said


def test_one_labelled_recording_alone_is_not_cut_into_blocks_and_with_others_they_are_the_folds(bags, tmp_path):
    import shutil

    for name in ("episode_1", "episode_2", "episode_4"):  # episode_2 alone has /phase
        shutil.copytree(bags / "mixed" / name, tmp_path / "three" / name)
    shutil.copytree(bags / "mixed" / "episode_2", tmp_path / "one" / "episode_2")
    (tmp_path / "hand.toml").write_text((bags / "hand.toml").read_text())
    said = fit(tmp_path, "one", tmp_path / "one-work")
    assert "1 labelled recording, fewer than 5" in said  # no blocks holding whole phases out of training:
    assert "folds: none (one training recording whose task never restarts" in said  # nothing cross-validated
    said = fit(tmp_path, "three", tmp_path / "three-work")
    assert "2 recordings without labels labelled by aligning each to the 1 labelled training recording:" in said
    assert "3 folds by episode" in said


def test_where_every_recording_is_clicked_the_clicked_ones_are_ranked_to_label_one_on_every_frame(bags, tmp_path):
    import arm_bags

    seeds = {f"episode_{k + 1}": 4100 + k for k in (1, 2, 4, 5)}  # the bags of "labelled"
    (tmp_path / "clicks.csv").write_text("\n".join(arm_bags.clicks(arm_bags.ROBOTS["panda"], seeds)) + "\n")
    done = CliRunner().invoke(app, ["fit", "--env", "rosbag", "--source", str(bags / "labelled"), "--labels",
                                    str(tmp_path / "clicks.csv"), "--spec", str(bags / "hand.toml"), "--epochs", "3",
                                    "-w", str(tmp_path / "clicked")])
    assert done.exit_code == 0, done.output
    said = " ".join(done.output.split())
    assert f"label one on every frame next, to say where the clicked ones' phases begin ({tmp_path / 'clicked'}" in said
    ranked = pl.read_csv(tmp_path / "clicked" / artifacts.LABEL_NEXT)
    assert sorted(ranked["episode"]) == sorted(seeds) and ranked["rank"].to_list() == [1, 2, 3, 4]
    assert ranked["distance"].is_finite().all() and f"1. {ranked['episode'][0]}: " in said
    assert ("only clicks label the training recordings: these figures cannot be trusted until one recording is "
            "labelled on every frame") in said
    assert "from the clicks' fill fit trained on: nothing checks them against the decoding" in said
    frames = artifacts.read_table(tmp_path / "clicked" / artifacts.FRAMES, "frames")[0]
    phases = pl.read_csv(tmp_path / "clicked" / artifacts.UNLABELLED_INTERVALS)
    assert (phases["end"] - phases["start"] + 1).sum() == frames.height  # each one's predicted phases, to correct
    first = ranked["episode"][0]  # labelled on every frame instead (its proposal as it is), the others clicked
    clicked = [f"{e},,,{f},{c}" for e, f, c in pl.read_csv(tmp_path / "clicks.csv").iter_rows() if e != first]
    own = phases.filter(pl.col("episode") == first).drop("unit")
    labelled = [f"{e},{s},{t},,{c}" for e, s, t, c in own.iter_rows()]
    (tmp_path / "mixed.csv").write_text("\n".join(["episode,start,end,frame,label", *clicked, *labelled]) + "\n")
    done = CliRunner().invoke(app, ["fit", "--env", "rosbag", "--source", str(bags / "labelled"), "--labels",
                                    str(tmp_path / "mixed.csv"), "--labels-unit", "frames", "--spec",
                                    str(bags / "hand.toml"), "--epochs", "3", "-w", str(tmp_path / "one-labelled")])
    assert done.exit_code == 0, done.output
    assert "aligned in time to the 1 training recording labelled on every frame" in " ".join(done.output.split())
    assert not (tmp_path / "one-labelled" / artifacts.LABEL_NEXT).exists()  # nothing left to rank
