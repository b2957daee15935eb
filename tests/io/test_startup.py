"""Start-up stays light (issue 15 item 7): registering the CLI imports no numerical library.

The time itself is measured by benchmarks/bench_startup.py (a timing test would be flaky on
a shared machine); this checks the cause, which is deterministic.
"""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("numpy", "scipy", "xarray", "pint", "sympy", "matplotlib", "dask", "distributed",
         "netCDF4", "pandas")


def _loaded_after(code: str) -> set[str]:
    probe = f"{code}\nimport sys\nprint(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True).stdout
    return set(out.split())


def test_cli_help_imports_no_numerical_library():
    code = ("import sys\nfrom typer.testing import CliRunner\nfrom gprm.cli import app\n"
            "for c in ([], ['fit'], ['show'], ['impact'], ['synth', 'campaign'], ['demo']):\n"
            "    r = CliRunner().invoke(app, c + ['--help'])\n"
            "    assert r.exit_code == 0, r.output")
    assert _loaded_after(code) == set()


def test_lazy_package_attributes_still_resolve():
    """The packages' public names import on first use (and the probe itself is not vacuous:
    touching one loads numpy)."""
    assert _loaded_after("import gprm.params, gprm.flight, gprm.campaign, gprm.simulate, "
                         "gprm.model, gprm.fit") == set()
    assert "numpy" in _loaded_after("from gprm.params import paper\npaper()")
    import gprm.flight

    assert set(gprm.flight.__all__) <= set(dir(gprm.flight))
    for name in gprm.flight.__all__:
        assert getattr(gprm.flight, name) is not None
