#!/usr/bin/env bash
# Set up (once) and run the whole chain on generated data into demo-run/ (the README's first
# command). Extra arguments go to `gprm demo`, e.g. `bash scripts/demo.sh --quick`.
# A rerun resumes: stages whose inputs are unchanged are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
fi
# (Re)install when pyproject.toml changed since the last install, or gprm is missing; a
# later run needs no network.
STAMP=.venv/.gprm-installed
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ] || ! .venv/bin/gprm --help >/dev/null 2>&1; then
  .venv/bin/python -m pip install -q -e . >/dev/null
  touch "$STAMP"
fi
exec .venv/bin/gprm demo --out demo-run "$@"
