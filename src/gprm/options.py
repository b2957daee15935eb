"""Option types of the ``gprm`` command line: one syntax for numbers, quantities and windows.

Every option is checked while the command line is parsed, so a bad value is refused before any
file is read or written, with the option named as typed (``Invalid value for '--seed': ...``).

- integers and plain numbers with a range: :class:`Int`, :class:`Number`;
- quantities with units: :class:`Quantity` accepts ``1.2 ms``, ``1.2ms`` or a bare number in SI
  units (``1.2e-3``), and refuses a value of the wrong dimension (``2 V`` for a time);
- racing schedules: :class:`Race` accepts ``ITER:KEEP[,ITER:KEEP...]`` or ``off``;
- windows: :class:`Window` accepts ``START,END`` with units on each bound (``0.97ms,1.2ms``) or
  once at the end (``0.97,1.2 ms``); bare numbers are SI.

The types are small callables for ``typer.Option(parser=...)``: they return the value in SI
units or raise ValueError with the reason, which typer reports as a bad value of the option.
"""

from __future__ import annotations

import math

__all__ = ["Int", "Number", "Quantity", "Race", "Window", "parse_quantity"]


def _range_problem(v: float, lo, hi, lo_open: bool, hi_open: bool) -> str | None:
    if lo is not None and (v < lo or (lo_open and v == lo)):
        return f"must be {'>' if lo_open else '>='} {lo:g}"
    if hi is not None and (v > hi or (hi_open and v == hi)):
        return f"must be {'<' if hi_open else '<='} {hi:g}"
    return None


class _Parser:
    name = "value"

    def fail(self, message, param=None, ctx=None):
        raise ValueError(message)

    def __call__(self, value):
        return self.convert(value, None, None)

    @property
    def __name__(self) -> str:          # older click wraps a parser by its function name
        return self.name

    def __repr__(self):
        return f"{type(self).__name__}({vars(self)})"


class Int(_Parser):
    """An integer within [min, max] (either bound optional)."""

    name = "integer"

    def __init__(self, min: int | None = None, max: int | None = None):
        self.min, self.max = min, max

    def get_metavar(self, param, ctx=None):  # noqa: D401 - click API
        lo = "" if self.min is None else f"{self.min}"
        hi = "" if self.max is None else f"{self.max}"
        return f"INT[{lo}..{hi}]" if (lo or hi) else "INT"

    def convert(self, value, param, ctx):
        if isinstance(value, bool):
            self.fail(f"expected an integer, got {value!r}", param, ctx)
        if isinstance(value, int):
            v = value
        else:
            text = str(value).strip()
            try:
                v = int(text)
            except ValueError:
                self.fail(f"expected an integer, got {text!r}", param, ctx)
        problem = _range_problem(v, self.min, self.max, False, False)
        if problem:
            self.fail(f"{problem}, got {v}", param, ctx)
        return v


class Number(_Parser):
    """A finite real number within a range (open or closed bounds)."""

    name = "number"

    def __init__(self, min: float | None = None, max: float | None = None, *,
                 min_open: bool = False, max_open: bool = False):
        self.min, self.max, self.min_open, self.max_open = min, max, min_open, max_open

    def get_metavar(self, param, ctx=None):
        return "NUMBER"

    def convert(self, value, param, ctx):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            v = float(value)
        else:
            text = str(value).strip()
            try:
                v = float(text)
            except ValueError:
                self.fail(f"expected a number, got {text!r}", param, ctx)
        if not math.isfinite(v):
            self.fail(f"must be finite, got {value!r}", param, ctx)
        problem = _range_problem(v, self.min, self.max, self.min_open, self.max_open)
        if problem:
            self.fail(f"{problem}, got {v:g}", param, ctx)
        return v


def parse_quantity(text, unit: str) -> float:
    """``'1.2 ms'``, ``'1.2ms'`` or ``'1.2e-3'`` (bare: SI) -> the value in ``unit`` (SI).

    Raises ValueError with the reason on a malformed value or a wrong dimension.
    """
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        v = float(text)
    else:
        s = str(text).strip()
        try:
            v = float(s)
        except ValueError:
            v = _quantity_in(s, unit)
            # a typed '0.97 ms' is 0.97e-3 s, not the product's 0.0009699999999999999
            v = float(f"{v:.15g}")
    if not math.isfinite(v):
        raise ValueError(f"must be finite, got {text!r}")
    return v


