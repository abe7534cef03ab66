"""The ROS 1 test's publisher and recorder (rospy), run as their own processes against the test's master.

    python tests/ros_driver.py publish ROWS.npy SUBSCRIBERS [HZ]  # /joint_states at 100 Hz (or HZ), stamped, once
                                                                  # they listen
    python tests/ros_driver.py record TOPIC FILE              # each std_msgs/String's data a line; "ready" on stdout
"""

from __future__ import annotations

import sys
import time

import numpy as np
import rospy

import ros_episode

WAIT_S = 30


def publish(rows_file: str, subscribers: int, hz: float = 1e9 / ros_episode.STEP) -> None:
    from sensor_msgs.msg import JointState

    rospy.init_node("episode", anonymous=True, disable_signals=True)
    publisher = rospy.Publisher("/joint_states", JointState, queue_size=1000)
    deadline = time.monotonic() + WAIT_S
    while publisher.get_num_connections() < subscribers:
        if time.monotonic() > deadline:
            sys.exit(f"publish: {publisher.get_num_connections()} of {subscribers} subscribers after {WAIT_S} s")
        time.sleep(0.05)
    rate, step = rospy.Rate(hz), round(1e9 / hz)
    for k, row in enumerate(np.load(rows_file)):
        message = JointState(name=ros_episode.JOINTS, position=row[:7].tolist())
        t = ros_episode.START + k * step
        message.header.stamp = rospy.Time(t // 10**9, t % 10**9)
        message.header.seq = k
        publisher.publish(message)
        rate.sleep()
    time.sleep(0.5)  # let the last messages leave before the connections close


def record(topic: str, path: str) -> None:
    from std_msgs.msg import String

    with open(path, "a") as out:
        rospy.init_node("recorder", anonymous=True, disable_signals=True)
        subscriber = rospy.Subscriber(topic, String, lambda m: (out.write(m.data + "\n"), out.flush()), queue_size=1000)
        deadline = time.monotonic() + WAIT_S
        while subscriber.get_num_connections() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        print("ready" if subscriber.get_num_connections() else "no publisher", flush=True)
        while True:
            time.sleep(1)


if __name__ == "__main__":
    if sys.argv[1] == "publish":
        publish(sys.argv[2], int(sys.argv[3]), *map(float, sys.argv[4:5]))
    else:
        record(sys.argv[2], sys.argv[3])
