"""`mlnseq ros --ros 2` and `mlnseq echo | mlnseq stream` against real DDS peers (tests/dds_driver.py: Cyclone DDS
participants speaking as ROS 2 nodes, each its own process, on the loopback, in a domain of the test's own): a
ROS 2 bag's /joint_states published at its 100 Hz pace give the classes and probabilities `predict` gives on the
bag; so do joints and a gripper on two topics; a publisher of another type is one error line; SIGINT answers the
frame the node holds, then the node exits 0. And the same bag through a C peer on Debian's Cyclone 0.10 (the
series ROS 2 Humble ships; tests/dds_c_peer/). Everything started is stopped by process group in a finally.
Without cyclonedds (or, for the C peer, Debian's cyclonedds-dev and cyclonedds-tools) the tests skip, saying why;
in CI (CI=true) they fail instead."""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import ros2_episode
import ros_episode
from mlnseq import predict
from mlnseq.catalog import artifacts

MLNSEQ = str(Path(sys.executable).parent / "mlnseq")
DRIVER = Path(__file__).resolve().parents[1] / "dds_driver.py"
WAIT_S = 30


def skip_or_fail(why: str) -> None:
    if os.environ.get("CI") == "true":
        pytest.fail(why)
    pytest.skip(why)


def dds_or_skip() -> None:
    try:
        import cyclonedds.domain  # noqa: F401
    except ImportError as error:
        skip_or_fail(f"cyclonedds is not installed ({error}): `make setup` installs mlnseq[ros2]")


def cyclone_config(path: Path, tag: str, interface: bool = True, unicast: bool = True) -> str:
    """A Cyclone configuration file's URI: the loopback interface, unicast discovery of 127.0.0.1 (no multicast),
    and the discovery tag ``tag``, which only this test's participants carry."""
    general = ('<Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>' if interface else "") + (
        "<AllowMulticast>false</AllowMulticast>" if unicast else "")
    discovery = ('<ParticipantIndex>auto</ParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>'
                 if unicast else "") + f"<Tag>{tag}</Tag>"
    path.write_text(f"<CycloneDDS><Domain><General>{general}</General><Discovery>{discovery}</Discovery></Domain>"
                    "</CycloneDDS>")
    return path.as_uri()


def dds_env(folder: Path, **node: bool) -> tuple[dict[str, str], dict[str, str]]:
    """The peers' environment (a random domain, the localhost-only configuration) and the node's: the same with
    its configuration less what ``node`` leaves out (``interface``, ``unicast``), for the ROS_ variables to give."""
    tag = f"mlnseq-test-{os.getpid()}-{random.randrange(10**9)}"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "CYCLONEDDS"))}
    path = os.pathsep.join(filter(None, [str(DRIVER.parent), os.environ.get("PYTHONPATH")]))
    peers = {**env, "ROS_DOMAIN_ID": str(random.randrange(1, 200)), "PYTHONUNBUFFERED": "1", "PYTHONPATH": path,
             "CYCLONEDDS_URI": cyclone_config(folder / "peers.xml", tag)}
    return peers, {**peers, "CYCLONEDDS_URI": cyclone_config(folder / "node.xml", tag, **node)}


