"""--env rosbag: one recording written by each library's own writer (ROS 1 bag, ROS 2 bag in sqlite3 and
MCAP storage, a bare MCAP) gives the frames of the same recording written as a CSV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

pytest.importorskip("rosbags", reason="the [recordings] extra is not installed")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from mlnseq import sources  # noqa: E402
from mlnseq.sources.desk import CLASSES as DESK_CLASSES  # noqa: E402
from mlnseq.catalog.errors import BadInput  # noqa: E402
from mlnseq.sources import SourceOptions  # noqa: E402
from mlnseq.sources.recording import Labels, TableColumns
from mlnseq.sources.table import collect_frames  # noqa: E402

FRAMES, STEP = 500, 20_000_000  # 50 Hz joint states; the gripper at 10 Hz
START = 1_700_000_000 * 10**9
JOINTS = [f"j{i}" for i in range(1, 8)]
STORE = get_typestore(Stores.ROS2_HUMBLE)
JointState, Header, Time = (STORE.types[n] for n in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                     "builtin_interfaces/msg/Time"))
Float64, String = STORE.types["std_msgs/msg/Float64"], STORE.types["std_msgs/msg/String"]


@pytest.fixture(scope="module")
def desk(shared_data) -> np.ndarray:
    return np.loadtxt(shared_data / "desk-taurus" / "taurus_kinematics_train.txt")[:FRAMES]


def messages(desk: np.ndarray):
    """(topic, time ns, message) in time order: joint states every frame, the gripper every 5th frame, a
    phase message wherever the label changes."""
    previous = None
    for k in range(len(desk)):
        t = START + k * STEP
        stamp = Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base")
        yield "/joint_states", t, JointState(header=stamp, name=JOINTS, position=desk[k, :7].copy(),
                                             velocity=np.zeros(0), effort=np.zeros(0))
        if k % 5 == 0:
            yield "/gripper", t, Float64(data=float(desk[k, 13]))
        if desk[k, -1] != previous:
            previous = desk[k, -1]
            yield "/phase", t, String(data=DESK_CLASSES[int(previous)])


def write_messages(writer, desk: np.ndarray, serialize) -> None:
    """The recording's messages through a rosbags writer, each topic's connection added at its first message."""
    connections = {}
    for topic, t, message in messages(desk):
        if topic not in connections:
            connections[topic] = writer.add_connection(topic, message.__msgtype__, typestore=STORE)
        writer.write(connections[topic], t, serialize(message, message.__msgtype__))


def write_ros2(path: Path, desk: np.ndarray, storage) -> Path:
    with Writer2(path, version=9, storage_plugin=storage) as writer:
        write_messages(writer, desk, STORE.serialize_cdr)
    return path


def write_ros1(path: Path, desk: np.ndarray) -> Path:
    with Writer1(path) as writer:
        write_messages(writer, desk, STORE.serialize_ros1)
    return path


def write_bare_mcap(path: Path, desk: np.ndarray) -> Path:
    """With mcap's own ROS 2 writer (not rosbags)."""
    from mcap_ros2.writer import Writer

    definitions = {
        "sensor_msgs/msg/JointState": "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort\n" + "=" * 80 + "\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
        + "=" * 80 + "\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n",
        "std_msgs/msg/Float64": "float64 data\n", "std_msgs/msg/String": "string data\n"}
    with open(path, "wb") as handle:
        writer = Writer(handle)
        schemas = {name: writer.register_msgdef(name, text) for name, text in definitions.items()}
        for topic, t, message in messages(desk):
            if topic == "/joint_states":
                data = {"header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": "base"},
                        "name": JOINTS, "position": message.position.tolist(), "velocity": [], "effort": []}
            else:
                data = {"data": message.data}
            writer.write_message(topic, schemas[message.__msgtype__], data, log_time=t, publish_time=t)
        writer.finish()
    return path


