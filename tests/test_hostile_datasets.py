"""LeRobot datasets and robomimic HDF5 files (written with polars and h5py from the real DESK kinematics): a
model trained on one predicts on it, and damaged ones are refused in one line naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq import collect, export, predict, sources, train
from mlnseq.catalog.errors import BadInput
from mlnseq.sources import SourceOptions
from mlnseq.sources.recording import Labels, TableColumns

LENGTHS = (240, 160)
JOINTS = [f"panda_joint{i}" for i in range(1, 8)]


@pytest.fixture(scope="module")
def desk(shared_data) -> np.ndarray:
    return np.loadtxt(shared_data / "desk-taurus" / "taurus_kinematics_train.txt")[:sum(LENGTHS)]


def parts(desk: np.ndarray):
    start = 0
    for index, n in enumerate(LENGTHS):
        yield index, desk[start:start + n]
        start += n


def write_lerobot(root: Path, desk: np.ndarray, info_features: dict | None = None, shuffle: bool = False) -> Path:
    """A LeRobot v2.1 dataset: observation.state a 7-vector named by joint, phase the DESK label."""
    features = info_features or {
        "observation.state": {"dtype": "float32", "shape": [7], "names": JOINTS},
        "phase": {"dtype": "int64", "shape": [1], "names": None},
        **{k: {"dtype": d, "shape": [1], "names": None} for k, d in (
            ("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"))}}
    (root / "meta").mkdir(parents=True)
    (root / "data" / "chunk-000").mkdir(parents=True)
    (root / "meta" / "info.json").write_text(json.dumps({"codebase_version": "v2.1", "fps": 30, "features": features}))
    for index, part in parts(desk):
        n = len(part)
        table = pl.DataFrame({"observation.state": part[:, :7].astype(np.float32).tolist(),
                              "phase": part[:, -1].astype(np.int64),
                              "timestamp": (np.arange(n) / 30).astype(np.float32),
                              "frame_index": np.arange(n), "episode_index": [index] * n},
                             schema_overrides={"observation.state": pl.Array(pl.Float32, 7)})
        if shuffle:
            table = table.sample(fraction=1.0, shuffle=True, seed=index)
        table.write_parquet(root / "data" / "chunk-000" / f"episode_{index:06d}.parquet")
    return root


def write_hdf5(path: Path, desk: np.ndarray, change=None) -> Path:
    """A robomimic-style file: data/demo_N/obs/joint_pos (7-vector), obs/gripper (scalar), phase (text)."""
    import h5py

    with h5py.File(path, "w") as handle:
        for index, part in parts(desk):
            demo = handle.create_group(f"data/demo_{index}")
            demo["obs/joint_pos"] = part[:, :7]
            demo["obs/gripper"] = part[:, 13]
            demo["phase"] = np.array([f"S{int(k)}".encode() for k in part[:, -1]])
        if change is not None:
            change(handle)
    return path


def train_and_predict(workdir: Path, env: str, source: Path, label: str, out: Path) -> predict.Predicted:
    collect.run(workdir, collect.CollectOptions(env=env, source=source, columns=TableColumns(label=label)))
    train.run(workdir, train.TrainOptions(method="lstm", mode="stream", epochs=1))
    model = export.run(workdir, export.ExportOptions(method="lstm")).path
    return predict.run(predict.PredictOptions(model=model, source=source, output=out))


def test_predict_reads_the_lerobot_dataset_its_model_was_trained_on(desk, tmp_path):
    dataset = write_lerobot(tmp_path / "lerobot", desk)
    predicted = train_and_predict(tmp_path / "work", "lerobot", dataset, "phase", tmp_path / "p.parquet")
    assert predicted.table.height == sum(LENGTHS) and predicted.metrics is not None
    assert predicted.table["episode"].unique().sort().to_list() == [0, 1]


def test_predict_reads_the_hdf5_file_its_model_was_trained_on(desk, tmp_path):
    pytest.importorskip("h5py")
    path = write_hdf5(tmp_path / "demos.hdf5", desk)
    predicted = train_and_predict(tmp_path / "work", "hdf5", path, "phase", tmp_path / "p.parquet")
    assert predicted.table.height == sum(LENGTHS) and predicted.metrics is not None
    assert predicted.table["episode"].unique().sort().to_list() == ["demo_0", "demo_1"]


def test_a_split_feature_name_reads_only_that_element(desk, tmp_path):
    dataset = write_lerobot(tmp_path / "lerobot", desk)
    (recording, _) = sources.read("lerobot", dataset, TableColumns(features=("observation.state/panda_joint3",)),
                                  SourceOptions(), Labels.NONE)
    assert recording.features.columns == ["observation.state/panda_joint3"]
    np.testing.assert_allclose(recording.features[:, 0].to_numpy(), desk[:240, 2].astype(np.float32))


def refused_read(env: str, source: Path, *needles: str) -> None:
    with pytest.raises(BadInput) as error:
        sources.read(env, source, TableColumns(label="phase"), SourceOptions())
    for needle in needles:
        assert needle in str(error.value), (needle, str(error.value))


def test_a_label_shorter_than_its_demo_is_refused(desk, tmp_path):
    pytest.importorskip("h5py")

    def shorten(handle):
        del handle["data/demo_1/phase"]
        handle["data/demo_1/phase"] = np.array([b"S1"] * 100)
    refused_read("hdf5", write_hdf5(tmp_path / "d.hdf5", desk, shorten), "d.hdf5:/data/demo_1/phase",
                 "100 labels", "for 160 frames")


def test_a_scalar_obs_dataset_is_left_out_and_refused_when_named(desk, tmp_path):
    pytest.importorskip("h5py")

    def scalar(handle):
        handle["data/demo_0/obs/robot_id"] = 7
        handle["data/demo_1/obs/robot_id"] = 7
    path = write_hdf5(tmp_path / "d.hdf5", desk, scalar)
    (first, _) = sources.read("hdf5", path, TableColumns(label="phase"), SourceOptions())
    assert "obs/robot_id" not in first.features.columns and first.features.width == 8
    with pytest.raises(BadInput, match=r"d.hdf5:/data/demo_0/obs/robot_id: int64 of shape \(\) is not one value"):
        sources.read("hdf5", path, TableColumns(label="phase", features=("obs/robot_id",)), SourceOptions())


def test_a_demo_that_is_a_dataset_is_refused(desk, tmp_path):
    pytest.importorskip("h5py")

    def flat(handle):
        handle["data/demo_2"] = desk[:10, :7]
    refused_read("hdf5", write_hdf5(tmp_path / "d.hdf5", desk, flat),
                 "d.hdf5:/data/demo_2 is a dataset, not a demo group")


def test_a_label_that_is_not_utf8_is_refused(desk, tmp_path):
    pytest.importorskip("h5py")

    def latin1(handle):
        labels = handle["data/demo_0/phase"][()].astype("S16")
        labels[5] = "S1 \u00e9paule".encode("latin-1")
        del handle["data/demo_0/phase"]
        handle["data/demo_0/phase"] = labels
    refused_read("hdf5", write_hdf5(tmp_path / "d.hdf5", desk, latin1), "d.hdf5:/data/demo_0/phase frame 5",
                 "not UTF-8")


@pytest.mark.parametrize("spec", [["float32", 7], {"dtype": "float32", "shape": ["two"]}, "observation"],
                         ids=["a list", "shape of text", "a string"])
def test_a_lerobot_feature_spec_that_is_not_an_object_with_a_shape_is_refused(desk, tmp_path, spec):
    dataset = write_lerobot(tmp_path / "lerobot", desk, info_features={
        "observation.state": spec, "phase": {"dtype": "int64", "shape": [1]},
        "frame_index": {"dtype": "int64", "shape": [1]}, "episode_index": {"dtype": "int64", "shape": [1]}})
    refused_read("lerobot", dataset, "meta/info.json", "feature 'observation.state'", "'shape' of whole numbers")


def test_lerobot_rows_out_of_frame_order_are_ordered_by_frame_index(desk, tmp_path):
    ordered = sources.read("lerobot", write_lerobot(tmp_path / "a", desk), TableColumns(label="phase"), SourceOptions())
    shuffled = sources.read("lerobot", write_lerobot(tmp_path / "b", desk, shuffle=True), TableColumns(label="phase"),
                            SourceOptions())
    for a, b in zip(ordered, shuffled):
        assert a.features.equals(b.features) and a.time.equals(b.time) and a.label.equals(b.label)


def test_one_element_of_an_hdf5_vector_is_read_from_every_demo(desk, tmp_path):
    pytest.importorskip("h5py")
    path = write_hdf5(tmp_path / "d.hdf5", desk)
    recordings = sources.read("hdf5", path, TableColumns(features=("obs/joint_pos/3", "obs/gripper")), SourceOptions(),
                              Labels.NONE)
    assert [r.features.columns for r in recordings] == [["obs/joint_pos/3", "obs/gripper"]] * 2
    np.testing.assert_array_equal(recordings[1].features["obs/joint_pos/3"].to_numpy(), desk[240:, 3])


def test_a_lerobot_info_json_nested_too_deep_is_refused(desk, tmp_path):
    dataset = write_lerobot(tmp_path / "lerobot", desk)
    (dataset / "meta" / "info.json").write_text("[" * 200_000 + "]" * 200_000)
    refused_read("lerobot", dataset, "meta/info.json", "nested too deep")
