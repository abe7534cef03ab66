#!/usr/bin/env bash
# Installs pracmln 1.2.4 (the paper's MLN engine) into the virtual environment given as $1.
# pracmln is an sdist whose setup.py fails under current pip; it builds into a pure-Python wheel
# with pip 20.3.4 and --no-build-isolation in a throwaway venv. Its declared requirements (Django,
# pymongo, matplotlib, ...) are not needed to learn weights, so it is installed with --no-deps
# beside the few modules it imports. Importing it needs stages/mln/pracmln_compat.py.
set -euo pipefail
VENV=${1:-.venv}
if "$VENV/bin/python" -c "import importlib.util, sys; sys.exit(importlib.util.find_spec('pracmln') is None)"; then
  exit 0
fi
build=$(mktemp -d)
trap 'rm -rf "$build"' EXIT
python3 -m venv "$build/venv"
"$build/venv/bin/python" -m pip install -q "pip==20.3.4" setuptools wheel
"$build/venv/bin/python" -m pip wheel -q --no-deps --no-build-isolation "pracmln==1.2.4" -w "$build/wheels"
# Its real needs first, then pracmln itself: a later install with dependencies would check the whole
# environment and print pip's resolver error about the requirements pracmln declares but never uses.
"$VENV/bin/python" -m pip install -q dnutils pyparsing appdirs psutil tabulate mpmath numpy scipy
"$VENV/bin/python" -m pip install -q --no-deps "$build"/wheels/pracmln-*.whl
echo "install_pracmln: pracmln installed into $VENV"