def _quantity_in(s: str, unit: str) -> float:
    """The quantity string ``s`` (it has a unit) in ``unit``: the units every default meets
    from gprm.units' table (no pint registry to build), anything else through pint."""
    from gprm.units import known_quantity

    v = known_quantity(s, unit)
    if v is not None:
        return v
    import pint

    from gprm.units import ureg

    try:
        q: pint.Quantity | float = ureg().Quantity(s)
    except Exception:
        raise ValueError(f"cannot read {s!r} as a number with a unit (e.g. "
                         f"'1.2 m{unit}' or '1.2e-3')") from None
    if not isinstance(q, pint.Quantity):  # a bare number in a string
        return float(q)
    if q.dimensionless:
        return float(q.to("").magnitude)
    try:
        return float(q.to(unit).magnitude)
    except Exception:
        raise ValueError(f"{s!r} is not in a unit of {unit}") from None


class Quantity(Number):
    """A physical quantity: a number with an optional unit, converted to SI ``unit``."""

    name = "quantity"

    def __init__(self, unit: str, min: float | None = None, max: float | None = None, *,
                 min_open: bool = False, max_open: bool = False):
        super().__init__(min, max, min_open=min_open, max_open=max_open)
        self.unit = unit

    def get_metavar(self, param, ctx=None):
        return f"QTY[{self.unit}]"

    def convert(self, value, param, ctx):
        try:
            v = parse_quantity(value, self.unit)
        except ValueError as exc:
            self.fail(str(exc), param, ctx)
        problem = _range_problem(v, self.min, self.max, self.min_open, self.max_open)
        if problem:
            self.fail(f"{problem} {self.unit}, got {value}", param, ctx)
        return v


class Race(_Parser):
    """A racing schedule ``ITER:KEEP[,ITER:KEEP...]`` (integers >= 1; e.g. ``3:25,6:5``: after
    3 iterations keep the 25 best running starts of each chunk, after 6 the best 5) or
    ``off`` -> a tuple of (iterations, keep) pairs, () for off. The order of the points is
    checked by the fit's options (gprm.fit.starts.check_race)."""

    name = "race"

    def get_metavar(self, param, ctx=None):
        return "ITER:KEEP,...|off"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        text = str(value).strip()
        if text.lower() in ("off", "none", "0"):
            return ()
        pairs = []
        for part in text.split(","):
            bits = [b.strip() for b in part.split(":")]
            try:
                if len(bits) != 2:
                    raise ValueError
                r, q = int(bits[0]), int(bits[1])
            except ValueError:
                self.fail(f"expected ITER:KEEP pairs separated by commas (e.g. '3:25,6:5') "
                          f"or 'off', got {value!r}", param, ctx)
            if r < 1 or q < 1:
                self.fail(f"iterations and keep must be >= 1, got {part.strip()!r}",
                          param, ctx)
            pairs.append((r, q))
        return tuple(pairs)


class Window(_Parser):
    """``START,END`` (each with an optional unit, or one unit after END) -> (start, end) SI."""

    name = "window"

    def __init__(self, unit: str = "s", min: float | None = 0.0):
        self.unit, self.min = unit, min

    def get_metavar(self, param, ctx=None):
        return "START,END"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple) and len(value) == 2:
            a, b = (float(x) for x in value)
        else:
            parts = [p.strip() for p in str(value).split(",")]
            if len(parts) != 2 or not all(parts):
                self.fail(f"expected START,END (e.g. '0.97ms,1.2ms'), got {value!r}",
                          param, ctx)
            first, last = parts
            try:
                float(first)
                bare_first = True
            except ValueError:
                bare_first = False
            try:
                float(last)
                bare_last = True
            except ValueError:
                bare_last = False
            if bare_first and not bare_last:   # '0.97,1.2 ms': the unit applies to both
                from gprm.units import known_unit, ureg

                unit = known_unit(last)
                if unit is None:
                    try:
                        unit = str(ureg().Quantity(last).units)
                    except Exception:
                        unit = None
                if unit:
                    first = f"{first} {unit}"
            try:
                a = parse_quantity(first, self.unit)
                b = parse_quantity(last, self.unit)
            except ValueError as exc:
                self.fail(str(exc), param, ctx)
        if self.min is not None and a < self.min:
            self.fail(f"START must be >= {self.min:g} {self.unit}, got {value!r}", param, ctx)
        if not a < b:
            self.fail(f"START must be before END, got {value!r}", param, ctx)
        return (a, b)
