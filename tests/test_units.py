"""gprm.units' table of known units against pint, and the fast paths that use it.

The table lets a command read ``--window 0.97ms,1.2ms`` and print parameters in their display
units without building pint's registry; these tests keep it equal to pint's definitions
(factor to the bit, SI unit string as pint writes it), and check that each fast path gives
what the pint path gives.
"""

from __future__ import annotations

import pytest

from gprm import options
from gprm.params import REGISTRY
from gprm.params import files as pfiles
from gprm.units import KNOWN, known_factor, known_quantity, known_unit, si_unit, ureg


@pytest.mark.parametrize("unit", sorted(KNOWN))
def test_known_units_are_pints(unit):
    q = ureg().Quantity(1.0, unit).to_base_units()
    factor, si = KNOWN[unit]
    assert factor == q.magnitude                      # bit-identical
    assert si == f"{q.units:~}".replace(" ", "") == si_unit(unit)


def test_si_unit_outside_the_table_is_pints():
    assert "N" not in KNOWN and si_unit("N") == "kg*m/s**2"


def test_every_display_unit_of_the_registry_is_known():
    # the reports' conversions then never build the registry
    assert {spec.unit for spec in REGISTRY.values()} <= set(KNOWN)


@pytest.mark.parametrize("text, si", [
    ("0.97ms", "s"), ("0.97 ms", "s"), ("1.2 ms", "s"), ("3 us", "s"), ("-2.5e-1 ns", "s"),
    ("12 mm", "m"), ("0.5um", "m"), ("5 nm", "m"), ("2 mrad", "rad"), ("30 deg", "rad"),
    ("28 kHz", "Hz"), (".5 MHz", "Hz"), ("200 mV", "V"), ("1.5 kV", "V"), ("12.4 g", "kg"),
])
def test_known_quantity_is_pints_product(text, si):
    q = ureg().Quantity(text).to(si).magnitude
    assert known_quantity(text, si) == q
    assert options.parse_quantity(text, si) == float(f"{q:.15g}")


@pytest.mark.parametrize("text, si", [
    ("1 min", "s"),            # not in the table: pint
    ("2 ms", "m"),             # wrong dimension: pint says so
    ("1.2 ms extra", "s"),     # not a number and a unit
    ("ms", "s"),
])
def test_unknown_or_wrong_goes_to_pint(text, si):
    assert known_quantity(text, si) is None


def test_parse_quantity_outside_the_table_still_works_and_refuses():
    assert options.parse_quantity("1 min", "s") == 60.0
    with pytest.raises(ValueError, match="not in a unit of s"):
        options.parse_quantity("2 mm", "s")
    with pytest.raises(ValueError, match="not in a unit of s"):
        options.parse_quantity("2 mV", "s")     # in the table, but not a time


def test_known_factor_between_units_and_window_unit():
    assert known_factor("ms", "s") == 1e-3
    assert known_factor("um", "m") == 1e-6
    assert known_factor("ms", "m") is None        # another dimension
    assert known_factor("furlong", "m") is None
    assert known_unit("1.2 ms") == "ms" and known_unit("1.2 fortnight") is None
    assert options.Window("s").convert("0.97,1.2 ms", None, None) == (0.97e-3, 1.2e-3)
    assert options.Window("s").convert("0.97ms,1.2ms", None, None) == (0.97e-3, 1.2e-3)


def test_from_si_and_si_units_match_pint_for_every_parameter():
    for name, spec in REGISTRY.items():
        base = ureg().Quantity(1.0, spec.unit).to_base_units()
        assert pfiles.from_si(0.123, name) == 0.123 / base.magnitude, name
        assert pfiles.si_unit_strings([name]) == [f"{base.units:~}".replace(" ", "") or "1"]
