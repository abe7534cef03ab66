"""--env lerobot (v2.0, v2.1 and v3.0 layouts, written per LeRobot's documented schema with polars) and
--env hdf5 (robomimic layout, written with h5py): the frames of the same recording written as a CSV."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq import sources
from mlnseq.sources.desk import CLASSES as DESK_CLASSES
from mlnseq.catalog.errors import BadInput
from mlnseq.sources import SourceOptions
from mlnseq.sources.recording import Labels, TableColumns
from mlnseq.sources.table import collect_frames

LENGTHS = (240, 160)  # two episodes
FPS = 30
LEFT = ["x", "y", "z", "angle_1", "angle_2", "angle_3", "gripper"]


@pytest.fixture(scope="module")
def desk(shared_data) -> np.ndarray:
    return np.loadtxt(shared_data / "desk-taurus" / "taurus_kinematics_train.txt")[:sum(LENGTHS)]


def episodes(desk: np.ndarray):
    start = 0
    for index, n in enumerate(LENGTHS):
        yield index, desk[start:start + n]
        start += n


@pytest.fixture(scope="module")
def labels(desk, tmp_path_factory) -> Path:
    """The DESK labels as intervals in frames, episode ids as the sources give them."""
    rows = ["episode,start,end,label"]
    for index, part in episodes(desk):
        edges = [0, *(np.flatnonzero(np.diff(part[:, -1])) + 1).tolist(), len(part)]
        rows += [f"{{e}},{a},{b - 1},{DESK_CLASSES[int(part[a, -1])]}" for a, b in zip(edges, edges[1:])]
    path = tmp_path_factory.mktemp("labels") / "intervals.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


def with_ids(labels: Path, ids: list[str], tmp_path: Path) -> Path:
    lines = labels.read_text().splitlines()
    counts = iter(ids)
    out, current = [lines[0]], None
    for line in lines[1:]:
        if line.split(",")[1] == "0":
            current = next(counts)
        out.append(line.replace("{e}", current, 1))
    path = tmp_path / f"{ids[0]}.csv"
    path.write_text("\n".join(out) + "\n")
    return path


def named(labels: Path) -> TableColumns:
    """--classes naming the file's classes (sorted, as read without): S6 labels one episode alone, a phase of its own,
    which a labels file names in --classes (else it is refused as a typo)."""
    return TableColumns(classes=tuple(sorted(set(pl.read_csv(labels)["label"]))))


def expected(desk, tmp_path, names: list[str], values) -> pl.DataFrame:
    """The same frames through the table reader: a CSV with a label column."""
    table = pl.concat([pl.DataFrame({"episode": [index] * len(part), "t": np.arange(len(part)) / FPS,
                                     "phase": [DESK_CLASSES[int(k)] for k in part[:, -1]]})
                       .hstack(pl.DataFrame({n: values(part)[:, i] for i, n in enumerate(names)}))
                       for index, part in episodes(desk)])
    table.write_csv(tmp_path / "same.csv")
    return collect_frames(sources.read("table", tmp_path / "same.csv", TableColumns(label="phase", time="t"),
                                       SourceOptions()))[0]


def lerobot_names(version: str, names: list[str]):
    return {"motors": names} if version == "v2.0" else names


def write_lerobot(root: Path, desk: np.ndarray, version: str) -> Path:
    state = lambda part: part[:, :7].astype(np.float32)  # noqa: E731
    action = lambda part: part[:, 7:14].astype(np.float32)  # noqa: E731
    features = {
        "observation.state": {"dtype": "float32", "shape": [7], "names": lerobot_names(version, LEFT)},
        "action": {"dtype": "float32", "shape": [7], "names": None},
        "observation.images.top": {"dtype": "video", "shape": [48, 64, 3], "names": ["height", "width", "channels"]},
        **{k: {"dtype": d, "shape": [1], "names": None} for k, d in (("timestamp", "float32"), ("frame_index", "int64"),
                                                                     ("episode_index", "int64"), ("index", "int64"),
                                                                     ("task_index", "int64"))}}
    v3 = version == "v3.0"
    info = {"codebase_version": version, "robot_type": "taurus", "fps": FPS, "total_episodes": len(LENGTHS),
            "total_frames": sum(LENGTHS), "chunks_size": 1000, "features": features,
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet" if v3
            else "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"}
    (root / "meta").mkdir(parents=True)
    (root / "data" / "chunk-000").mkdir(parents=True)
    (root / "meta" / "info.json").write_text(json.dumps(info, indent=2))
    parts, start = [], 0
    for index, part in episodes(desk):
        n = len(part)
        parts.append(pl.DataFrame({
            "observation.state": state(part).tolist(), "action": action(part).tolist(),
            "timestamp": (np.arange(n) / FPS).astype(np.float32), "frame_index": np.arange(n),
            "episode_index": [index] * n, "index": np.arange(start, start + n), "task_index": [0] * n,
        }, schema_overrides={"observation.state": pl.Array(pl.Float32, 7), "action": pl.List(pl.Float32)}))
        start += n
    if v3:
        pl.concat(parts).write_parquet(root / "data" / "chunk-000" / "file-000.parquet")
        (root / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
        pl.DataFrame({"episode_index": [0, 1], "length": list(LENGTHS), "data/chunk_index": [0, 0],
                      "data/file_index": [0, 0]}).write_parquet(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    else:
        for index, part in enumerate(parts):
            part.write_parquet(root / "data" / "chunk-000" / f"episode_{index:06d}.parquet")
        (root / "meta" / "episodes.jsonl").write_text(
            "".join(json.dumps({"episode_index": i, "tasks": ["transfer the peg"], "length": n}) + "\n"
                    for i, n in enumerate(LENGTHS)))
    return root


@pytest.mark.parametrize("version", ["v2.0", "v2.1", "v3.0"])
def test_a_lerobot_dataset_gives_the_frames_of_the_same_csv(desk, labels, tmp_path, version):
    root = write_lerobot(tmp_path / "dataset", desk, version)
    found, meta = collect_frames(sources.read("lerobot", root, named(labels), SourceOptions(
        labels=with_ids(labels, ["0", "1"], tmp_path))))
    names = [f"observation.state/{n}" for n in LEFT] + [f"action/{k}" for k in range(7)]
    assert meta["features"] == names
    same = expected(desk, tmp_path, names, lambda part: part[:, :14].astype(np.float32).astype(np.float64))
    assert found.equals(same)


def test_lerobot_refuses_an_unknown_version(desk, tmp_path):
    root = write_lerobot(tmp_path / "dataset", desk, "v2.1")
    info = json.loads((root / "meta" / "info.json").read_text())
    (root / "meta" / "info.json").write_text(json.dumps({**info, "codebase_version": "v1.6"}))
    with pytest.raises(BadInput, match=r"info.json: codebase_version 'v1.6' is not supported; mlnseq reads v2.0, v2.1, v3.0"):
        sources.read("lerobot", root, TableColumns(), SourceOptions())


def write_robomimic(path: Path, desk: np.ndarray) -> Path:
    import h5py

    with h5py.File(path, "w") as handle:
        for index, part in episodes(desk):
            demo = handle.create_group(f"data/demo_{index}")
            demo.create_dataset("obs/eef_pos", data=part[:, :3])
            demo.create_dataset("obs/gripper", data=part[:, 6])
            demo.create_dataset("obs/agentview_image", data=np.zeros((len(part), 4, 4, 3), dtype=np.uint8))
            demo.create_dataset("actions", data=part[:, 7:14])
    return path


def test_an_hdf5_file_gives_the_frames_of_the_same_csv(desk, labels, tmp_path):
    pytest.importorskip("h5py", reason="the [recordings] extra is not installed")
    source = write_robomimic(tmp_path / "demos.hdf5", desk)
    found, meta = collect_frames(sources.read("hdf5", source, named(labels), SourceOptions(
        labels=with_ids(labels, ["demo_0", "demo_1"], tmp_path))))
    names = ["obs/eef_pos/0", "obs/eef_pos/1", "obs/eef_pos/2", "obs/gripper", *(f"actions/{k}" for k in range(7))]
    assert meta["features"] == names  # the image left out
    assert found.equals(expected(desk, tmp_path, names, lambda part: part[:, [0, 1, 2, 6, *range(7, 14)]]))
    picked = sources.read("hdf5", source, TableColumns(features=("actions",)), SourceOptions(), label=Labels.NONE)
    assert picked[0].features.columns == [f"actions/{k}" for k in range(7)]
    with pytest.raises(BadInput, match=r"demos.hdf5:/data/demo_0: no dataset 'obs/joint_pos'; the demo's datasets "
                                       r"are actions, obs/agentview_image, obs/eef_pos, obs/gripper"):
        sources.read("hdf5", source, TableColumns(features=("obs/joint_pos",)), SourceOptions(), label=Labels.NONE)
