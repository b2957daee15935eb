#!/usr/bin/env bash
# Set up (once) and run the main job. The README calls this script.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
.venv/bin/python -m pip install -q -e . >/dev/null
if .venv/bin/gprm demo --help >/dev/null 2>&1; then
  exec .venv/bin/gprm demo --out demo-run "$@"
fi
# Until the demo stage exists: simulate the paper set.
mkdir -p demo-run
exec .venv/bin/gprm simulate --out demo-run/simulation.nc
