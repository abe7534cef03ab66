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
# Debian packages for the tests of real services, installed where apt-get is and we are root (CI): ROS 1 (`mlnseq ros`
# against a real master; linked into .venv by scripts/link_ros1.py), Cyclone DDS 0.10 (the series ROS 2 Humble ships;
# the ROS 2 interop test's C peer: its library, headers and idlc; ROS 2 itself needs none, the ros2 extra's cyclonedds
# wheel holds its C library), slurm-wlm and munge (the sweep's one-node SLURM cluster) and chromium (mlnseq review's
# browser tests, driven through Playwright's Python package, never `playwright install`). Elsewhere those tests skip,
# saying why (under CI they fail). Each set is said first; all go in one apt-get run, beside the Python installs.
ROS_PACKAGES="python3-rosmaster python3-rostopic python3-rospy python3-sensor-msgs python3-std-msgs"
ros_ready() { /usr/bin/python3 -c "import rospy, rostopic, rosmaster, sensor_msgs.msg, std_msgs.msg" 2>/dev/null; }
cyclone_ready() { command -v idlc >/dev/null && [ -f /usr/include/dds/dds.h ]; }
slurm_ready() { command -v slurmctld >/dev/null; }
chromium_ready() { command -v chromium >/dev/null; }
system_ok() { [ -z "${NO_SYSTEM:-}" ] && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; }
WANTED=()  # each a set of packages, as one word
want() {  # a ready-check, its packages, what for
  "$1" && return 0
  echo "setup: apt-get install $2 ($3; NO_SYSTEM=1 skips this)"
  WANTED+=("$2")
}
if system_ok; then
  want ros_ready "$ROS_PACKAGES" "Debian's ROS 1, for mlnseq ros and its test"
  want cyclone_ready "cyclonedds-dev cyclonedds-tools" "Cyclone DDS 0.10, for the ROS 2 interop test"
  want slurm_ready "slurm-wlm munge" "a one-node SLURM cluster for the sweep's test"
  want chromium_ready chromium "headless, for mlnseq review's browser tests"
fi
apt_install() { DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null; }
install_wanted() {  # all sets in one run; where that fails, each set alone, so one missing set keeps no other out
  apt-get update -qq || return 1
  apt_install ${WANTED[*]} && return 0
  local status=0 packages
  for packages in "${WANTED[@]}"; do apt_install $packages || status=1; done
  return $status
}
APT_PID=
APT_LOG=$(mktemp)
trap 'rm -f "$APT_LOG"' EXIT
if [ ${#WANTED[@]} -gt 0 ]; then
  install_wanted >"$APT_LOG" 2>&1 &
  APT_PID=$!
fi
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
if [ -n "$APT_PID" ]; then
  wait "$APT_PID" || { echo "setup: apt-get failed:"; tail -n 5 "$APT_LOG"; }
  for ready in ros_ready cyclone_ready slurm_ready chromium_ready; do
    "$ready" || echo "setup: ${ready%_ready} is not installed; the tests that need it will say so"
  done
fi
if ros_ready; then /usr/bin/python3 scripts/link_ros1.py .venv; fi
touch .venv/.setup-done
echo "setup: .venv ready"
