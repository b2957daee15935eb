#!/usr/bin/env bash
# Set up (once) and run the whole test suite. The README and CI both call this script.
set -euo pipefail
cd "$(dirname "$0")/.."
GPRM_EXTRAS="[test]"
source scripts/_venv.sh
# Two workers: the CI machine has 2 cores.
exec .venv/bin/python -m pytest -n 2 -q "$@"
