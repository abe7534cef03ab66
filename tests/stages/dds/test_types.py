"""ROS 2 message types built from rosbags' typestore as DDS types: every message of Humble's 150 reads the CDR bytes
rosbags writes for it (a ROS 2 bag's, and a ROS 2 node's on the wire) and writes them back byte for byte; ROS's
type names; the live core reads a built message as it reads rclpy's."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the [ros2] extra is not installed")

from rosbags.typesys import Stores, get_typestore  # noqa: E402
from rosbags.typesys.store import Nodetype  # noqa: E402

from mlnseq.catalog.errors import BadInput  # noqa: E402
from mlnseq.dds import types  # noqa: E402
from mlnseq.recognition import rostopic  # noqa: E402

DTYPES = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8, "int16": np.int16,
          "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
          "float32": np.float32, "float64": np.float64}


def scalar(base: str, bound: int, rng: np.random.Generator):
    if base == "string":
        return "ab,c"[: bound or 4]
    if base == "bool":
        return bool(rng.integers(2))
    if base.startswith("float"):
        return float(np.asarray(rng.normal(), dtype=DTYPES[base]))
    info = np.iinfo(DTYPES[base])
    top = 127 if base == "byte" else info.max  # a byte: rosbags packs it signed, ROS 2 (an octet) unsigned
    return int(info.min + int(rng.random() * (top - info.min)))  # the 64-bit ranges too


def value(store, node, rng: np.random.Generator):
    """A random value of a field, as rosbags holds it (numbers in arrays as numpy arrays)."""
    kind, detail = node
    if kind == Nodetype.BASE:
        return scalar(*detail, rng)
    if kind == Nodetype.NAME:
        return message(store, detail, rng)
    element, size = detail
    n = size if kind == Nodetype.ARRAY else int(rng.integers(0, (size or 3) + 1))
    items = [value(store, element, rng) for _ in range(n)]
    if element[0] == Nodetype.BASE and element[1][0] != "string":
        return np.array(items, dtype=DTYPES[element[1][0]])
    return items


def message(store, name: str, rng: np.random.Generator):
    _, fields = store.fielddefs[name]
    return store.types[name](**{field: value(store, node, rng) for field, node in fields})


def same(original, built) -> bool:
    """Whether a built message holds the values of rosbags' message, field by field."""
    if hasattr(original, "__msgtype__"):
        return all(same(getattr(original, f), getattr(built, f)) for f in built.get_fields_and_field_types())
    if isinstance(original, np.ndarray):
        built = np.frombuffer(built, dtype=np.uint8) if isinstance(built, bytes) else built  # a uint8[N] array
        return np.array_equal(original, np.asarray(built, dtype=original.dtype))
    if isinstance(original, list):
        return len(original) == len(built) and all(same(a, b) for a, b in zip(original, built))
    return original == built


def test_every_humble_message_reads_and_writes_rosbags_cdr_bytes():
    store, built, rng = get_typestore(Stores.ROS2_HUMBLE), types.MessageTypes("humble"), np.random.default_rng(7)
    assert len(store.fielddefs) == 150
    for name in sorted(store.fielddefs):
        original = message(store, name, rng)
        raw = bytes(store.serialize_cdr(original, name))
        kind = built.get(name)
        assert kind.__idl_typename__ == types.dds_type_name(name)
        read = kind.deserialize(raw)
        assert list(read.get_fields_and_field_types()) == [field for field, _ in store.fielddefs[name][1]]
        assert same(original, read) and read.serialize() == raw, name


def test_the_live_core_reads_a_built_joint_state_as_rclpys():
    store, built = get_typestore(Stores.ROS2_HUMBLE), types.MessageTypes("humble")
    T = store.types
    state = T["sensor_msgs/msg/JointState"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1_700_000_000, nanosec=20_000_000),
                                        frame_id="base"),
        name=["elbow", "wrist"], position=np.array([0.5, -1.25]), velocity=np.zeros(0), effort=np.array([3.0, 4.0]))
    got = built.get("sensor_msgs/msg/JointState").deserialize(bytes(store.serialize_cdr(state, state.__msgtype__)))
    assert rostopic.message_time(got) == 1_700_000_000_020_000_000
    assert rostopic.message_values(got, "/joint_states") == {
        "/joint_states/position/elbow": 0.5, "/joint_states/position/wrist": -1.25,
        "/joint_states/effort/elbow": 3.0, "/joint_states/effort/wrist": 4.0}


def test_ros_type_names_and_distros(monkeypatch):
    assert types.dds_type_name("sensor_msgs/msg/JointState") == "sensor_msgs::msg::dds_::JointState_"
    assert types.ros_type_name("sensor_msgs::msg::dds_::JointState_") == "sensor_msgs/msg/JointState"
    assert types.ros_type_name("JointState") is None and types.ros_type_name("a::b::c::D") is None
    assert {"humble", "iron", "jazzy"} <= set(types.distros())
    monkeypatch.setenv("ROS_DISTRO", "jazzy")
    assert types.default_distro() == "jazzy"
    monkeypatch.setenv("ROS_DISTRO", "noetic")  # a ROS 1 set-up: the typestores' default
    assert types.default_distro() == "humble"
    with pytest.raises(BadInput, match="unknown --distro 'rolling': choose one of .*humble"):
        types.MessageTypes("rolling")
    with pytest.raises(BadInput, match="foo_msgs/msg/Bar is not a message type of ROS 2 humble"):
        types.MessageTypes("humble").get("foo_msgs/msg/Bar")
