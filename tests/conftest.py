"""Shared fixtures: the real data folder beside the repository and workdirs holding collected frames."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from stages import collect

REPO = Path(__file__).resolve().parents[1]

FETCH_TEST_EPISODES = 4
FETCH_TEST_SEED = 0


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root."""
    return REPO


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` relative to the repository root (read-only real data)."""
    path = REPO.parent / "shared" / "data"
    if not path.is_dir():
        pytest.fail(f"real data not found at {path}")
    return path


@pytest.fixture(scope="session")
def desk_frames_workdir(tmp_path_factory, shared_data) -> Path:
    """A workdir whose frames.parquet is the DESK motion import (22,329 frames); treat it as read-only."""
    workdir = tmp_path_factory.mktemp("desk")
    collect.run(workdir, collect.CollectOptions(env="desk", source=shared_data / "desk-taurus"))
    return workdir


@pytest.fixture(scope="session")
def fetch_frames_workdir(tmp_path_factory) -> Path:
    """A workdir whose frames.parquet holds a few real MuJoCo Fetch episodes; treat it as read-only.

    Tests using it need MuJoCo: mark them ``@pytest.mark.mujoco``.
    """
    workdir = tmp_path_factory.mktemp("fetch")
    options = collect.CollectOptions(env="fetch", episodes=FETCH_TEST_EPISODES, seed=FETCH_TEST_SEED)
    collect.run(workdir, options)
    return workdir


@pytest.fixture(scope="session")
def desk_mln_workdir(tmp_path_factory, desk_frames_workdir) -> Path:
    """DESK frames + predicates + the paper's formulas + learned weights (bare options); read-only."""
    from stages import binarize, formulas, learn_weights

    workdir = tmp_path_factory.mktemp("desk-mln")
    shutil.copy(desk_frames_workdir / "frames.parquet", workdir / "frames.parquet")
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions())
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
    return workdir


@pytest.fixture(scope="session")
def desk_full_workdir(tmp_path_factory, desk_mln_workdir) -> Path:
    """Every artifact of the bare DESK pipeline (lstm trained 2 epochs, conflated, evaluated); read-only."""
    from stages import conflate, eval as evaluate, train

    workdir = tmp_path_factory.mktemp("desk-full")
    for path in desk_mln_workdir.iterdir():
        shutil.copy(path, workdir / path.name)
    train.run(workdir, train.TrainOptions(epochs=2))
    conflate.run(workdir, conflate.ConflateOptions())
    evaluate.run(workdir, evaluate.EvalOptions())
    return workdir


@pytest.fixture(scope="session")
def desk_stream_workdir(tmp_path_factory, desk_frames_workdir) -> Path:
    """DESK with examples/temporal.mln learned (cll), lstm and priorlayer trained in stream mode (3 epochs, a
    validation part held out) and conflated with every decoding: a model a live stream can use; read-only."""
    from stages import binarize, conflate, formulas, learn_weights, train

    workdir = tmp_path_factory.mktemp("desk-stream")
    shutil.copy(desk_frames_workdir / "frames.parquet", workdir / "frames.parquet")
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
    for method in ("lstm", "priorlayer"):
        train.run(workdir, train.TrainOptions(method=method, mode="stream", epochs=3, select="val_accuracy"))
    conflate.run(workdir, conflate.ConflateOptions(decode=("none", "filter", "viterbi")))
    return workdir


@pytest.fixture(scope="session")
def desk_folds_workdir(tmp_path_factory, desk_frames_workdir) -> Path:
    """DESK with examples/temporal.mln learned with 3 folds (learn-weights --folds 3), lstm and priorlayer trained in
    stream mode on the whole training split with 3 fold networks each (2 epochs), conflated with every decoding
    (the network factor's weight learned, every method cross-validated); read-only."""
    from stages import binarize, conflate, formulas, learn_weights, train

    workdir = tmp_path_factory.mktemp("desk-folds")
    shutil.copy(desk_frames_workdir / "frames.parquet", workdir / "frames.parquet")
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions(folds=3))
    for method in ("lstm", "priorlayer"):
        train.run(workdir, train.TrainOptions(method=method, mode="stream", epochs=2, folds=3))
    conflate.run(workdir, conflate.ConflateOptions(decode=("none", "filter", "viterbi")))
    return workdir


@pytest.fixture(scope="session")
def desk_test_recording(tmp_path_factory, desk_frames_workdir) -> Path:
    """The DESK test split as a user's recording: a CSV of frame, label and the three motion channels."""
    import polars as pl

    frames = pl.read_parquet(desk_frames_workdir / "frames.parquet").filter(pl.col("split") == "test")
    path = tmp_path_factory.mktemp("recording") / "desk-test.csv"
    frames.select("frame", "label", "arm_distance", "left_gripper", "right_gripper").write_csv(path)
    return path
