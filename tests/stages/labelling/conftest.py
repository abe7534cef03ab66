"""A workdir fitted on the generated arm's bags (tests/arm_bags.py) with recordings left unlabelled, and a model
file of it that holds both the network and the MLN, for the labelling library's tests."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

SEED = 6300


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> dict:
    """3 labelled bags and 3 unlabelled ones (episode_4: an arm carrying five times the payload, unlike the
    others), fitted with the hand spec and 3 epochs; ``model``: the conflation exported from it."""
    pytest.importorskip("rosbags")
    pytest.importorskip("torch")
    import arm_bags
    from typer.testing import CliRunner

    from mlnseq_cli.main import app

    root = tmp_path_factory.mktemp("labelling")
    robot = arm_bags.ROBOTS["panda"]
    heavy = replace(robot, payload=(5.0, 8.0))
    for k in range(6):
        arm = heavy if k == 3 else robot
        arm_bags.write_bag(root / "bags" / f"episode_{k + 1}", arm, SEED + k, phases=k in (0, 1, 2))
    (root / "hand.toml").write_text(arm_bags.hand_spec("panda"))
    workdir, model = root / "work", root / "conflation.mlnseq"
    runner = CliRunner()
    done = runner.invoke(app, ["fit", "--env", "rosbag", "--source", str(root / "bags"), "--label-topic", "/phase",
                               "--spec", str(root / "hand.toml"), "--epochs", "3", "-w", str(workdir)])
    assert done.exit_code == 0, done.output
    done = runner.invoke(app, ["export", "-w", str(workdir), "--method", "conflation", "--decode", "filter", "-o",
                               str(model)])
    assert done.exit_code == 0, done.output
    return {"root": root, "workdir": workdir, "model": model, "bags": root / "bags"}


