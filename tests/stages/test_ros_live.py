"""`rostopic echo -p /joint_states` into stream (no ROS needed): the rows are put on the model's clock as collect
put the training bag on it, so a 1 kHz feed and a 100 Hz feed both give predict's frames on a bag of the same
messages; each answer carries its frame's time; bad rows are one line each and the stream goes on."""

from __future__ import annotations

import dataclasses

import io
import json

import numpy as np
import polars as pl
import pytest

pytest.importorskip("rosbags", reason="the [recordings] extra is not installed")

import ros_episode  # noqa: E402
from mlnseq import predict, stream  # noqa: E402
from mlnseq.catalog import artifacts  # noqa: E402
from mlnseq.catalog.errors import BadInput  # noqa: E402
from mlnseq.recognition import live  # noqa: E402


@pytest.fixture(scope="module")
def expected(joint_state_model, tmp_path_factory) -> pl.DataFrame:
    """predict on a ROS 1 bag of the live rows at 100 Hz."""
    folder = tmp_path_factory.mktemp("live-bag")
    bag = ros_episode.write_bag(folder / "live.bag", joint_state_model["live"])
    options = predict.PredictOptions(model=joint_state_model["model"], source=bag, output=folder / "p.parquet")
    return predict.run(options).table


def run_stream(model, lines: list[str], **options) -> tuple[list[dict], list[str]]:
    out, err = [], []
    source = io.BytesIO(("\n".join(lines) + "\n").encode())
    stream.run(stream.StreamOptions(model=model, **options), source, out.append, err.append)
    return [json.loads(line) for line in out], err


@pytest.mark.parametrize("repeat", [1, 10])
def test_a_100_hz_and_a_1_khz_feed_give_predicts_frames_on_the_bag(joint_state_model, expected, repeat):
    rows = joint_state_model["live"]
    answers, notes = run_stream(joint_state_model["model"], ros_episode.echo_csv(rows, repeat))
    assert len(answers) == expected.height == len(rows)
    assert [a["class"] for a in answers] == expected["class"].to_list()
    classes = list(answers[0]["probabilities"])
    got = np.array([[a["probabilities"][c] for c in classes] for a in answers])
    want = expected.select(artifacts.class_probability_column(c) for c in classes).to_numpy()
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert [a["time"] for a in answers] == expected["time"].to_list()  # from the recording's start, as predict's
    assert [a["stamp"] for a in answers] == [(ros_episode.START + k * ros_episode.STEP) / 1e9 for k in range(len(rows))]
    assert expected["stamp"].to_list() == [a["stamp"] for a in answers]  # and predict's stamp: the messages' clock
    warned = [n for n in notes if n.startswith("warning:")]
    assert warned == ([] if repeat == 1 else
                      ["warning: /joint_states arrives at 1000 Hz, the model's clock is 100 Hz (more than 2x apart): "
                       "each frame holds the last message at its tick, as collect read the bags"])


def test_bad_rows_are_one_line_each_and_the_stream_goes_on(joint_state_model, expected):
    lines = ros_episode.echo_csv(joint_state_model["live"][:6])
    header, good = lines[0], lines[1:]
    no_time = good[1].split(",")
    no_time[0] = no_time[2] = "0"
    other_joint = good[2].replace("panda_joint3", "elbow")
    back = good[3].split(",")  # the fourth message again, 5 ms earlier: back in time by less than a frame
    back[0] = back[2] = str(int(back[2]) - 5_000_000)
    back = ",".join(back)
    text = good[3].split(",")
    text[-1] = "nan?"
    feed = [header, good[0], ",".join(no_time), good[1], other_joint, good[2], good[3], back, ",".join(text),
            "1,2", good[4], good[5]]
    answers, notes = run_stream(joint_state_model["model"], feed)
    assert [a["class"] for a in answers] == expected["class"].to_list()[:6]
    errors = [n for n in notes if n.startswith("error:")]
    assert [e.split(":")[1].strip() for e in errors] == ["line 3", "line 5", "line 8", "line 9", "line 10"]
    assert "no time" in errors[0] and "no position of joint 'panda_joint3'" in errors[1]
    assert "goes back in time" in errors[2] and "'nan?', not a number" in errors[3] and "2 fields" in errors[4]
    with pytest.raises(stream.InputLine, match="line 3: no time"):
        run_stream(joint_state_model["model"], feed, strict=True)


