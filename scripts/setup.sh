#!/usr/bin/env bash
# Creates .venv in the repository and installs mlnseq editable with every extra (all) and the test dependencies
# (pracmln, optional, is installed by scripts/install_pracmln.sh; `make setup` runs both).
# torch 2.13.0 goes first: on these machines it is a CPU wheel on local disk, while a looser
# requirement with nothing installed would download a multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q "torch==2.13.0" || .venv/bin/python -m pip install -q "torch>=2.2"
.venv/bin/python -m pip install -q -e ".[all,test,sweep]"
# ROS 1 from Debian's own packages (`mlnseq ros` and its test against a real master): installed where apt-get is
# and we are root (CI), then linked into .venv (scripts/link_ros1.py); elsewhere the ROS test skips, saying why.
ROS_PACKAGES="python3-rosmaster python3-rostopic python3-rospy python3-sensor-msgs python3-std-msgs"
ros_ready() { /usr/bin/python3 -c "import rospy, rostopic, rosmaster, sensor_msgs.msg, std_msgs.msg" 2>/dev/null; }
if ! ros_ready && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q $ROS_PACKAGES; } >/dev/null \
    || echo "setup: apt-get could not install $ROS_PACKAGES; the ROS test will say so"
fi
if ros_ready; then /usr/bin/python3 scripts/link_ros1.py .venv; fi
# ROS 2 needs no system package (the ros2 extra's cyclonedds wheel holds its C library); its interop test builds a C
# peer on Debian's Cyclone DDS 0.10 (the series ROS 2 Humble ships): its library, headers and idlc, installed where
# apt-get is and we are root; elsewhere that test skips (under CI it fails), saying why.
CYCLONE_PACKAGES="cyclonedds-dev cyclonedds-tools"
cyclone_ready() { command -v idlc >/dev/null && [ -f /usr/include/dds/dds.h ]; }
if ! cyclone_ready && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $CYCLONE_PACKAGES >/dev/null; } \
    || echo "setup: apt-get could not install $CYCLONE_PACKAGES; the ROS 2 C-peer test will say so"
fi
# mlnseq sweep's cluster test (in make test) starts a one-node SLURM: Debian's slurm-wlm and munge, installed
# where apt-get exists and we are root (elsewhere that test skips, or fails under CI, saying what is missing).
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null && ! command -v slurmctld >/dev/null; then
  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null; } \
    || echo "setup: slurm-wlm and munge not installed (the SLURM cluster test needs them)"
fi
touch .venv/.setup-done
echo "setup: .venv ready"
