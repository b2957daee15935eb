#!/usr/bin/env bash
# Set up (once) and run the whole test suite. The README and CI both call this script.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
.venv/bin/python -m pip install -q -e ".[test]"
# Two workers: the CI machine has 2 cores.
exec .venv/bin/python -m pytest -n 2 -q "$@"
