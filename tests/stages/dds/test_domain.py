"""The participant as rmw_cyclonedds makes it: ROS 2's topic names and domain, the Cyclone configuration each
distro's ROS_ variables ask for (and that Cyclone accepts), and the start-up errors of `mlnseq ros --ros 2` and
`mlnseq echo`: one line, exit 2."""

from __future__ import annotations

import os
import random

import pytest
from typer.testing import CliRunner

from mlnseq.catalog.errors import BadInput
from mlnseq.dds import domain
from mlnseq_cli.main import app

runner = CliRunner()
LOCALHOST_FRAGMENT = ("<CycloneDDS><Domain><General><AllowMulticast>false</AllowMulticast></General><Discovery>"
                      "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
                      "<Peers><Peer address=\"localhost\"/>{peers}</Peers></Discovery></Domain></CycloneDDS>")


def test_topic_names_and_the_domain():
    assert domain.topic_name("/joint_states") == "rt/joint_states"
    assert domain.topic_name("mlnseq/activity/frame") == "rt/mlnseq/activity/frame"
    assert domain.domain_id({}) == 0 and domain.domain_id({"ROS_DOMAIN_ID": " 42 "}) == 42
    for bad in ("abc", "-1", "233"):
        with pytest.raises(BadInput, match=f"ROS_DOMAIN_ID '{bad}': a domain id is a whole number from 0 to 232"):
            domain.domain_id({"ROS_DOMAIN_ID": bad})


def test_each_distros_discovery_settings():
    assert domain.discovery_config("humble", {}) == ""
    assert domain.discovery_config("humble", {"ROS_LOCALHOST_ONLY": "1", "CYCLONEDDS_URI": "file:///c.xml"}) == (
        "<CycloneDDS><Domain><General><Interfaces><NetworkInterface address=\"127.0.0.1\"/></Interfaces></General>"
        "</Domain></CycloneDDS>,file:///c.xml")
    assert domain.discovery_config("humble", {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}) == ""  # Iron's variable
    localhost = LOCALHOST_FRAGMENT.format(peers="")
    assert domain.discovery_config("jazzy", {"ROS_AUTOMATIC_DISCOVERY_RANGE": "localhost"}) == localhost
    assert domain.discovery_config("jazzy", {"ROS_LOCALHOST_ONLY": "1"}) == localhost  # its old name, unset range
    assert domain.discovery_config("iron", {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
                                            "ROS_STATIC_PEERS": "10.0.0.2; robot.local"}) == LOCALHOST_FRAGMENT.format(
        peers="<Peer address=\"10.0.0.2\"/><Peer address=\"robot.local\"/>")
    assert domain.discovery_config("jazzy", {"ROS_STATIC_PEERS": "10.0.0.2"}) == (  # SUBNET, the default
        "<CycloneDDS><Domain><Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32"
        "</MaxAutoParticipantIndex><Peers><Peer address=\"10.0.0.2\"/></Peers></Discovery></Domain></CycloneDDS>")
    off = domain.discovery_config("jazzy", {"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF", "ROS_STATIC_PEERS": "10.0.0.2"})
    assert "<AllowMulticast>false</AllowMulticast>" in off and f"<Tag>ros_discovery_off_{os.getpid()}</Tag>" in off
    assert "Peer" not in off
    assert domain.discovery_config("kilted", {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT"}) == ""
    with pytest.raises(BadInput, match="ROS_AUTOMATIC_DISCOVERY_RANGE 'LAN': choose one of SUBNET, LOCALHOST"):
        domain.discovery_config("jazzy", {"ROS_AUTOMATIC_DISCOVERY_RANGE": "lan"})


@pytest.mark.parametrize("scope", ["LOCALHOST", "OFF"])
def test_cyclone_accepts_the_configurations(scope):
    """No multicast in either; a discovery tag of the test's own, so that nothing else is met."""
    pytest.importorskip("cyclonedds", reason="the [ros2] extra is not installed")
    tag = f"<CycloneDDS><Domain><Discovery><Tag>mlnseq-{os.getpid()}-{random.randrange(10**9)}</Tag></Discovery>" \
          "</Domain></CycloneDDS>"
    participant = domain.Participant("jazzy", "mlnseq_test", {
        "ROS_DOMAIN_ID": str(random.randrange(1, 200)), "ROS_AUTOMATIC_DISCOVERY_RANGE": scope, "CYCLONEDDS_URI": tag})
    assert participant.new_publications() == []


def test_start_up_errors_are_one_line_and_exit_2(tmp_path, monkeypatch, own_data_glitch):
    pytest.importorskip("cyclonedds", reason="the [ros2] extra is not installed")
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)
    model = tmp_path / "none.mlnseq"
    for args, env, error in (
            (["ros", str(model), "--ros", "2"], {}, f"error: model file {model} not found"),
            (["ros", str(own_data_glitch["model"]), "--ros", "2"], {}, "error: the model's frames were read with --env "
                                                                       "table, not from ROS bags"),
            (["ros", str(model), "--ros", "3"], {}, "error: unknown --ros '3': choose one of auto, 1, 2"),
            (["ros", str(model), "--qos", "fast"], {}, "error: unknown --qos 'fast': choose one of auto, reliable, "
                                                       "best-effort"),
            (["echo", "/joint_states", "--distro", "rolling"], {}, "error: unknown --distro 'rolling'"),
            (["echo", "/joint_states", "--count", "0"], {}, "error: --count 0: at least 1 message"),
            (["echo", "/joint_states"], {"ROS_DOMAIN_ID": "x"}, "error: ROS_DOMAIN_ID 'x': a domain id")):
        result = runner.invoke(app, args, env=env)
        assert result.exit_code == 2 and result.output.count("\n") == 1, (args, result.output)
        assert result.output.startswith(error), (args, result.output)
