#!/usr/bin/env bash
# Run every benchmark (one command) and print their markdown sections. BENCHMARKS.md records
# the output of this script on a named machine. Options are passed to each benchmark
# (e.g. --quick). Needs the .venv of scripts/test.sh or scripts/demo.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
echo "# gprm benchmarks ($(date -u +%Y-%m-%dT%H:%MZ), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs))"
for b in startup simulate preprocess fit predict flight; do
  echo
  "$PY" "benchmarks/bench_${b}.py" "$@"
done
echo
"$PY" benchmarks/bench_fit.py --demo "$@"     # the fit with model mismatch (issue 4 target)
