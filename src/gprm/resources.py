"""Resource guards: estimate the memory of a piece of work before allocating it, and refuse
work that cannot fit with one line naming the option and the largest value that fits.

The estimates are per unit of the option (bytes per start, per sample) times the requested
count, measured on the code paths that allocate (docs/data-formats.md, "Resource guards").
Available memory is what the operating system reports as available now (``psutil``), so the
answer depends on the machine and its load, not on hidden state.
"""

from __future__ import annotations

from gprm.errors import GprmInputError

#: fraction of the available memory one command may plan to use
MEMORY_FRACTION = 0.8


def available_memory() -> int:
    """Bytes of memory available to a new allocation now (psutil; /proc/meminfo fallback)."""
    try:
        import psutil

        return int(psutil.virtual_memory().available)
    except Exception:  # pragma: no cover - psutil ships with distributed
        try:
            with open("/proc/meminfo", encoding="ascii") as fh:
                for line in fh:
                    if line.startswith("MemAvailable:"):
                        return int(line.split()[1]) * 1024
        except OSError:
            pass
    return 1 << 62  # unknown: do not refuse


def _fmt_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"  # pragma: no cover


def largest_that_fits(bytes_per_unit: float, fixed: float = 0.0, *,
                      available: int | None = None) -> int:
    """The largest count whose estimate ``fixed + count * bytes_per_unit`` fits."""
    avail = available_memory() if available is None else available
    budget = MEMORY_FRACTION * avail - fixed
    return max(0, int(budget // max(bytes_per_unit, 1.0)))


def check_memory(count: float, bytes_per_unit: float, *, field: str, what: str,
                 fixed: float = 0.0, available: int | None = None, unit_scale: float = 1.0,
                 unit: str = "", integer: bool = False) -> None:
    """Refuse ``count`` units of work when the estimate exceeds the memory available.

    ``unit_scale`` turns the count into the option's value for the message (e.g. samples per
    Hz of ``--rate``); the message gives the largest option value that fits (rounded down to
    a whole number for an ``integer`` option).
    """
    avail = available_memory() if available is None else available
    need = fixed + float(count) * bytes_per_unit
    if need <= MEMORY_FRACTION * avail:
        return
    n_max = largest_that_fits(bytes_per_unit, fixed, available=avail)
    v_max = n_max / unit_scale
    vtxt = f"{int(v_max)}" if (unit_scale == 1.0 or integer) else f"{v_max:.4g}"
    raise GprmInputError(f"{what} would need about {_fmt_bytes(need)} of memory, "
                         f"{_fmt_bytes(avail)} available; the largest value that fits is "
                         f"{vtxt}{(' ' + unit) if unit else ''}", field=field)
