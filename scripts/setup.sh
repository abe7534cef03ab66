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
touch .venv/.setup-done
echo "setup: .venv ready"