@pytest.fixture(scope="module")
def bags(desk, tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("bags")
    return {"ros1": write_ros1(folder / "trial.bag", desk),
            "sqlite3": write_ros2(folder / "trial_sqlite", desk, StoragePlugin.SQLITE3),
            "mcap": write_ros2(folder / "trial_mcap", desk, StoragePlugin.MCAP),
            "bare": write_bare_mcap(folder / "trial.mcap", desk)}


@pytest.fixture(scope="module")
def as_csv(desk, tmp_path_factory) -> Path:
    """The frames the bag should give, computed here: the 50 Hz clock, the gripper's last value (every 5th
    frame's), the last phase."""
    path = tmp_path_factory.mktemp("csv") / "trial.csv"
    table = {"t": np.arange(FRAMES) * STEP / 1e9, "phase": [DESK_CLASSES[int(k)] for k in desk[:, -1]]}
    table.update({f"/joint_states/position/{j}": desk[:, i] for i, j in enumerate(JOINTS)})
    table["/gripper/data"] = desk[(np.arange(FRAMES) // 5) * 5, 13]
    pl.DataFrame(table).write_csv(path)
    return path


OPTIONS = SourceOptions(topics=("/joint_states", "/gripper"), label_topic="/phase")


def frames(source: Path, options: SourceOptions = OPTIONS, columns=TableColumns()) -> tuple[pl.DataFrame, dict]:
    recordings = sources.read("rosbag", source, columns, options)
    return collect_frames(recordings, columns.classes)


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap", "bare"])
def test_each_bag_format_gives_the_frames_of_the_same_csv(bags, as_csv, kind):
    expected, _ = collect_frames(sources.read("table", as_csv, TableColumns(label="phase", time="t"), SourceOptions()))
    found, meta = frames(bags[kind])
    assert found.columns == expected.columns and found.equals(expected)
    assert meta["classes"] == sorted(set(DESK_CLASSES[int(k)] for k in np.unique(expected["label"])))


def test_default_topics_rate_and_a_folder_of_bags(bags, desk, tmp_path):
    recording = sources.read("rosbag", bags["sqlite3"], TableColumns(), SourceOptions(), label=Labels.NONE)[0]
    assert recording.resolved["topics"] == ["/gripper", "/joint_states"]  # every numeric topic, by name
    assert recording.resolved["rate"] == pytest.approx(10.0)  # the first topic's
    assert recording.resolved["skipped_topics"] == ["/phase"]
    assert recording.features.height == (FRAMES - 1) // 5 + 1
    folder = tmp_path / "trials"
    folder.mkdir()
    write_ros1(folder / "a.bag", desk[:200])
    write_bare_mcap(folder / "b.mcap", desk[200:])
    table, meta = frames(folder)
    assert meta["episode_names"] == ["a", "b"] and table.group_by("episode").len().sort("episode")["len"].to_list() == [200, 300]
    faster = sources.read("rosbag", bags["ros1"], TableColumns(), SourceOptions(topics=("/joint_states",), rate=100),
                          label=Labels.NONE)[0]
    assert faster.features.height == 2 * FRAMES - 1  # a tick every 10 ms, each holding the last 20 ms message
    assert faster.features["/joint_states/position/j1"].to_numpy()[1::2].tolist() == desk[:-1, 0].tolist()


def test_bad_bags_are_one_line_naming_the_topic_or_file(bags, desk, tmp_path):
    with pytest.raises(BadInput, match=r"trial.bag: no topic '/joint_state'; its topics are /gripper \(std_msgs/msg/Float64\)"):
        frames(bags["ros1"], SourceOptions(topics=("/joint_state",)))
    with pytest.raises(BadInput, match=r"topic '/phase' \(std_msgs/msg/String\) has no numeric field"):
        frames(bags["ros1"], SourceOptions(topics=("/phase",), label_topic=None), TableColumns())
    empty = tmp_path / "empty.bag"
    with Writer1(empty) as writer:
        writer.add_connection("/joint_states", JointState.__msgtype__, typestore=STORE)
    with pytest.raises(BadInput, match="empty.bag: the bag holds no message"):
        frames(empty)
    for name, whole in (("cut.bag", bags["ros1"]), ("cut.mcap", bags["bare"])):
        cut = tmp_path / name
        cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
        with pytest.raises(BadInput, match=f"{name}: cannot read it as a ROS bag"):
            frames(cut)


@pytest.mark.slow
def test_a_model_from_a_bag_predicts_new_bags_read_the_same_way(bags, tmp_path):
    import json
    import zipfile

    from typer.testing import CliRunner

    from mlnseq_cli.main import app
    from mlnseq import export, train

    runner = CliRunner()
    work = tmp_path / "work"
    done = runner.invoke(app, ["collect", "--env", "rosbag", "--source", str(bags["ros1"]), "--topics",
                               "/joint_states,/gripper", "--label-topic", "/phase", "-w", str(work)])
    assert done.exit_code == 0, done.output
    assert "500 frames, 1 episode" in " ".join(done.output.split())
    train.run(work, train.TrainOptions(method="lstm", mode="stream", epochs=1))
    model = export.run(work, export.ExportOptions(method="lstm")).path
    with zipfile.ZipFile(model) as archive:
        reading = json.loads(archive.read("manifest.json"))["reading"]
    assert reading["env"] == "rosbag" and reading["topics"] == ["/joint_states", "/gripper"]
    assert reading["rate"] == pytest.approx(50.0) and reading["label_topic"] == "/phase"
    out = tmp_path / "new.parquet"
    predicted = runner.invoke(app, ["predict", str(model), "--source", str(bags["mcap"]), "-o", str(out)])
    assert predicted.exit_code == 0, predicted.output
    table = pl.read_parquet(out)
    assert table.height == FRAMES and table["episode"].unique().to_list() == ["trial_mcap"] and "label" in table.columns
    refused = runner.invoke(app, ["collect", "--env", "rosbag", "--source", str(bags["mcap"]), "--topics", "/odom",
                                  "-w", str(tmp_path / "w2")])
    assert refused.exit_code == 2 and "no topic '/odom'" in refused.stderr
    assert refused.stderr.strip().count("\n") == 0 and not (tmp_path / "w2" / "frames.parquet").exists()


def test_a_missing_reader_library_is_one_line_naming_the_extra(bags, tmp_path):
    """Run in a process where rosbags cannot be imported, as on an install without the extra."""
    import subprocess
    import sys

    script = ("import sys; sys.modules['rosbags'] = None\n"
              "from mlnseq_cli.main import main\n"
              f"sys.argv = ['mlnseq', 'collect', '--env', 'rosbag', '--source', {str(bags['bare'])!r}, '-w', {str(tmp_path)!r}]\n"
              "main()\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parents[3])
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == ("error: reading this format needs rosbags, which is not installed: "
                                   "pip install '.[recordings]' in mlnseq's checkout, or "
                                   "pip install 'mlnseq-0.1.0-py3-none-any.whl[recordings]' beside the wheel")
    assert not (tmp_path / "frames.parquet").exists()


def test_ticks_before_the_first_label_message_are_dropped_or_unlabelled(desk, tmp_path):
    listed = list(messages(desk))
    first = next(m for m in listed if m[0] == "/phase")
    listed.remove(first)
    listed.insert(next(i for i, m in enumerate(listed) if m[1] == START + 10 * STEP) + 1,
                  ("/phase", START + 10 * STEP, first[2]))
    path = tmp_path / "late.bag"
    with Writer1(path) as writer:
        connections = {}
        for topic, t, message in listed:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, message.__msgtype__, typestore=STORE)
            writer.write(connections[topic], t, STORE.serialize_ros1(message, message.__msgtype__))
    dropped = sources.read("rosbag", path, TableColumns(), OPTIONS)[0]
    assert dropped.features.height == FRAMES - 10 and dropped.time[0] == pytest.approx(10 * STEP / 1e9)
    kept = sources.read("rosbag", path, TableColumns(), SourceOptions(**{**OPTIONS.__dict__, "unlabelled": "idle"}))[0]
    assert kept.features.height == FRAMES and kept.label.head(11).to_list() == ["idle"] * 10 + [first[2].data]
