"""The piezo configurations of the model: which actuator drives the tip retraction (1: the
nominal one, 2: the redundant one the ground campaign drove). ``check_piezo`` is the one check
of a piezo number, used by every stage that takes one."""

from __future__ import annotations

from gprm.errors import GprmInputError

PIEZOS: tuple[int, ...] = (1, 2)


def check_piezo(piezo, *, field: str = "piezo", source: str | None = None,
                optional: bool = False) -> None:
    """Refuse a piezo that is not 1 or 2 (None too, unless ``optional``: "the model's own")
    with a :class:`GprmInputError` naming ``field`` (and ``source``)."""
    if piezo is None and optional:
        return
    if isinstance(piezo, bool) or piezo not in PIEZOS:
        raise GprmInputError(f"must be 1 or 2, got {piezo!r}", source=source, field=field)
