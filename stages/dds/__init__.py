"""ROS 2 on the wire, without a ROS 2 install: a ROS 2 node talks DDS, and so does a Cyclone DDS participant
(the ``cyclonedds`` wheel, its C library inside) that names topics, types and QoS as ROS 2 does.

``types.py`` builds the ROS 2 message types at run time from rosbags' typestore for a distro (``--distro``),
``domain.py`` is the participant: the domain and discovery ROS 2's environment asks for (``ROS_DOMAIN_ID``,
``ROS_LOCALHOST_ONLY``, ``ROS_AUTOMATIC_DISCOVERY_RANGE``), ``rt/`` topic names, ROS's QoS profiles and the
subscriptions made as publishers are discovered; ``node.py`` is `mlnseq ros --ros 2`, the recogniser node on the
live core (recognition/live.py's `MessageFeed`), which `mlnseq ros` (ROS 1) runs as well.
"""

from __future__ import annotations

from mlnseq.catalog.errors import MissingExtra, install_hint

EXTRA = "ros2"  # the extra of cyclonedds and rosbags


def require() -> None:
    """Refuse in one line when the DDS binding or the typestore is not installed."""
    for module in ("cyclonedds", "rosbags"):
        try:
            __import__(module)
        except ImportError:
            raise MissingExtra(f"ROS 2 over DDS needs cyclonedds and rosbags ({module} is not installed): "
                               f"{install_hint(EXTRA)}") from None

