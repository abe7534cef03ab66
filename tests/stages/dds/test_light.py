"""The ros2 extra is light: it asks for cyclonedds and rosbags alone, and the ROS 2 node (a model loaded, the types
built, a participant with its writers, the frames held decided at the stop) runs with torch and scipy unimportable."""

from __future__ import annotations

import importlib.metadata
import os
import random
import subprocess
import sys

import pytest
from packaging.requirements import Requirement

NODE_WITHOUT_TORCH = """
import sys, threading
sys.modules.update(torch=None, scipy=None)  # importing them raises ImportError; looking them up finds nothing
from mlnseq.dds import node
from mlnseq.dds.domain import QosChoice
stop = threading.Event()
stop.set()
print(node.run(node.NodeOptions(sys.argv[1], "/mlnseq/activity", "mlnseq", "humble", QosChoice.AUTO), print, stop))
print(sorted(m for m, module in sys.modules.items() if module is not None and m.split(".")[0] in ("torch", "scipy")))
"""


def test_the_ros2_extra_asks_for_cyclonedds_and_rosbags_alone():
    requirements = [Requirement(text) for text in importlib.metadata.requires("mlnseq")]
    ros2 = {r.name for r in requirements if r.marker is not None and r.marker.evaluate({"extra": "ros2"})}
    base = {r.name for r in requirements if r.marker is None}
    assert ros2 - base == {"cyclonedds", "rosbags"}


def test_the_ros2_node_runs_without_torch_and_scipy(joint_state_model, tmp_path):
    pytest.importorskip("cyclonedds", reason="the [ros2] extra is not installed")
    config = tmp_path / "cyclonedds.xml"  # the loopback, no multicast, a tag no other participant has
    config.write_text('<CycloneDDS><Domain><General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
                      '<AllowMulticast>false</AllowMulticast></General><Discovery>'
                      f'<Tag>mlnseq-light-{os.getpid()}-{random.randrange(10**9)}</Tag></Discovery></Domain></CycloneDDS>')
    env = {**os.environ, "CYCLONEDDS_URI": config.as_uri(), "ROS_DOMAIN_ID": str(random.randrange(1, 200))}
    done = subprocess.run([sys.executable, "-c", NODE_WITHOUT_TORCH, str(joint_state_model["model"])], env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-2:] == ["(0, 0, 0)", "[]"], done.stdout
