"""The paper authors' published motion codes as a predicates table (for tests and benchmarks).

The DESK files carry an arm-distance code and a left and right gripper code per frame; the
Fetch files one gripper code. The paper's DESK predicates are the three codes and the pair of
gripper codes; Fetch has the gripper code. Each code value becomes one boolean column.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts

ARM = ("static", "increasing", "decreasing")
GRIPPER = ("static", "open", "closed", "opening", "closing")
FETCH_GRIPPER = ("static", "closing", "opening")


def one_hot(codes: np.ndarray, prefix: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    return {f"{prefix}_{name}": codes == value for value, name in enumerate(names)}


def predicates_table(
    columns: dict[str, dict[str, np.ndarray]], labels: np.ndarray, splits: np.ndarray, episodes: np.ndarray
) -> tuple[pl.DataFrame, dict[str, list[str]]]:
    """Keys, then one boolean column per predicate value; and the predicates metadata."""
    frames = np.concatenate([np.arange((episodes == e).sum()) for e in np.unique(episodes)])
    keys = {
        "episode": pl.Series("episode", episodes, dtype=pl.Int32),
        "frame": pl.Series("frame", frames, dtype=pl.Int32),
        "label": pl.Series("label", labels, dtype=pl.Int16),
        "split": pl.Series("split", splits, dtype=pl.String),
    }
    values = {n: pl.Series(n, v, dtype=pl.Boolean) for group in columns.values() for n, v in group.items()}
    meta = {predicate: list(group) for predicate, group in columns.items()}
    assert list(keys) == list(artifacts.KEY_COLUMNS)
    return pl.DataFrame({**keys, **values}), meta


def desk_predicates(data: Path, train_limit: int | None = None) -> tuple[pl.DataFrame, dict[str, list[str]]]:
    """DESK: the training file (episode 0, train) then the test file (episode 1, test)."""
    train = np.loadtxt(data / "desk-taurus" / "taurus_motion_train.txt")
    test = np.loadtxt(data / "desk-taurus" / "taurus_motion_test.txt")
    if train_limit is not None:
        train = train[:train_limit]
    table = np.concatenate([train, test]).astype(np.int64)
    arm, left, right = table[:, 1], table[:, 3], table[:, 5]
    pairs = {
        f"grippers_{a}_{b}": (left == i) & (right == j)
        for i, a in enumerate(GRIPPER) for j, b in enumerate(GRIPPER)
    }
    columns = {
        "arm_distance": one_hot(arm, "arm_distance", ARM),
        "left_gripper": one_hot(left, "left_gripper", GRIPPER),
        "right_gripper": one_hot(right, "right_gripper", GRIPPER),
        "grippers": pairs,
    }
    splits = np.array(["train"] * len(train) + ["test"] * len(test))
    episodes = np.array([0] * len(train) + [1] * len(test))
    return predicates_table(columns, table[:, 6], splits, episodes)


def fetch_predicates(data: Path, tiles: int = 1) -> tuple[pl.DataFrame, dict[str, list[str]]]:
    """Fetch training file (all train), repeated ``tiles`` times as episodes 0..tiles-1."""
    table = np.loadtxt(data / "gym-fetch-v1" / "fetch_motion_train.txt").astype(np.int64)
    table = np.tile(table, (tiles, 1))
    columns = {"gripper": one_hot(table[:, 0], "gripper", FETCH_GRIPPER)}
    episodes = np.repeat(np.arange(tiles), len(table) // tiles)
    return predicates_table(columns, table[:, 1], np.array(["train"] * len(table)), episodes)


def write_predicates(
    workdir: Path, table: pl.DataFrame, predicates: dict[str, list[str]], source: str, inputs: tuple[Path, ...] = ()
) -> Path:
    """Write a published-codes table as ``workdir/predicates.parquet`` (classes C0.. by label)."""
    n_classes = int(table["label"].max()) + 1 if table.height else 0
    classes = [f"S{k + 1}" for k in range(n_classes)] if source == "desk" else [f"phase {k}" for k in range(n_classes)]
    meta = {"predicates": predicates, "classes": classes, "source": source}
    return artifacts.write_table(table, Path(workdir) / artifacts.PREDICATES, "predicates", meta, inputs=list(inputs))
