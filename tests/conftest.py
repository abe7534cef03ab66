"""Shared fixtures: the real data folder beside the repository and workdirs holding collected frames."""

from __future__ import annotations

import fcntl
import os
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest

from mlnseq import collect

REPO = Path(__file__).resolve().parents[1]

FETCH_TEST_EPISODES = 4
FETCH_TEST_SEED = 0
# The eight longest files, the longest first (measured with pytest's --durations): `make test` hands whole files to
# its two workers in the order collected (--no-loadscope-reorder: xdist's own order, the most tests first, started
# the review day's one-test file last), and a long file started last leaves the other worker idle at the end.
LONGEST_FIRST = ("tests/docs/test_docs_run.py", "tests/stages/sweeps/test_sweep_slurm.py", "tests/test_benchmarks.py",
                 "tests/cli/test_review_day.py", "tests/test_reproduce.py", "tests/cli/test_review_cli.py",
                 "tests/stages/pipeline/test_fit_parts.py", "tests/test_wheel.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The files of ``LONGEST_FIRST`` first, in its order; the rest as collected."""
    rank = {path: k for k, path in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))


# Files whose tests compare with one costly run of a session fixture: the interrupted local sweep (the SLURM sweep's
# reference, and the full disk's) goes to the worker of the SLURM tests' file, which makes it while its cluster runs;
# the docs' recordings page's check to the worker that runs the docs' pages. So each run is made once. (The local fit
# that fit's parts and fit through SLURM compare with, ``arm_fit``, is made once by ``made_once`` instead: the parts'
# tests run on the other worker while the cluster waits.)
ONE_WORKER = {path: "tests/stages/sweeps/test_sweep_slurm.py" for path in (
    "tests/stages/sweeps/test_sweep_local.py", "tests/stages/sweeps/test_sweep_disk.py",
    "tests/stages/sweeps/test_sweep_file.py")} | {
    "tests/docs/test_docs_recordings.py": "tests/docs/test_docs_run.py"}


