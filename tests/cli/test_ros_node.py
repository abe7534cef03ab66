"""`mlnseq ros` and `rostopic echo -p | mlnseq stream` against a real ROS 1 master (Debian's packages, which
scripts/setup.sh installs and links into .venv): a recorded episode's /joint_states published at its 100 Hz
rate gives the classes and probabilities `predict` gives on a bag of the same messages; the node survives bad
messages. Everything started is stopped by process group in a finally. Without ROS 1 it skips, saying why;
in CI (CI=true) it fails instead."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client
from pathlib import Path

import numpy as np
import pytest

import ros_episode
from mlnseq import explain, predict
from mlnseq.catalog import artifacts
from mlnseq.recognition.reading import ReadOptions

MLNSEQ = str(Path(sys.executable).parent / "mlnseq")
DRIVER = Path(__file__).resolve().parents[1] / "ros_driver.py"
WAIT_S = 30


def ros_or_skip() -> None:
    missing = [name for name in ("rosmaster", "rostopic") if shutil.which(name) is None]
    probe = subprocess.run([sys.executable, "-c", "import rospy, sensor_msgs.msg, std_msgs.msg"], capture_output=True,
                           text=True)
    if missing or probe.returncode:
        why = (f"ROS 1 is not installed ({', '.join(missing) or probe.stderr.strip().splitlines()[-1]}): on Debian, "
               "`make setup` as root installs python3-rosmaster python3-rostopic python3-rospy python3-sensor-msgs "
               "python3-std-msgs and links them into .venv")
        if os.environ.get("CI") == "true":
            pytest.fail(why)
        pytest.skip(why)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(check, what: str, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def master_up(uri: str) -> bool:
    try:
        return xmlrpc.client.ServerProxy(uri).getPid("/test")[0] == 1
    except OSError:
        return False


def test_the_node_and_the_echo_pipe_give_predicts_classes(joint_state_model, tmp_path):
    ros_or_skip()
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    path = os.pathsep.join(filter(None, [str(DRIVER.parent), os.environ.get("PYTHONPATH")]))  # a ROS setup.bash's too
    env = {**os.environ, "ROS_MASTER_URI": uri, "ROS_IP": "127.0.0.1", "ROS_HOME": str(tmp_path / "ros"),
           "PYTHONUNBUFFERED": "1", "PYTHONPATH": path}
    rows = joint_state_model["live"]
    np.save(tmp_path / "rows.npy", rows)
    model = str(joint_state_model["model"])
    started: list[subprocess.Popen] = []

    def start(args, **kwargs) -> subprocess.Popen:
        started.append(subprocess.Popen(args, env=env, start_new_session=True, **kwargs))
        return started[-1]

    logs = {name: open(tmp_path / f"{name}.log", "w+") for name in ("master", "node", "echo", "stream", "bad")}
    streamed = open(tmp_path / "stream.jsonl", "w+")
    try:
        start(["rosmaster", "--core", "-p", str(port)], stdout=logs["master"], stderr=subprocess.STDOUT)
        wait_for(lambda: master_up(uri), "the master")
        node = start([MLNSEQ, "ros", model], stdout=logs["node"], stderr=subprocess.STDOUT)
        recorder = start([sys.executable, str(DRIVER), "record", "/mlnseq/activity/frame",
                          str(tmp_path / "node.jsonl")], stdout=subprocess.PIPE, text=True)
        echo = start(["rostopic", "echo", "-p", "/joint_states"], stdout=subprocess.PIPE, stderr=logs["echo"])
        stream = start([MLNSEQ, "stream", model], stdin=echo.stdout, stdout=streamed, stderr=logs["stream"])
        echo.stdout.close()
        assert recorder.stdout.readline().strip() == "ready"
        publisher = start([sys.executable, str(DRIVER), "publish", str(tmp_path / "rows.npy"), "2"],
                          stdout=logs["bad"], stderr=subprocess.STDOUT)
        assert publisher.wait(WAIT_S) == 0, (tmp_path / "bad.log").read_text()
        node_lines = lambda: (tmp_path / "node.jsonl").read_text().splitlines()  # noqa: E731
        wait_for(lambda: len(node_lines()) >= len(rows) - 1, "the node's frames", 10)
        # then a publisher of another type on the model's topic: one note naming it, the node goes on
        start(["rostopic", "pub", "-1", "/joint_states", "std_msgs/String", "data: hello"], stdout=logs["bad"],
              stderr=subprocess.STDOUT)
        wait_for(lambda: "note: a publisher" in (tmp_path / "node.log").read_text(), "the node's note")
        os.killpg(echo.pid, signal.SIGINT)  # the pipe ends: stream answers its last ticks and exits
        assert stream.wait(WAIT_S) == 0, (tmp_path / "stream.log").read_text()
        node.send_signal(signal.SIGTERM)
        assert node.wait(WAIT_S) == 0
    finally:
        for process in reversed(started):
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
        for handle in (*logs.values(), streamed):
            handle.close()
    expected = predict.run(predict.PredictOptions(
        model=joint_state_model["model"], source=ros_episode.write_bag(tmp_path / "live.bag", rows),
        output=tmp_path / "p.parquet")).table
    classes = list(expected.select(c for c in expected.columns if c.startswith("p_")).columns)
    want = expected.select(classes).to_numpy()
    node_log = (tmp_path / "node.log").read_text()
    for name, lines in (("node", node_lines()), ("stream", (tmp_path / "stream.jsonl").read_text().splitlines())):
        answers = [json.loads(line) for line in lines]
        n = len(answers)
        assert n >= len(rows) - 1 if name == "node" else n == len(rows), (name, n)
        assert [a["class"] for a in answers] == expected["class"].to_list()[:n], name
        assert [a["time"] for a in answers] == expected["time"].to_list()[:n]
        assert [a["stamp"] for a in answers] == [(ros_episode.START + k * ros_episode.STEP) / 1e9 for k in range(n)]
        got = np.array([[a["probabilities"][c] for c in answers[0]["probabilities"]] for a in answers])
        np.testing.assert_allclose(got, want[:n], atol=1e-5, err_msg=name)
    assert classes == [artifacts.class_probability_column(c) for c in answers[0]["probabilities"]]
    assert expected["class"].n_unique() > 1
    notes = [line for line in node_log.splitlines() if line.startswith("note: a publisher")]
    assert len(notes) == 1 and notes[0].startswith(
        "note: a publisher on /joint_states sends std_msgs/String, which holds no position for the model's features: "
        "/rostopic_") and notes[0].endswith(
        " is not read; /joint_states is read from the publishers of the type that holds them"), node_log
    assert "error:" not in node_log
    assert node_log.splitlines()[-1] == f"ros: stopped after {len(rows)} frames (0 bad messages)"


def test_start_up_errors_are_one_line_and_exit_2(joint_state_model, tmp_path):
    ros_or_skip()
    env = {**os.environ, "ROS_MASTER_URI": f"http://127.0.0.1:{free_port()}", "ROS_HOME": str(tmp_path)}
    done = subprocess.run([MLNSEQ, "ros", str(joint_state_model["model"])], env=env, capture_output=True, text=True,
                          timeout=WAIT_S)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith(f"error: no ROS master answers at {env['ROS_MASTER_URI']} (ROS_MASTER_URI)")
    missing = subprocess.run([MLNSEQ, "ros", str(tmp_path / "none.mlnseq")], env=env, capture_output=True, text=True,
                             timeout=WAIT_S)
    assert missing.returncode == 2 and missing.stderr.count("\n") == 1 and "none.mlnseq" in missing.stderr


def test_the_node_goes_on_after_its_master_restarts_and_drains_every_frame_it_holds_on_sigterm(
        joint_state_model, lagged_joint_state_model, tmp_path):
    """A real rosmaster killed (SIGKILL) and started again on its port: the node says so, registers again, and a
    recorder and a publisher that come after the restart find it (its publications and its subscription restored).
    Its model (lstm+smooth@5) decodes with --decode smooth@3, a lag of 3: on SIGTERM the 3 frames it holds, and the
    last tick, are decided and published before it exits 0: every message's frame, equal to predict --decode
    smooth@3 on a bag of the same messages; with --explain 2, each frame's why is explain's for it."""
    ros_or_skip()
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    path = os.pathsep.join(filter(None, [str(DRIVER.parent), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "ROS_MASTER_URI": uri, "ROS_IP": "127.0.0.1", "ROS_HOME": str(tmp_path / "ros"),
           "PYTHONUNBUFFERED": "1", "PYTHONPATH": path}
    rows = joint_state_model["live"][:100]
    np.save(tmp_path / "rows.npy", rows)
    started: list[subprocess.Popen] = []
    logs = {name: open(tmp_path / f"{name}.log", "w+") for name in ("master", "again", "node", "driver")}
    node_log = lambda: (tmp_path / "node.log").read_text()  # noqa: E731
    frames = lambda: (tmp_path / "node.jsonl").read_text().splitlines()  # noqa: E731

    def start(args, **kwargs) -> subprocess.Popen:
        started.append(subprocess.Popen(args, env=env, start_new_session=True, **kwargs))
        return started[-1]

    try:
        master = start(["rosmaster", "--core", "-p", str(port)], stdout=logs["master"], stderr=subprocess.STDOUT)
        wait_for(lambda: master_up(uri), "the master")
        node = start([MLNSEQ, "ros", str(lagged_joint_state_model), "--explain", "2", "--decode", "smooth@3"],
                     stdout=logs["node"], stderr=subprocess.STDOUT)
        wait_for(lambda: "listening to /joint_states" in node_log(), "the node")
        os.kill(master.pid, signal.SIGKILL)
        master.wait()
        wait_for(lambda: "is gone" in node_log(), "the node to see the master gone")
        start(["rosmaster", "--core", "-p", str(port)], stdout=logs["again"], stderr=subprocess.STDOUT)
        wait_for(lambda: "is back" in node_log(), "the node to register again")
        recorder = start([sys.executable, str(DRIVER), "record", "/mlnseq/activity/frame", str(tmp_path / "node.jsonl")],
                         stdout=subprocess.PIPE, text=True)
        assert recorder.stdout.readline().strip() == "ready"  # the new master knows the node's publication
        publisher = start([sys.executable, str(DRIVER), "publish", str(tmp_path / "rows.npy"), "1"],
                          stdout=logs["driver"], stderr=subprocess.STDOUT)
        assert publisher.wait(WAIT_S) == 0, (tmp_path / "driver.log").read_text()  # ... and its subscription
        wait_for(lambda: len(frames()) >= len(rows) - 4, "the frames decided while the feed runs", 10)
        time.sleep(0.5)
        assert len(frames()) == len(rows) - 4  # the last tick waits for a later message, 3 more for the lag
        node.send_signal(signal.SIGTERM)
        assert node.wait(WAIT_S) == 0, node_log()
        wait_for(lambda: len(frames()) == len(rows), "the drained frames", 10)
    finally:
        for process in reversed(started):
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
        for handle in logs.values():
            handle.close()
    lines = node_log().splitlines()
    gone = [line for line in lines if "is gone" in line]
    back = [line for line in lines if "is back" in line]
    assert gone == [f"ros: the master at {uri} is gone; the node goes on with the connections it has, and registers "
                    "again when a master answers"]
    assert len(back) == 1 and back[0].startswith(f"ros: the master at {uri} is back (process ")
    assert back[0].endswith("registered again 3 publications and 1 subscriptions")  # /rosout beside the node's two
    assert lines[-1] == f"ros: stopped after {len(rows)} frames (0 bad messages)"
    expected = predict.run(predict.PredictOptions(
        model=lagged_joint_state_model, source=ros_episode.write_bag(tmp_path / "live.bag", rows),
        reading=ReadOptions(decode="smooth@3"),
        output=tmp_path / "p.parquet")).table
    answers = [json.loads(line) for line in frames()]
    assert [a["class"] for a in answers] == expected["class"].to_list() and {a["lag"] for a in answers} == {3}
    assert [a["time"] for a in answers] == expected["time"].to_list()
    assert [a["stamp"] for a in answers] == [(ros_episode.START + k * ros_episode.STEP) / 1e9 for k in range(len(rows))]
    assert all(len(a["why"]) == 2 for a in answers)  # --explain 2: as explain gives them, by the frame's own time
    for answer in (answers[0], answers[-1]):
        found = explain.run(explain.ExplainOptions(model=lagged_joint_state_model, source=tmp_path / "live.bag",
                                                   reading=ReadOptions(decode="smooth@3"),
                                                   time=answer["stamp"])).explanation
        assert (found.frame, [t.text for t in found.largest(2)]) == (answer["frame"], [t["text"] for t in answer["why"]])
        np.testing.assert_allclose([t["contribution"] for t in answer["why"]],
                                   [t.contribution for t in found.largest(2)], atol=2e-6)