def test_a_feed_of_another_type_or_a_model_of_two_topics_is_refused_at_the_start(joint_state_model):
    from mlnseq.recognition.recognizer import Recognizer

    model = joint_state_model["model"]
    with pytest.raises(BadInput, match=r"the feed has no joint names \(field.name0 ...\) for the model.s feature "
                       r"./joint_states/position/panda_joint1.: is it `rostopic echo -p /joint_states`"):
        run_stream(model, ["%time,field.data", "1700000000000000000,1.5"])
    two = Recognizer.load(model)
    two.manifest = dataclasses.replace(two.manifest, reading={**two.manifest.reading,
                                                               "topics": ["/joint_states", "/gripper"]})
    with pytest.raises(BadInput, match=r"reads 2 topics \(/joint_states, /gripper\) and `rostopic echo -p` shows one: "
                       r"run the node `mlnseq ros MODEL`"):
        live.echo_topic(live.LiveRecognizer(two, print))


def test_a_model_not_read_from_bags_knows_no_topics(joint_state_model):
    from mlnseq.recognition.recognizer import Recognizer

    model = Recognizer.load(joint_state_model["model"])
    model.manifest = dataclasses.replace(model.manifest, reading={"env": "table"})
    with pytest.raises(BadInput, match="read with --env table, not from ROS bags"):
        live.LiveRecognizer(model, print)