def pytest_xdist_make_scheduler(config, log):
    """Under ``--dist loadfile``: whole files to a worker, the files of ``ONE_WORKER`` to the same one."""
    if config.getoption("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SharedFixtures(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            scope = super()._split_scope(nodeid)
            return ONE_WORKER.get(scope, scope)

    return SharedFixtures(config, log)


Made = TypeVar("Made")


def made_once(tmp_path_factory, name: str, make: Callable[[Path], Made]) -> Made:
    """What ``make(folder)`` returns, made by the first of the run's workers (pytest-xdist) that asks and read back by
    the others, who wait for it: a session fixture's workdir is made once per run, not once per worker. Its files are
    read-only to every test, as each fixture says."""
    root = tmp_path_factory.getbasetemp()
    root = root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root  # the run's folder, above each worker's
    folder, result = root / f"made-{name}", root / f"made-{name}.pickle"
    with open(root / f"made-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not result.exists():
            shutil.rmtree(folder, ignore_errors=True)  # what a worker that failed making it left
            folder.mkdir()
            made = make(folder)
            result.write_bytes(pickle.dumps(made))
            return made
    return pickle.loads(result.read_bytes())


@pytest.fixture(scope="session")
def arm_fit_args(tmp_path_factory) -> list[str]:
    """`mlnseq fit`'s arguments but -w for six short episodes of the generated arm (tests/arm_bags.py, 15 Hz) as one
    table, 2 epochs: what ``arm_fit`` runs, and fit's parts and fit through SLURM run again."""
    import arm_bags

    def make(folder: Path) -> list[str]:
        table = arm_bags.write_table(folder / "arm.parquet", seed=9, episodes=6, rate=15.0)
        return ["fit", "--env", "table", "--source", str(table), "--epochs", "2"]

    return made_once(tmp_path_factory, "arm-table", make)


@pytest.fixture(scope="session")
def arm_fit(tmp_path_factory, arm_fit_args) -> dict:
    """``arm_fit_args`` run locally as ``-w local``: the model fit's parts and fit through SLURM must write alike;
    read-only. {workdir, stdout}."""
    import subprocess
    import sys

    def make(folder: Path) -> dict:
        done = subprocess.run([str(Path(sys.executable).with_name("mlnseq")), *arm_fit_args, "-w", "local"],
                              cwd=folder, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-3000:]
        return {"workdir": folder / "local", "stdout": done.stdout}

    return made_once(tmp_path_factory, "arm-fit", make)


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
    def make(workdir: Path) -> Path:
        collect.run(workdir, collect.CollectOptions(env="desk", source=shared_data / "desk-taurus"))
        return workdir

    return made_once(tmp_path_factory, "desk", make)


@pytest.fixture(scope="session")
def fetch_frames_workdir(tmp_path_factory) -> Path:
    """A workdir whose frames.parquet holds a few real MuJoCo Fetch episodes; treat it as read-only.

    Tests using it need MuJoCo: mark them ``@pytest.mark.mujoco``.
    """
    def make(workdir: Path) -> Path:
        collect.run(workdir, collect.CollectOptions(env="fetch", episodes=FETCH_TEST_EPISODES, seed=FETCH_TEST_SEED))
        return workdir

    return made_once(tmp_path_factory, "fetch", make)


@pytest.fixture(scope="session")
def desk_mln_workdir(tmp_path_factory, desk_frames_workdir) -> Path:
    """DESK frames + predicates + the paper's formulas + learned weights (bare options); read-only."""
    from mlnseq import binarize, formulas, learn_weights

    def make(workdir: Path) -> Path:
        shutil.copy(desk_frames_workdir / "frames.parquet", workdir / "frames.parquet")
        binarize.run(workdir, binarize.BinarizeOptions())
        formulas.run(workdir, formulas.FormulasOptions())
        learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
        return workdir

    return made_once(tmp_path_factory, "desk-mln", make)


@pytest.fixture(scope="session")
def desk_full_workdir(tmp_path_factory, desk_mln_workdir) -> Path:
    """Every artifact of the bare DESK pipeline (lstm trained 2 epochs, conflated, evaluated); read-only."""
    from mlnseq import conflate, eval as evaluate, train

    def make(workdir: Path) -> Path:
        for path in desk_mln_workdir.iterdir():
            shutil.copy(path, workdir / path.name)
        train.run(workdir, train.TrainOptions(epochs=2))
        conflate.run(workdir, conflate.ConflateOptions())
        evaluate.run(workdir, evaluate.EvalOptions())
        return workdir

    return made_once(tmp_path_factory, "desk-full", make)


@pytest.fixture(scope="session")
def desk_stream_workdir(tmp_path_factory, desk_frames_workdir) -> Path:
    """DESK with examples/temporal.mln learned (cll), lstm and priorlayer trained in stream mode (3 epochs, a
    validation part held out) and conflated with every decoding: a model a live stream can use; read-only."""
    from mlnseq import binarize, conflate, formulas, learn_weights, train

    def make(workdir: Path) -> Path:
        shutil.copy(desk_frames_workdir / "frames.parquet", workdir / "frames.parquet")
        binarize.run(workdir, binarize.BinarizeOptions())
        formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
        learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
        for method in ("lstm", "priorlayer"):
            train.run(workdir, train.TrainOptions(method=method, mode="stream", epochs=3, select="val_accuracy"))
        conflate.run(workdir, conflate.ConflateOptions(decode=("none", "filter", "viterbi")))
        return workdir

    return made_once(tmp_path_factory, "desk-stream", make)


@pytest.fixture(scope="session")
def desk_folds_workdir(tmp_path_factory, desk_frames_workdir) -> Path:
    """DESK with examples/temporal.mln learned with 3 folds (learn-weights --folds 3), lstm and priorlayer trained in
    stream mode on the whole training split with 3 fold networks each (2 epochs), conflated with every decoding
    (the network factor's weight learned, every method cross-validated); read-only."""
    from mlnseq import binarize, conflate, formulas, learn_weights, train

    def make(workdir: Path) -> Path:
        shutil.copy(desk_frames_workdir / "frames.parquet", workdir / "frames.parquet")
        binarize.run(workdir, binarize.BinarizeOptions())
        formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
        learn_weights.run(workdir, learn_weights.LearnWeightsOptions(folds=3))
        for method in ("lstm", "priorlayer"):
            train.run(workdir, train.TrainOptions(method=method, mode="stream", epochs=2, folds=3))
        conflate.run(workdir, conflate.ConflateOptions(decode=("none", "filter", "viterbi")))
        return workdir

    return made_once(tmp_path_factory, "desk-folds", make)


@pytest.fixture(scope="session")
def desk_test_recording(tmp_path_factory, desk_frames_workdir) -> Path:
    """The DESK test split as a user's recording: a CSV of frame, label and the three motion channels."""
    import polars as pl

    frames = pl.read_parquet(desk_frames_workdir / "frames.parquet").filter(pl.col("split") == "test")
    path = tmp_path_factory.mktemp("recording") / "desk-test.csv"
    frames.select("frame", "label", "arm_distance", "left_gripper", "right_gripper").write_csv(path)
    return path


@pytest.fixture(scope="session")
def own_data_glitch(tmp_path_factory) -> dict[str, Path]:
    """The own-data example's recordings (examples/own-data/make_data.py) with a sensor glitch in a test trial:
    three lift frames of trial 11 read as held still and loaded (a release, by a hard rule) then closed and free
    (a grasp, by another), so the order's hard rules leave the third no possible class. Its workdir has
    robot.mln plus those two hard rules learned, and an ``mln`` filter model: {csv, workdir, model, frame}."""
    import subprocess
    import sys

    import polars as pl

    from mlnseq import binarize, export, formulas, learn_weights
    from mlnseq.sources.recording import TableColumns

    def make(folder: Path):
        example = REPO / "examples" / "own-data"
        for name in ("make_data.py", "robot.binarize.toml", "robot.mln"):
            shutil.copy(example / name, folder / name)
        subprocess.run([sys.executable, "make_data.py"], cwd=folder, check=True, capture_output=True)
        recordings = pl.read_csv(folder / "recordings.csv").with_row_index("row")
        lift = recordings.filter((pl.col("trial") == 11) & (pl.col("phase") == "lift"))["row"].to_list()
        g0, g1, g2 = lift[5:8]
        z = recordings["ee_z"][g0 - 1]
        glitch = {g0: (z, 50.0, 3.0), g1: (z, 50.0, 3.0), g2: (z, 20.0, 0.0)}
        rows = recordings["row"].to_list()
        values = {name: [glitch[r][i] if r in glitch else v for r, v in zip(rows, recordings[name].to_list())]
                  for i, name in enumerate(("ee_z", "gripper_mm", "wrist_force"))}
        csv = folder / "glitch.csv"
        recordings.drop("row").with_columns(pl.Series(k, v) for k, v in values.items()).write_csv(csv)
        spec = folder / "glitch.mln"
        spec.write_text((folder / "robot.mln").read_text() + '\nHas("hold_closed_free", p) => Topic("grasp", p).\n'
                        'Has("ee_z_static", p) ^ Has("hold_static_loaded", p) => Topic("release", p).\n')
        workdir = folder / "work"
        columns = TableColumns(label="phase", episode="trial", time="t",
                               classes=("approach", "grasp", "lift", "release"))
        collect.run(workdir, collect.CollectOptions(env="table", source=csv, columns=columns))
        binarize.run(workdir, binarize.BinarizeOptions(spec=folder / "robot.binarize.toml"))
        formulas.run(workdir, formulas.FormulasOptions(spec=spec))
        learn_weights.run(workdir, learn_weights.LearnWeightsOptions(formulas=workdir / "formulas.mln"))
        model = export.run(workdir, export.ExportOptions(method="mln", decode="filter",
                                                         output=folder / "mln.mlnseq")).path
        frame = g2 - recordings.filter(pl.col("trial") == 11)["row"][0]
        return {"csv": csv, "workdir": workdir, "model": model, "frame": frame}

    return made_once(tmp_path_factory, "own-data-glitch", make)


@pytest.fixture(scope="session")
def joint_state_model(tmp_path_factory, shared_data) -> dict:
    """An lstm (stream mode, 40 epochs: six classes on the live rows) trained on a ROS 1 bag of DESK's arm as
    /joint_states at 100 Hz (the first 1,000 frames, tests/ros_episode.py) and exported: {model, live}, with
    ``live`` the other 405 frames' rows."""
    import ros_episode

    def make(folder: Path):
        model, rows, workdir = ros_episode.trained_model(folder, shared_data)
        return {"model": model, "live": rows[ros_episode.TRAIN_FRAMES:], "workdir": workdir}

    return made_once(tmp_path_factory, "joint-states", make)


@pytest.fixture(scope="session")
def lagged_joint_state_model(tmp_path_factory, joint_state_model) -> Path:
    """joint_state_model's lstm with a lagged decoder: a suggested spec, its formulas and weights, conflated with
    smooth at lag 5 and exported as lstm+smooth@5 (a live feed holds 5 frames back); read-only."""
    from mlnseq import binarize, conflate, export, formulas, learn_weights

    def make(folder: Path):
        workdir = folder / "work"
        shutil.copytree(joint_state_model["workdir"], workdir)
        binarize.run(workdir, binarize.BinarizeOptions(suggest=workdir / "suggested.binarize.toml"))
        formulas.run(workdir, formulas.FormulasOptions())
        learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
        conflate.run(workdir, conflate.ConflateOptions(decode=("smooth",), lags=(5,)))
        return export.run(workdir, export.ExportOptions(method="lstm", decode="smooth", lag=5,
                                                        output=folder / "lstm-smooth.mlnseq")).path

    return made_once(tmp_path_factory, "lagged-joint-states", make)
