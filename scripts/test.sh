#!/usr/bin/env bash
# Set up (once, from requirements/lock.txt) and run the whole test suite. The README and CI
# both call this script.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_venv.sh
# Two workers: the CI machine has 2 cores.
exec "$VENV/bin/python" -m pytest -n 2 -q "$@"
