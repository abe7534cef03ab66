"""`mlnseq echo`'s rows: a ROS 2 message flattened as `rostopic echo -p` prints it, under the names collect gives a
bag's fields, so that `stream` reads each of a bag-trained model's features from them (nested fields, fixed arrays,
the header stamp in ns, text quoted, floats in full)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the [ros2] extra is not installed")

from rosbags.rosbag2 import Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from mlnseq import echo  # noqa: E402
from mlnseq.dds.types import MessageTypes  # noqa: E402
from mlnseq.recognition import rostopic  # noqa: E402
from mlnseq.sources import rosbag  # noqa: E402
from mlnseq.sources.recording import Labels, TableColumns  # noqa: E402
from mlnseq.sources import SourceOptions  # noqa: E402

IMU = "sensor_msgs/msg/Imu"


def imu(store, k: int):
    T = store.types
    t = 1_700_000_000 * 10**9 + k * 10_000_000
    return T[IMU](header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9,
                                                                                       nanosec=t % 10**9),
                                                  frame_id="imu,link"),
                  orientation=T["geometry_msgs/msg/Quaternion"](x=0.1 * k, y=0.2, z=0.3, w=1 / 3),
                  orientation_covariance=np.arange(9, dtype=np.float64) + k,
                  angular_velocity=T["geometry_msgs/msg/Vector3"](x=k, y=-1.5, z=2e-9),
                  angular_velocity_covariance=np.zeros(9),
                  linear_acceleration=T["geometry_msgs/msg/Vector3"](x=9.81, y=0.0, z=-0.1 * k),
                  linear_acceleration_covariance=np.full(9, 0.25))


def test_an_imus_rows_hold_every_feature_collect_read_from_its_bag(tmp_path):
    store = get_typestore(Stores.ROS2_HUMBLE)
    raw = [bytes(store.serialize_cdr(imu(store, k), IMU)) for k in range(3)]
    with Writer(tmp_path / "imu", version=8) as writer:
        connection = writer.add_connection("/imu", IMU, typestore=store)
        for k, data in enumerate(raw):
            writer.write(connection, 1_700_000_000 * 10**9 + k * 10_000_000, data)
    [recording] = rosbag.read(tmp_path / "imu", TableColumns(), SourceOptions(topics=("/imu",)), Labels.NONE)
    features = list(recording.features.columns)
    built = MessageTypes("humble").get(IMU)
    columns = [echo.fields(built.deserialize(data)) for data in raw]
    header = ",".join(["%time", *(name for name, _ in columns[0])])
    assert header.startswith("%time,field.header.stamp,field.header.frame_id,field.orientation.x,")
    reader = rostopic.EchoCsv(header, "/imu", features)  # every feature has its column
    for k, row in enumerate(columns):
        message = reader.row(echo.csv_line([123, *(value for _, value in row)]))
        assert message.time == 1_700_000_000 * 10**9 + k * 10_000_000
        assert message.values == dict(zip(features, recording.features.row(k)))
    assert echo.csv_line([1, True, False, "a,b", 0.1]) == '1,1,0,"a,b",0.1'
