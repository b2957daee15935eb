#!/usr/bin/env bash
# Set up (once, from requirements/lock.txt) and run the whole test suite. The README and CI
# both call this script.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_venv.sh
# Two workers: the CI machine has 2 cores. --dist loadfile: each file's tests run on one
# worker, so a module fixture that runs a whole chain (tests/io/test_cf.py, tests/run, ...) is
# built once, not once per worker.
exec "$VENV/bin/python" -m pytest -n 2 --dist loadfile -q "$@"
