#!/usr/bin/env bash
# Creates .venv in the repository and installs mlnseq editable with every extra (all) and the test dependencies
# (pracmln, optional, is installed by scripts/install_pracmln.sh; `make setup` runs both). As root where apt-get
# is, it also installs Debian packages for the tests of `mlnseq ros` and of the SLURM sweep, saying which and why
# before it does; NO_SYSTEM=1 (`make setup NO_SYSTEM=1`) leaves the system alone (those tests then skip).
# torch 2.13.0 goes first, through pip: on these machines it is a CPU wheel on local disk (uv does not look
# there), while a looser requirement with nothing installed would download a multi-GB CUDA build. The rest goes
# through uv (parallel downloads: about 15 s where pip takes a minute), or pip where uv fails. Bytecode is
# compiled at install, on every core (with PYTHONDONTWRITEBYTECODE set, each process would compile what it imports).
set -euo pipefail
cd "$(dirname "$(readlink -f "$0")")/.."  # the checkout itself, also when run through a link to scripts/
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip uv
.venv/bin/python -m pip install -q --no-compile "torch==2.13.0" \
  || .venv/bin/python -m pip install -q --no-compile "torch>=2.2"
TORCH_DIR=$(.venv/bin/python -c 'import importlib.util as u; print(u.find_spec("torch").submodule_search_locations[0])')
# (one file of torch's own tests is Python 3.12 only: compileall reports it and exits 1, as pip would skip it)
.venv/bin/python -m compileall -q -j 0 "$TORCH_DIR" >/dev/null || true
.venv/bin/uv pip install -q --compile-bytecode --python .venv/bin/python -e ".[all,test]" \
  || .venv/bin/python -m pip install -q -e ".[all,test]"
# the editable checkout's own modules too (each mlnseq process would otherwise compile the 80-odd it imports)
.venv/bin/python -m compileall -q -j 0 stages mlnseq_cli benchmarks tests >/dev/null || true
# ROS 1 from Debian's own packages (`mlnseq ros` and its test against a real master): installed where apt-get is
# and we are root (CI), then linked into .venv (scripts/link_ros1.py); elsewhere the ROS test skips, saying why.
ROS_PACKAGES="python3-rosmaster python3-rostopic python3-rospy python3-sensor-msgs python3-std-msgs"
ros_ready() { /usr/bin/python3 -c "import rospy, rostopic, rosmaster, sensor_msgs.msg, std_msgs.msg" 2>/dev/null; }
system_ok() { [ -z "${NO_SYSTEM:-}" ] && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; }
APT_UPDATED=
apt_install() {  # quietly, after one apt-get update for the whole set-up
  { [ -n "$APT_UPDATED" ] || { apt-get update -qq && APT_UPDATED=1; }; } \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}
if ! ros_ready && system_ok; then
  echo "setup: apt-get install $ROS_PACKAGES (Debian's ROS 1, for mlnseq ros and its test; NO_SYSTEM=1 skips this)"
  apt_install $ROS_PACKAGES \
    || echo "setup: apt-get could not install $ROS_PACKAGES; the ROS test will say so"
fi
if ros_ready; then /usr/bin/python3 scripts/link_ros1.py .venv; fi
# ROS 2 needs no system package (the ros2 extra's cyclonedds wheel holds its C library); its interop test builds a C
# peer on Debian's Cyclone DDS 0.10 (the series ROS 2 Humble ships): its library, headers and idlc, installed where
# apt-get is and we are root; elsewhere that test skips (under CI it fails), saying why.
CYCLONE_PACKAGES="cyclonedds-dev cyclonedds-tools"
cyclone_ready() { command -v idlc >/dev/null && [ -f /usr/include/dds/dds.h ]; }
if ! cyclone_ready && system_ok; then
  echo "setup: apt-get install $CYCLONE_PACKAGES (Cyclone DDS 0.10, for the ROS 2 interop test; NO_SYSTEM=1 skips it)"
  apt_install $CYCLONE_PACKAGES \
    || echo "setup: apt-get could not install $CYCLONE_PACKAGES; the ROS 2 C-peer test will say so"
fi
# mlnseq sweep's cluster test (in make test) starts a one-node SLURM: Debian's slurm-wlm and munge, installed
# where apt-get exists and we are root (elsewhere that test skips, or fails under CI, saying what is missing).
if system_ok && ! command -v slurmctld >/dev/null; then
  echo "setup: apt-get install slurm-wlm munge (a one-node SLURM cluster for the sweep's test; NO_SYSTEM=1 skips this)"
  apt_install slurm-wlm munge \
    || echo "setup: slurm-wlm and munge not installed (the SLURM cluster test needs them)"
fi
# mlnseq review's browser tests drive Debian's chromium through Playwright (the test extra's Python package, never
# `playwright install`, which downloads a browser): installed where apt-get is and we are root; elsewhere they skip.
if system_ok && ! command -v chromium >/dev/null; then
  echo "setup: apt-get install chromium (headless, for mlnseq review's browser tests; NO_SYSTEM=1 skips this)"
  apt_install chromium \
    || echo "setup: chromium not installed (mlnseq review's browser tests will skip, saying so)"
fi
touch .venv/.setup-done
echo "setup: .venv ready"
