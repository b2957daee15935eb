# Sourced by scripts/demo.sh and scripts/test.sh: create .venv (once) and install gprm into it
# with the extras named in GPRM_EXTRAS (e.g. "[test]"). It reinstalls only when pyproject.toml
# changed since the last install for these extras, or gprm is missing, so later runs need no
# network.
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
fi
STAMP=".venv/.gprm-installed${GPRM_EXTRAS:-}"
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ] || ! .venv/bin/gprm --help >/dev/null 2>&1; then
  .venv/bin/python -m pip install -q -e ".${GPRM_EXTRAS:-}" >/dev/null
  touch "$STAMP"
fi
