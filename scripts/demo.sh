#!/usr/bin/env bash
# Set up (once) and run the whole chain on generated data into demo-run/ (the README's first
# command). Extra arguments go to `gprm demo`, e.g. `bash scripts/demo.sh --quick`.
# A rerun resumes: stages whose inputs are unchanged are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_venv.sh
exec "$VENV/bin/gprm" demo --out demo-run "$@"