def test_ctrl_c_answers_the_ticks_up_to_the_last_row_read(joint_state_model):
    import signal
    import subprocess
    import sys
    from pathlib import Path

    lines = ros_episode.echo_csv(joint_state_model["live"][:5])
    process = subprocess.Popen([str(Path(sys.executable).parent / "mlnseq"), "stream", str(joint_state_model["model"])],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        process.stdin.write("\n".join(lines) + "\n")
        process.stdin.flush()
        answers = [json.loads(process.stdout.readline()) for _ in range(4)]  # a tick waits for a later message
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
    finally:
        process.kill()
    answers += [json.loads(line) for line in out.splitlines()]
    assert process.returncode == 130, err
    assert [a["frame"] for a in answers] == [0, 1, 2, 3, 4]


def test_two_topics_on_the_clock_as_collect_reads_their_bag(joint_state_model, tmp_path):
    """/joint_states at 100 Hz and /gripper at 20 Hz from 55 ms on (the clock starts there), as a bag read by
    collect at 100 Hz and as messages through HoldLast one at a time, the gripper also sent at 1 kHz."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from mlnseq import sources
    from mlnseq.recognition import rostopic
    from mlnseq.sources import SourceOptions
    from mlnseq.sources.recording import Labels, TableColumns

    rows = joint_state_model["live"][:200]
    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Float64 = store.types["sensor_msgs/msg/JointState"], store.types["std_msgs/msg/Float64"]
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    start, step = ros_episode.START, ros_episode.STEP
    messages = [(start + k * step, "/joint_states", row[:7]) for k, row in enumerate(rows)]
    messages += [(start + 55_000_000 + k * 50_000_000, "/gripper", np.array([float(k)])) for k in range(39)]
    messages.sort(key=lambda m: (m[0], m[1] != "/joint_states"))
    with Writer(tmp_path / "two.bag") as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        gripper = writer.add_connection("/gripper", Float64.__msgtype__, typestore=store)
        for t, topic, values in messages:
            if topic == "/gripper":
                writer.write(gripper, t, store.serialize_ros1(Float64(data=values[0]), Float64.__msgtype__))
            else:
                stamp = Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="")
                message = JointState(header=stamp, name=ros_episode.JOINTS, position=values.copy(),
                                     velocity=np.zeros(0), effort=np.zeros(0))
                writer.write(joints, t, store.serialize_ros1(message, JointState.__msgtype__))
    recording = sources.read("rosbag", tmp_path / "two.bag", TableColumns(),
                             SourceOptions(topics=("/joint_states", "/gripper"), rate=100), label=Labels.NONE)[0]
    names = recording.features.columns
    slots = rostopic.features_by_topic(names, ["/joint_states", "/gripper"])
    thousand = sorted([*(m for m in messages if m[1] == "/joint_states"),
                       *((t + j * 1_000_000, topic, values) for t, topic, values in messages if topic == "/gripper"
                         for j in range(50))], key=lambda m: (m[0], m[1] != "/joint_states"))
    for fast, feed in ((False, messages), (True, thousand)):
        clock, ticks = rostopic.HoldLast(slots, len(names), 100), []
        for t, topic, values in feed:
            ticks += clock.push(topic, t, values)
        ticks += clock.finish()
        times, got = np.array([t for t, _ in ticks]), np.array([r for _, r in ticks])
        expected = recording.features.to_numpy()
        assert times[0] == start + 55_000_000 and len(ticks) == len(expected) + fast  # 1 kHz: 14 ms more, one tick
        np.testing.assert_array_equal(got[:len(expected)], expected)
        np.testing.assert_allclose(times[:len(expected)], start + recording.time.to_numpy() * 1e9, rtol=0, atol=1)


def test_a_feed_replayed_in_a_loop_is_a_new_episode_each_time_it_jumps_back(joint_state_model, expected):
    rows = joint_state_model["live"][:60]
    lines = ros_episode.echo_csv(rows)
    answers, notes = run_stream(joint_state_model["model"], lines + lines[1:] + lines[1:31])
    assert [(a["episode"], a["frame"]) for a in answers] == [(e, k) for e, n in ((0, 60), (1, 60), (2, 30))
                                                             for k in range(n)]
    for episode, first in ((0, 0), (1, 60), (2, 120)):
        n = 30 if episode == 2 else 60
        assert [a["class"] for a in answers[first:first + n]] == expected["class"].to_list()[:n]
        assert [a["time"] for a in answers[first:first + n]] == [a["time"] for a in answers[:n]]
        assert [a["stamp"] for a in answers[first:first + n]] == [a["stamp"] for a in answers[:n]]
    jumps = [n for n in notes if "goes back" in n]
    assert jumps == [f"note: /joint_states goes back 0.590 s in time (to {ros_episode.START / 1e9:.3f} s, a bag "
                     f"replayed in a loop?): episode {e} starts, the frames before it decided" for e in (1, 2)]


def test_a_feed_silent_past_the_hold_skips_those_frames_as_predict_drops_them_from_its_bag(joint_state_model,
                                                                                          tmp_path):
    """Rows 0-49, then 3 s of silence, then rows 50-99: the 2 s after row 49 hold it, the rest are skipped; predict
    on a bag of the same messages drops the same frames and gives the same classes and probabilities."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    rows = joint_state_model["live"][:100]
    stamps = [ros_episode.START + k * ros_episode.STEP + (3 * 10**9 if k >= 50 else 0) for k in range(100)]
    lines = ros_episode.echo_csv(rows)
    lines = [lines[0]] + [line.replace(str(ros_episode.START + k * ros_episode.STEP), str(stamps[k]))
                          for k, line in enumerate(lines[1:])]
    answers, notes = run_stream(joint_state_model["model"], lines)
    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time = (store.types[n] for n in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                         "builtin_interfaces/msg/Time"))
    with Writer(tmp_path / "silent.bag") as writer:
        connection = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        for t, row in zip(stamps, rows):
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id=""),
                                 name=ros_episode.JOINTS, position=row[:7].copy(), velocity=np.zeros(0),
                                 effort=np.zeros(0))
            writer.write(connection, t, store.serialize_ros1(message, JointState.__msgtype__))
    table = predict.run(predict.PredictOptions(model=joint_state_model["model"], source=tmp_path / "silent.bag",
                                               output=tmp_path / "p.parquet")).table
    assert len(answers) == table.height == 100 + 200  # the rows, and 2 s at 100 Hz held; 100 ticks skipped
    assert [a["class"] for a in answers] == table["class"].to_list()
    classes = list(answers[0]["probabilities"])
    np.testing.assert_allclose([[a["probabilities"][c] for c in classes] for a in answers],
                               table.select(artifacts.class_probability_column(c) for c in classes).to_numpy(),
                               atol=1e-5)
    start = ros_episode.START / 1e9
    assert [n for n in notes if n.startswith("note: /joint_states")] == [
        f"note: /joint_states sent nothing for over 2 s (--max-hold): the frames from {start + 2.5:.3f} s are skipped "
        "until it sends again", f"note: /joint_states sent again: 100 frames skipped ({start + 3.5:.3f} s)"]