def wait_for(check, what: str, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


class Processes:
    """The processes a test starts, each in its own session, all stopped by process group at the end."""

    def __init__(self, env: dict[str, str]):
        self.env, self.started = env, []

    def start(self, args, env: dict[str, str] | None = None, **kwargs) -> subprocess.Popen:
        self.started.append(subprocess.Popen(args, env=env or self.env, start_new_session=True, **kwargs))
        return self.started[-1]

    def stop(self) -> None:
        for process in reversed(self.started):
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()


def lines(path: Path) -> list[str]:
    return path.read_text().splitlines() if path.exists() else []


def check_answers(answers: list[dict], expected, n: int) -> None:
    """At least 95 % of the n frames answered, each as predict answered it on the bag."""
    assert len(answers) >= 0.95 * n, (len(answers), n)
    want = expected.select(artifacts.class_probability_column(c) for c in answers[0]["probabilities"]).to_numpy()
    frames = [a["frame"] for a in answers]
    assert frames == sorted(set(frames))
    assert [a["class"] for a in answers] == [expected["class"][k] for k in frames]
    assert [a["time"] for a in answers] == [expected["time"][k] for k in frames]  # from the recording's start
    assert [a["stamp"] for a in answers] == [expected["stamp"][k] for k in frames]  # the messages' clock
    assert expected["stamp"].to_list() == [(ros_episode.START + round(t * 1e9)) / 1e9 for t in expected["time"]]
    got = np.array([[a["probabilities"][c] for c in answers[0]["probabilities"]] for a in answers])
    np.testing.assert_allclose(got, want[frames], atol=1e-5)
    assert expected["class"].n_unique() > 1


def predicted(model: Path, bag: Path, folder: Path):
    """predict on the bag: each frame's time from the bag's start and its stamp on the messages' clock (s)."""
    return predict.run(predict.PredictOptions(model=model, source=bag, output=folder / "p.parquet")).table


def test_the_node_and_the_echo_pipe_give_predicts_classes(joint_state_model, tmp_path):
    dds_or_skip()
    rows, model = joint_state_model["live"], str(joint_state_model["model"])
    bag = ros2_episode.write_bag(tmp_path / "live", rows)
    peers, node_env = dds_env(tmp_path, interface=False)  # the node's loopback: ROS_LOCALHOST_ONLY, as on Humble
    processes = Processes(peers)
    logs = {name: open(tmp_path / f"{name}.log", "w+") for name in ("node", "echo", "stream", "peers")}
    node_out, streamed = tmp_path / "node.jsonl", tmp_path / "stream.jsonl"
    try:
        node = processes.start([MLNSEQ, "ros", model, "--ros", "2"], env={**node_env, "ROS_LOCALHOST_ONLY": "1"},
                               stdout=logs["node"], stderr=subprocess.STDOUT)
        recorder = processes.start([sys.executable, str(DRIVER), "record", "/mlnseq/activity/frame", str(node_out)],
                                   stdout=subprocess.PIPE, text=True)
        echo = processes.start([MLNSEQ, "echo", "/joint_states"], stdout=subprocess.PIPE, stderr=logs["echo"])
        with open(streamed, "w") as out:
            stream = processes.start([MLNSEQ, "stream", model, "--explain", "2"], stdin=echo.stdout, stdout=out,
                                     stderr=logs["stream"])
        echo.stdout.close()
        assert recorder.stdout.readline().strip() == "ready"
        publisher = processes.start([sys.executable, str(DRIVER), "publish", str(bag), "2"], stdout=logs["peers"],
                                    stderr=subprocess.STDOUT)
        assert publisher.wait(WAIT_S) == 0, (tmp_path / "peers.log").read_text()
        wait_for(lambda: len(lines(node_out)) >= len(rows) - 1, "the node's frames", 10)
        # then a publisher of another type on the model's topic: one note, the node goes on
        processes.start([sys.executable, str(DRIVER), "wrong", "/joint_states"], stdout=logs["peers"],
                        stderr=subprocess.STDOUT)
        wait_for(lambda: "note: a publisher" in (tmp_path / "node.log").read_text(), "the node's note")
        os.killpg(echo.pid, signal.SIGINT)  # the pipe ends: stream answers its last tick and exits
        assert echo.wait(WAIT_S) == 0 and stream.wait(WAIT_S) == 0, (tmp_path / "stream.log").read_text()
        node.send_signal(signal.SIGINT)
        assert node.wait(WAIT_S) == 0, (tmp_path / "node.log").read_text()
        wait_for(lambda: len(lines(node_out)) >= len(rows), "the frame the node held", 5)
    finally:
        processes.stop()
        for handle in logs.values():
            handle.close()
    expected = predicted(joint_state_model["model"], bag, tmp_path)
    assert expected.height == len(rows)
    check_answers([json.loads(line) for line in lines(node_out)], expected, len(rows))
    piped = [json.loads(line) for line in lines(streamed)]
    check_answers(piped, expected, len(rows))
    from mlnseq import explain  # `mlnseq echo | mlnseq stream --explain 2`: each line's why is explain's on the bag

    for answer in (piped[1], piped[-1]):
        found = explain.run(explain.ExplainOptions(model=joint_state_model["model"], source=bag,
                                                   time=answer["stamp"])).explanation
        assert found.frame == answer["frame"] and [t["text"] for t in answer["why"]] == [
            t.text for t in found.largest(2)]
        np.testing.assert_allclose([t["contribution"] for t in answer["why"]],
                                   [t.contribution for t in found.largest(2)], atol=2e-6)
    assert all(a["why"] for a in piped) and not any("why" in json.loads(line) for line in lines(node_out))
    node_log = (tmp_path / "node.log").read_text().splitlines()
    notes = [line for line in node_log if line.startswith("note: a publisher")]
    assert len(notes) == 1 and notes[0].startswith(
        "note: a publisher on /joint_states sends std_msgs/msg/String, which holds no position for the model's "
        "features: its writer "), node_log
    assert not [line for line in node_log if line.startswith("error:")], node_log
    assert node_log[-1] == f"ros: stopped after {len(rows)} frames (0 bad messages)"
    assert (tmp_path / "echo.log").read_text().splitlines()[-1] == f"echo: {len(rows)} messages of /joint_states"


def test_a_stray_string_publisher_up_first_and_the_node_reads_the_robot_explaining_every_frame(
        lagged_joint_state_model, joint_state_model, tmp_path):
    """A std_msgs/String publisher on /joint_states (its participant named stray_talker) is up before the node: the
    node names it in one note and reads /joint_states as the JointState its model needs when that publisher comes.
    With --explain 2, every frame on TOPIC/frame carries why, and `explain --time` with the frame's own time (or its
    stamp) explains that frame of the bag with the same terms."""
    dds_or_skip()
    from mlnseq import explain

    rows = joint_state_model["live"][:150]
    bag = ros2_episode.write_bag(tmp_path / "live", rows)
    peers, node_env = dds_env(tmp_path)
    processes = Processes(peers)
    logs = {name: open(tmp_path / f"{name}.log", "w+") for name in ("node", "peers", "stray")}
    node_out, node_log = tmp_path / "node.jsonl", lambda: (tmp_path / "node.log").read_text()  # noqa: E731
    try:
        processes.start([sys.executable, str(DRIVER), "wrong", "/joint_states", "600", "stray_talker"],
                        stdout=logs["stray"], stderr=subprocess.STDOUT)
        time.sleep(1.0)  # the stray publisher is discovered before the node's first look
        node = processes.start([MLNSEQ, "ros", str(lagged_joint_state_model), "--ros", "2", "--explain", "2"],
                               env=node_env, stdout=logs["node"], stderr=subprocess.STDOUT)
        wait_for(lambda: "note: a publisher on /joint_states" in node_log(), "the node's note on the stray publisher")
        recorder = processes.start([sys.executable, str(DRIVER), "record", "/mlnseq/activity/frame", str(node_out)],
                                   stdout=subprocess.PIPE, text=True)
        assert recorder.stdout.readline().strip() == "ready", node_log()
        publisher = processes.start([sys.executable, str(DRIVER), "publish", str(bag), "1"], stdout=logs["peers"],
                                    stderr=subprocess.STDOUT)
        assert publisher.wait(WAIT_S) == 0, (tmp_path / "peers.log").read_text()
        wait_for(lambda: len(lines(node_out)) >= len(rows) - 6, "the node's frames", 10)  # a lag of 5, the last tick
        node.send_signal(signal.SIGINT)
        assert node.wait(WAIT_S) == 0, node_log()
        wait_for(lambda: len(lines(node_out)) >= len(rows), "the frames the node held", 5)
    finally:
        processes.stop()
        for handle in logs.values():
            handle.close()
    answers = [json.loads(line) for line in lines(node_out)]
    check_answers(answers, predicted(lagged_joint_state_model, bag, tmp_path), len(rows))
    assert len(answers) == len(rows) and all(len(a["why"]) == 2 for a in answers) and {a["lag"] for a in answers} == {5}
    for answer in (answers[3], answers[len(rows) // 2], answers[-1]):
        for clock in ("time", "stamp"):
            found = explain.run(explain.ExplainOptions(model=lagged_joint_state_model, source=bag,
                                                       time=answer[clock])).explanation
            assert (found.frame, found.chosen) == (answer["frame"], answer["class"]), clock
            assert [t["text"] for t in answer["why"]] == [t.text for t in found.largest(2)]
            np.testing.assert_allclose([t["contribution"] for t in answer["why"]],
                                       [t.contribution for t in found.largest(2)], atol=2e-6)
    said = node_log().splitlines()
    notes = [line for line in said if line.startswith("note: a publisher")]
    assert len(notes) == 1 and notes[0].startswith(
        "note: a publisher on /joint_states sends std_msgs/msg/String, which holds no position for the model's "
        "features: its writer ") and notes[0].endswith(
        "(participant 'stray_talker') is not read; /joint_states is read as the type that holds them"), said
    assert "ros: subscribed to /joint_states (sensor_msgs/msg/JointState, reliable)" in said
    assert not [line for line in said if line.startswith("error:")] and said[-1] == (
        f"ros: stopped after {len(rows)} frames (0 bad messages)")


@pytest.fixture(scope="module")
def two_topic_model(tmp_path_factory, shared_data) -> dict:
    """An lstm (stream mode, 40 epochs) trained on a ROS 2 bag of DESK's arm: six joints on /joint_states at 100 Hz
    and its gripper opening on /gripper (std_msgs/Float64) at 50 Hz (the first 1,000 frames); ``live``: the rest."""
    from mlnseq import collect, export, train
    from mlnseq.sources import SourceOptions

    folder = tmp_path_factory.mktemp("two-topics")
    rows = ros_episode.desk_rows(shared_data)
    bag = ros2_episode.write_bag(folder / "train", rows[:ros_episode.TRAIN_FRAMES], gripper=True)
    workdir = folder / "work"
    collect.run(workdir, collect.CollectOptions(env="rosbag", source=bag, recordings=SourceOptions(
        topics=("/joint_states", "/gripper"), label_topic="/phase")))
    train.run(workdir, train.TrainOptions(method="lstm", mode="stream", epochs=40))
    model = export.run(workdir, export.ExportOptions(method="lstm", output=folder / "lstm.mlnseq")).path
    return {"model": model, "live": rows[ros_episode.TRAIN_FRAMES:]}


def test_two_topics_merged_and_the_frame_held_answered_at_sigint(two_topic_model, tmp_path):
    """Joints and a gripper (no header: its time is the sample's source timestamp); the node started with no --ros
    and no ROS 1 master configured (so ROS 2), as a Jazzy node whose unicast discovery of localhost comes from
    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (the loopback interface from the test's configuration)."""
    dds_or_skip()
    rows, model = two_topic_model["live"], two_topic_model["model"]
    bag = ros2_episode.write_bag(tmp_path / "live", rows, gripper=True)
    expected = predicted(model, bag, tmp_path)
    peers, node_env = dds_env(tmp_path, unicast=False)
    processes = Processes(peers)
    node_env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    logs = {name: open(tmp_path / f"{name}.log", "w+") for name in ("node", "peers")}
    node_out = tmp_path / "node.jsonl"
    try:
        node = processes.start([MLNSEQ, "ros", str(model), "--distro", "jazzy"], env=node_env, stdout=logs["node"],
                               stderr=subprocess.STDOUT)
        recorder = processes.start([sys.executable, str(DRIVER), "record", "/mlnseq/activity/frame", str(node_out)],
                                   stdout=subprocess.PIPE, text=True)
        assert recorder.stdout.readline().strip() == "ready", (tmp_path / "node.log").read_text()
        publisher = processes.start([sys.executable, str(DRIVER), "publish", str(bag), "1"], stdout=logs["peers"],
                                    stderr=subprocess.STDOUT)
        assert publisher.wait(WAIT_S) == 0, (tmp_path / "peers.log").read_text()
        wait_for(lambda: len(lines(node_out)) >= expected.height - 1, "the node's frames", 10)
        time.sleep(0.5)
        held = len(lines(node_out))  # the last tick waits for a later message, or the end of the feed
        node.send_signal(signal.SIGINT)
        assert node.wait(WAIT_S) == 0, (tmp_path / "node.log").read_text()
        wait_for(lambda: len(lines(node_out)) >= expected.height, "the frame the node held", 5)
    finally:
        processes.stop()
        for handle in logs.values():
            handle.close()
    assert held == expected.height - 1
    answers = [json.loads(line) for line in lines(node_out)]
    assert len(answers) == expected.height
    check_answers(answers, expected, expected.height)
    assert len(answers[0]["probabilities"]) > 1 and expected.height >= len(rows) - 1
    node_log = (tmp_path / "node.log").read_text().splitlines()
    assert node_log[0].startswith("ros: mlnseq on ROS 2 jazzy (DDS domain ")
    assert "listening to /joint_states, /gripper" in node_log[0]
    assert sorted(node_log[1:3]) == ["ros: subscribed to /gripper (std_msgs/msg/Float64, best effort)",
                                     "ros: subscribed to /joint_states (sensor_msgs/msg/JointState, reliable)"]
    assert node_log[-1] == f"ros: stopped after {expected.height} frames (0 bad messages)"


@pytest.fixture(scope="module")
def c_peer(tmp_path_factory) -> Path:
    """tests/dds_c_peer/peer.c built on Debian's Cyclone C library (its idlc for the message types)."""
    source = DRIVER.parent / "dds_c_peer"
    missing = [tool for tool in ("idlc", "gcc") if shutil.which(tool) is None]
    if missing or not Path("/usr/include/dds/dds.h").is_file():
        skip_or_fail(f"Debian's Cyclone DDS C library is not installed ({', '.join(missing) or 'dds/dds.h'}): "
                     "`make setup` as root installs cyclonedds-dev and cyclonedds-tools")
    folder = tmp_path_factory.mktemp("c-peer")
    for command in (["idlc", "-l", "c", str(source / "ros2_msgs.idl")],
                    ["gcc", "-O1", "-Wall", "-Werror", "-o", "peer", str(source / "peer.c"), "ros2_msgs.c", "-I.",
                     "-lddsc"]):
        done = subprocess.run(command, cwd=folder, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
    return folder / "peer"


def test_a_c_peer_on_cyclone_0_10_and_the_node(joint_state_model, c_peer, tmp_path):
    """The bag's JointState messages from C (Cyclone 0.10's own CDR), the frames recorded by C."""
    dds_or_skip()
    from rosbags.highlevel import AnyReader

    rows, model = joint_state_model["live"], str(joint_state_model["model"])
    bag = ros2_episode.write_bag(tmp_path / "live", rows)
    with AnyReader([bag]) as reader, open(tmp_path / "rows.txt", "w") as out:
        out.write(" ".join(ros_episode.JOINTS) + "\n")
        for connection, _, raw in reader.messages([c for c in reader.connections if c.topic == "/joint_states"]):
            message = reader.deserialize(raw, connection.msgtype)
            stamp = message.header.stamp.sec * 10**9 + message.header.stamp.nanosec
            out.write(" ".join([str(stamp), *map(repr, message.position.tolist())]) + "\n")
    peers, node_env = dds_env(tmp_path)
    processes = Processes(peers)
    logs = {name: open(tmp_path / f"{name}.log", "w+") for name in ("node", "peers")}
    node_out = tmp_path / "node.jsonl"
    try:
        node = processes.start([MLNSEQ, "ros", model, "--ros", "2"], env=node_env, stdout=logs["node"],
                               stderr=subprocess.STDOUT)
        recorder = processes.start([str(c_peer), "record", "/mlnseq/activity/frame", str(node_out)],
                                   stdout=subprocess.PIPE, text=True)
        assert recorder.stdout.readline().strip() == "ready", (tmp_path / "node.log").read_text()
        publisher = processes.start([str(c_peer), "publish", str(tmp_path / "rows.txt"), "1"], stdout=logs["peers"],
                                    stderr=subprocess.STDOUT)
        assert publisher.wait(WAIT_S) == 0, (tmp_path / "peers.log").read_text()
        wait_for(lambda: len(lines(node_out)) >= len(rows) - 1, "the node's frames", 10)
        node.send_signal(signal.SIGINT)
        assert node.wait(WAIT_S) == 0, (tmp_path / "node.log").read_text()
        wait_for(lambda: len(lines(node_out)) >= len(rows), "the frame the node held", 5)
    finally:
        processes.stop()
        for handle in logs.values():
            handle.close()
    check_answers([json.loads(line) for line in lines(node_out)], predicted(joint_state_model["model"], bag, tmp_path),
                  len(rows))
    node_log = (tmp_path / "node.log").read_text().splitlines()
    assert node_log[-1] == f"ros: stopped after {len(rows)} frames (0 bad messages)"
