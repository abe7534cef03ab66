"""ROS 2 message types as DDS types, built at run time from rosbags' typestore for a distro (no IDL written by
hand, no ROS install): ``sensor_msgs/msg/JointState`` is the ``@final`` struct ``sensor_msgs::msg::dds_::JointState_``
(rmw_cyclonedds' naming), serialized in plain CDR (XCDR1) to the bytes a ROS 2 bag holds for it.

Each built class also answers rclpy's ``get_fields_and_field_types``, so the live core reads its messages as it
reads rclpy's (stages/recognition/rostopic.py).
"""

from __future__ import annotations

import os
from typing import Any

from mlnseq.catalog.errors import BadInput

DEFAULT_DISTRO = "humble"
STRING = "std_msgs/msg/String"
DDS_PREFIX, DDS_SUFFIX = "dds_", "_"  # sensor_msgs::msg::dds_::JointState_
BASE_TYPES = {"byte": "uint8", "char": "uint8", "octet": "uint8", "int8": "int8", "uint8": "uint8",
              "int16": "int16", "uint16": "uint16", "int32": "int32", "uint32": "uint32", "int64": "int64",
              "uint64": "uint64", "float32": "float32", "float64": "float64"}


def distros() -> list[str]:
    """The ROS 2 distros rosbags holds message definitions for, oldest first."""
    from rosbags.typesys import Stores

    return [store.value.removeprefix("ros2_") for store in Stores if store.value.startswith("ros2_")]


def default_distro() -> str:
    """ROS_DISTRO where it names a ROS 2 distro (a sourced ROS 2 set-up), else humble."""
    named = os.environ.get("ROS_DISTRO", "").strip().lower()
    return named if named in distros() else DEFAULT_DISTRO


def dds_type_name(name: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``."""
    package, kind, short = name.split("/")
    return f"{package}::{kind}::{DDS_PREFIX}::{short}{DDS_SUFFIX}"


def ros_type_name(dds_name: str) -> str | None:
    """``sensor_msgs::msg::dds_::JointState_`` -> ``sensor_msgs/msg/JointState``; None for a name ROS 2 does not
    give a type."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != DDS_PREFIX or not parts[3].endswith(DDS_SUFFIX):
        return None
    return f"{parts[0]}/{parts[1]}/{parts[3][:-len(DDS_SUFFIX)]}"


def _fields_and_field_types(cls: type) -> dict[str, str]:
    """What rclpy's messages answer and the live core asks: the fields in order with their types."""
    return {name: str(kind) for name, kind in cls.__annotations__.items()}


class MessageTypes:
    """The ROS 2 message types of one distro's typestore, each built once when first asked for."""

    def __init__(self, distro: str):
        from rosbags.typesys import Stores, get_typestore

        if distro not in distros():
            raise BadInput(f"unknown --distro {distro!r}: choose one of {', '.join(distros())}")
        self.distro = distro
        self.store = get_typestore(Stores(f"ros2_{distro}"))
        self.built: dict[str, type] = {}

    def __contains__(self, name: str) -> bool:
        return name in self.store.fielddefs

    def get(self, name: str) -> type:
        """The DDS type of a ROS 2 message ``name`` (``pkg/msg/Type``); BadInput for one the distro lacks."""
        if name not in self.built:
            if name not in self:
                raise BadInput(f"{name} is not a message type of ROS 2 {self.distro} (rosbags' typestore): "
                               "check --distro")
            self.built[name] = self._build(name)
        return self.built[name]

    def numeric_fields(self, name: str) -> set[str]:
        """The top-level fields of ``name`` that hold numbers (a number, an array of numbers, or a message holding
        some), the header aside: the fields a model's features on a topic of this type are read from."""
        _, fields = self.store.fielddefs[name]
        return {field for field, node in fields if field != "header" and self._numeric(node)}

    def _numeric(self, node: tuple[Any, Any]) -> bool:
        from rosbags.typesys.store import Nodetype

        kind, detail = node
        if kind == Nodetype.NAME:
            return any(self._numeric(inner) for _, inner in self.store.fielddefs[detail][1])
        if kind == Nodetype.BASE:
            return detail[0] not in ("string", "wstring")
        return self._numeric(detail[0])

    def _build(self, name: str) -> type:
        from cyclonedds.idl import make_idl_struct

        _, fields = self.store.fielddefs[name]
        members = {field: self._member(node) for field, node in fields}  # an empty message has its one uint8 here
        built = make_idl_struct(name.rsplit("/", 1)[1], dds_type_name(name), members)
        built.get_fields_and_field_types = classmethod(_fields_and_field_types)  # a mixin base would enter the type
        return built

    def _member(self, node: tuple[Any, Any]) -> Any:
        """A field's DDS type from rosbags' (node type, details)."""
        from cyclonedds.idl import types
        from rosbags.typesys.store import Nodetype

        kind, detail = node
        if kind == Nodetype.NAME:
            return self.get(detail)
        if kind == Nodetype.BASE:
            base, bound = detail
            if base == "string":
                return types.bounded_str[bound] if bound else str
            if base == "bool":
                return bool
            if base not in BASE_TYPES:
                raise BadInput(f"a field of type {base} has no DDS type here (ROS 2 {self.distro})")
            return getattr(types, BASE_TYPES[base])
        element, size = detail
        if kind == Nodetype.ARRAY:
            return types.array[self._member(element), size]
        return types.sequence[self._member(element), size] if size else types.sequence[self._member(element)]