class Joints:
    """A sensor_msgs/JointState as a client library hands it over (fields by __slots__, a sec/nanosec stamp)."""

    __slots__ = ("header", "name", "position", "velocity", "effort")

    def __init__(self, t: int, row: np.ndarray):
        from types import SimpleNamespace

        self.header = SimpleNamespace(stamp=SimpleNamespace(sec=t // 10**9, nanosec=t % 10**9))
        self.name, self.position, self.velocity, self.effort = list(ros_episode.JOINTS), row[:7].tolist(), [], []


def test_the_node_core_queue_drops_the_oldest_counts_them_and_drains_what_it_holds(joint_state_model):
    from mlnseq.recognition.recognizer import Recognizer

    rows = joint_state_model["live"][:200]
    messages = [Joints(ros_episode.START + k * ros_episode.STEP, row) for k, row in enumerate(rows)]
    notes: list[str] = []
    feed = live.MessageFeed(Recognizer.load(joint_state_model["model"]), notes.append, lambda: 0.0, queue_size=50)
    for message in messages[:120]:
        feed.offer("/joint_states", message, 0)
    first = feed.pending(0)
    for message in messages[120:]:
        feed.offer("/joint_states", message, 0)
    assert feed.dropped == 70 + 30 and len(feed.queue) == 50
    rest = feed.drain()
    alone = live.MessageFeed(Recognizer.load(joint_state_model["model"]), print, lambda: 0.0)
    one_by_one = [f for m in messages[70:120] + messages[150:] for f in alone.receive("/joint_states", m, 0)]
    one_by_one += alone.finish()
    assert [f.time for f in first + rest] == [f.time for f in one_by_one]
    assert [f.prediction.name for f in first + rest] == [f.prediction.name for f in one_by_one]
    assert [n for n in notes if n.startswith("warning")] == [
        "warning: the recogniser falls behind the feed: 70 messages dropped so far, the oldest first (the queue holds "
        "50)"]  # said once, then at most every 10 s
    assert feed.frames == len(one_by_one) and feed.drain() == []


def test_an_echo_feed_explains_every_frame_as_explain_does_and_explain_finds_it_by_either_clock(
        lagged_joint_state_model, joint_state_model, tmp_path):
    """stream --explain 2 on `rostopic echo -p` rows (the lagged model: formulas, a lag of 5): every line carries why,
    the two largest terms `explain` gives for that frame of a bag of the same messages, found by the line's time
    (seconds from the start) and by its stamp (the messages' clock); a time a frame past the end is refused."""
    from mlnseq import explain

    rows = joint_state_model["live"][:120]
    bag = ros_episode.write_bag(tmp_path / "live.bag", rows)
    answers, _ = run_stream(lagged_joint_state_model, ros_episode.echo_csv(rows), explain=2)
    assert len(answers) == len(rows) and all(len(a["why"]) == 2 for a in answers)
    assert {"network", "past"} <= {t["kind"] for a in answers for t in a["why"]}
    for answer in (answers[0], answers[37], answers[-1]):
        for clock in ("time", "stamp"):
            found = explain.run(explain.ExplainOptions(model=lagged_joint_state_model, source=bag,
                                                       time=answer[clock])).explanation
            assert found.frame == answer["frame"] and found.chosen == answer["class"], clock
            assert [t["text"] for t in answer["why"]] == [t.text for t in found.largest(2)]
            np.testing.assert_allclose([t["contribution"] for t in answer["why"]],
                                       [t.contribution for t in found.largest(2)], atol=2e-6)
    past = answers[-1]["stamp"] + ros_episode.STEP / 1e9
    with pytest.raises(BadInput, match=r"--time 1700000001\.2: outside the episode \(its times run 0-1\.19, its stamps "
                                       r"1700000000-1700000001\.19\); give a time within it"):
        explain.run(explain.ExplainOptions(model=lagged_joint_state_model, source=bag, time=past))


def test_predict_on_a_bag_writes_the_stamp_beside_the_time_and_rerun_gets_both_timelines(joint_state_model, tmp_path):
    rr = pytest.importorskip("rerun", reason="the [recordings] extra is not installed")
    rows = joint_state_model["live"][:50]
    bag = ros_episode.write_bag(tmp_path / "live.bag", rows)
    table = predict.run(predict.PredictOptions(model=joint_state_model["model"], source=bag, rerun=tmp_path / "v.rrd",
                                               intervals=tmp_path / "i.csv", output=tmp_path / "p.parquet")).table
    assert table.columns[:4] == ["episode", "frame", "time", "stamp"]
    assert table["stamp"].to_list() == [(ros_episode.START + k * ros_episode.STEP) / 1e9 for k in range(len(rows))]
    assert table["time"].to_list() == [k * ros_episode.STEP / 1e9 for k in range(len(rows))]
    timelines = {name for chunk in rr.chunk.RrdReader(tmp_path / "v.rrd").stream()
                 if chunk.entity_path.endswith("/class/predicted") for name in chunk.timeline_names}
    assert timelines == {"time", "frame", "stamp"}
    assert pl.read_csv(tmp_path / "i.csv")["start"][0] == 0.0  # intervals: the recording's time, as --labels reads
