"""`mlnseq fit` on a --source where some recordings have no labels: they never enter a split, a fold or a figure
(the predictions and cross-validated figures are those of the labelled recordings alone), and with fewer than
FEW_LABELLED labelled recordings every one of them trains. On the generated arm's bags (tests/arm_bags.py)."""

from __future__ import annotations

from pathlib import Path

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


def test_unlabelled_recordings_change_no_figure(bags, tmp_path):
    said = fit(bags, "mixed", tmp_path / "mixed")
    fit(bags, "labelled", tmp_path / "labelled")
    assert "2 recordings without labels: used unlabelled" in said
    assert "4 labelled recordings, fewer than 5: every one trains, none is spent on a test split" in said
    mixed, mixed_meta = artifacts.read_table(tmp_path / "mixed" / artifacts.PREDICTIONS, "predictions")
    alone, alone_meta = artifacts.read_table(tmp_path / "labelled" / artifacts.PREDICTIONS, "predictions")
    assert set(mixed["split"]) == {"train"} and mixed["episode"].unique().sort().to_list() == [1, 2, 4, 5]
    assert mixed.drop("episode").equals(alone.drop("episode"))
    assert mixed_meta["cross_validation"] == alone_meta["cross_validation"]
    ranked = pl.read_csv(tmp_path / "mixed" / artifacts.LABEL_NEXT)
    assert sorted(ranked["episode"]) == ["episode_1", "episode_4"] and ranked["rank"].to_list() == [1, 2]
    first = ranked.row(0, named=True)
    assert f"label next ({tmp_path / 'mixed' / artifacts.LABEL_NEXT}" in said and f"1. {first['episode']}: " in said
    phases = pl.read_csv(tmp_path / "mixed" / artifacts.UNLABELLED_INTERVALS)
    assert set(phases["episode"]) == {"episode_1", "episode_4"} and phases.columns == ["episode", "start", "end",
                                                                                        "label"]
    assert not (tmp_path / "labelled" / artifacts.LABEL_NEXT).exists()  # nothing unlabelled: nothing ranked
    scored = CliRunner().invoke(app, ["eval", "-w", str(tmp_path / "mixed")])  # no test split to score
    assert scored.exit_code != 0 and "--holdout share keeps one" in scored.stderr


def test_one_labelled_recording_beside_unlabelled_ones_is_not_cut_into_blocks(bags, tmp_path):
    import shutil

    one = tmp_path / "one"
    for name in ("episode_1", "episode_2", "episode_4"):  # episode_2 alone has /phase
        shutil.copytree(bags / "mixed" / name, one / name)
    (tmp_path / "hand.toml").write_text((bags / "hand.toml").read_text())
    said = fit(tmp_path, "one", tmp_path / "work")
    assert "1 labelled recording, fewer than 5" in said  # no blocks holding whole phases out of training:
    assert "folds: none (one training recording whose task never restarts" in said  # nothing cross-validated
