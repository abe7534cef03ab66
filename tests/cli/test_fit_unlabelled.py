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
    first = ranked["episode"][0]  # labelled on every frame in `mlnseq review -w` (its proposal saved as it is)
    truth = np.asarray(arm_bags.PHASES)[arm_bags.episode_signals(arm_bags.ROBOTS["panda"], seeds[first])["phase"]]
    saved = reviewed_and_saved(tmp_path, "clicked", first)
    table = pl.read_csv(saved)  # the fit's clicks carried, and the saved recording's intervals, each with its unit
    assert set(table.filter(pl.col("frame").is_not_null())["episode"]) == set(seeds) - {first}
    assert table.filter(pl.col("episode") == first)["unit"].unique().to_list() == ["seconds"]  # a bag's unit
    done = CliRunner().invoke(app, ["fit", "--env", "rosbag", "--source", str(bags / "labelled"), "--labels",
                                    str(saved), "--spec", str(bags / "hand.toml"), "--epochs", "3",
                                    "-w", str(tmp_path / "clicked")])  # the same workdir, no --labels-unit
    assert done.exit_code == 0, done.output
    said = " ".join(done.output.split())
    assert "aligned in time to the 1 training recording labelled on every frame" in said
    assert not (tmp_path / "clicked" / artifacts.LABEL_NEXT).exists()  # nothing left to rank, nothing stale
    assert "cannot be trusted" not in said and "fit estimated (" in said  # the clicked ones' fill still estimated
    frames, meta = artifacts.read_table(tmp_path / "clicked" / artifacts.FRAMES, "frames")
    mine = frames.filter(pl.col("episode") == meta["episode_names"].index(first))["label"].to_numpy()
    assert np.mean(np.asarray(meta["classes"])[mine] == truth) > 0.9  # the clicks' fill, as saved in the page


def reviewed_and_saved(root: Path, workdir: str, episode: str) -> Path:
    """`mlnseq review MODEL -w WORKDIR` served, ``episode`` saved with the band the page starts it with (fit's
    proposal), as a user who accepts it presses Ctrl+S; the labels file it saved (WORKDIR.labels.csv)."""
    import json

    from review_browser import request, served

    with served(root / workdir / "model.mlnseq", "-w", workdir, cwd=root) as (url, printed):
        rows = json.loads(request(url, "GET", "/api/recordings", {})[1])["recordings"]
        index = next(r["index"] for r in rows if r["id"] == episode)
        view = json.loads(request(url, "GET", f"/api/recording?index={index}", {})[1])
        assert rows[0]["id"] == episode and rows[0]["origin"] == "estimated between your clicks"
        body = json.dumps({"index": index, "segments": [[a, b, view["classes"][k]] for a, b, k in view["proposal"]]})
        status, answer = request(url, "POST", "/api/save", {"Content-Type": "application/json",
                                                            "Content-Length": str(len(body))}, body.encode())
        assert status == 200, answer
    assert any(line.startswith(f"review: saved {episode} ") for line in printed)
    return root / f"{workdir}.labels.csv"
