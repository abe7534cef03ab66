#!/usr/bin/env bash
# Creates .venv in the repository and installs mlnseq with its test dependencies and the recording readers (pracmln, optional, is
# installed by scripts/install_pracmln.sh; `make setup` runs both).
# torch 2.13.0 goes first: on these machines it is a CPU wheel on local disk, while a looser
# requirement with nothing installed would download a multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q "torch==2.13.0" || .venv/bin/python -m pip install -q "torch>=2.2"
.venv/bin/python -m pip install -q -e ".[test,recordings,sweep]"
# mlnseq sweep's cluster test (make test-slurm) starts a one-node SLURM: Debian's slurm-wlm and munge, installed
# where apt-get exists and we are root (elsewhere that test skips, or fails under CI, saying what is missing).
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null && ! command -v slurmctld >/dev/null; then
  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null; } \
    || echo "setup: slurm-wlm and munge not installed (make test-slurm needs them)"
fi
touch .venv/.setup-done
echo "setup: .venv ready"
