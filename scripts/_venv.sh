# Sourced by scripts/demo.sh, scripts/test.sh and .ci/run: create a venv (once; default .venv,
# or GPRM_VENV) and install into it the exact versions of requirements/lock.txt (or of the
# file named in GPRM_REQUIREMENTS), then gprm itself without resolving dependencies again.
# It reinstalls only when pyproject.toml or the requirements file changed since the last
# install, or gprm is missing, so later runs need no network.
PY=${PYTHON:-python3}
VENV=${GPRM_VENV:-.venv}
REQ=${GPRM_REQUIREMENTS:-requirements/lock.txt}
if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
fi
STAMP="$VENV/.gprm-installed-$(basename "$REQ")"
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ] || [ "$REQ" -nt "$STAMP" ] \
   || ! "$VENV/bin/gprm" --help >/dev/null 2>&1; then
  if [ "$REQ" = requirements/lock.txt ]; then
    # exact pins of every package: install them, then gprm alone
    "$VENV/bin/python" -m pip install -q -r "$REQ" >/dev/null
    "$VENV/bin/python" -m pip install -q --no-deps -e . >/dev/null
  else
    # a constraints file (e.g. the lower bounds): gprm[test] resolved within it
    "$VENV/bin/python" -m pip install -q -c "$REQ" -e ".[test]" >/dev/null
  fi
  "$VENV/bin/python" -m pip check >/dev/null || { "$VENV/bin/python" -m pip check; exit 1; }
  touch "$STAMP"
fi
