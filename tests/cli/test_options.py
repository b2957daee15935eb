"""One command-line syntax (issue #15 item 5): quantities with units, windows, ranges, flags
shown as flags and help text on every option."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gprm.options import Int, Number, Quantity, Window, parse_quantity

PREFIX = {"": 1.0, "m": 1e-3, "u": 1e-6, "n": 1e-9, "k": 1e3, "M": 1e6}


@settings(max_examples=80, deadline=None)
@given(x=st.floats(-1e6, 1e6, allow_nan=False), prefix=st.sampled_from(sorted(PREFIX)),
       unit=st.sampled_from(["s", "m", "Hz"]), space=st.booleans())
def test_a_quantity_with_a_prefixed_unit_is_its_si_value(x, prefix, unit, space):
    text = f"{x!r}{' ' if space else ''}{prefix}{unit}"
    assert math.isclose(parse_quantity(text, unit), x * PREFIX[prefix], rel_tol=1e-12,
                        abs_tol=1e-300)
    assert parse_quantity(repr(x), unit) == x                 # bare numbers are SI


@pytest.mark.parametrize("text, unit", [("2 V", "s"), ("abc", "s"), ("1 furlongz", "m"),
                                        ("nan", "s"), ("inf ms", "s"), ("", "Hz")])
def test_bad_quantities_are_refused(text, unit):
    with pytest.raises(ValueError):
        parse_quantity(text, unit)


@settings(max_examples=60, deadline=None)
@given(a=st.floats(0, 10, allow_nan=False), d=st.floats(1e-6, 10, allow_nan=False))
def test_window_forms_agree(a, d):
    b = a + d
    w = Window("s")
    expect = (a * 1e-3, b * 1e-3)
    for text in (f"{a!r}ms,{b!r}ms", f"{a!r},{b!r} ms", f"{a!r} ms, {b!r} ms"):
        got = w(text)
        assert math.isclose(got[0], expect[0], rel_tol=1e-12, abs_tol=1e-300)
        assert math.isclose(got[1], expect[1], rel_tol=1e-12)
    assert w(f"{a!r},{b!r}") == (a, b)


@pytest.mark.parametrize("text", ["1,0.5", "1ms,1ms", "-1,2", "1", "1,2,3", "a,b", "1,2 V"])
def test_bad_windows_are_refused(text):
    with pytest.raises(ValueError):
        Window("s")(text)


def test_ranges():
    assert Int(min=0)("0") == 0 and Int(1, 2)("2") == 2
    for bad in ("-1", "1.5", "x", "True"):
        with pytest.raises(ValueError):
            Int(min=0)(bad)
    with pytest.raises(ValueError):
        Number(0, 1, min_open=True, max_open=True)("1")
    with pytest.raises(ValueError):
        Number(0)("inf")
    assert Quantity("Hz", 0, min_open=True)("200kHz") == 200e3


def _all_commands():
    from typer.main import get_command

    from gprm.cli import app

    root = get_command(app)
    out = []
    for name, cmd in root.commands.items():
        if hasattr(cmd, "commands"):
            out += [(f"{name} {s}", c) for s, c in cmd.commands.items()]
        else:
            out.append((name, cmd))
    return out


@pytest.mark.parametrize("name, cmd", _all_commands(), ids=[n for n, _ in _all_commands()])
def test_every_option_has_help_and_flags_are_flags(name, cmd):
    from typer.testing import CliRunner

    from gprm.cli import app

    for p in cmd.params:
        if p.param_type_name == "option":
            assert (p.help or "").strip(), f"{name} {p.opts[0]} has no help text"
    r = CliRunner().invoke(app, [*name.split(), "--help"])
    assert r.exit_code == 0, r.output
    assert "<bool>" not in r.output and "BOOLEAN" not in r.output, r.output


def test_help_shows_flags_without_a_value():
    from typer.testing import CliRunner

    from gprm.cli import app

    r = CliRunner().invoke(app, ["fit", "--help"])
    assert r.exit_code == 0
    line = [ln for ln in r.output.splitlines() if "--profile" in ln][0]
    assert "<bool>" not in line and "BOOLEAN" not in line


@pytest.mark.parametrize("group", [[], ["synth"]], ids=["gprm", "gprm synth"])
def test_help_lists_each_command_with_its_whole_summary(group):
    """Issue 22: click cut summaries at the first period ("identification (Sec.") and to one
    line ("and write..."); each is now the docstring's first paragraph, wrapped."""
    import inspect

    from typer.testing import CliRunner

    from gprm.cli import app

    r = CliRunner().invoke(app, [*group, "--help"], terminal_width=80)
    assert r.exit_code == 0, r.output
    listing = r.output.split("Commands:")[1]
    assert "..." not in listing, listing
    flat = " ".join(listing.split())
    for name, cmd in _all_commands():
        if name.split()[:-1] != group:
            continue
        first = inspect.cleandoc(cmd.callback.__doc__).split("\n\n")[0]
        assert f"{name.split()[-1]} {' '.join(first.split())}" in flat, (name, listing)
