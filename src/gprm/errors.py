"""The one error type for bad input.

Every check of user input raises :class:`GprmInputError` with the file (or source), the field
and the problem, so that the CLI can print it on one line and exit non-zero. A field that is a
command-line option (``--seed``) is shown as typed; a file's field as ``field 'name'``.
"""

from __future__ import annotations


class GprmInputError(ValueError):
    """Bad input: names the source (file), the field and what is wrong with it."""

    def __init__(self, problem: str, *, source: str | None = None, field: str | None = None):
        self.problem = problem
        self.source = None if source is None else str(source)
        self.field = field
        parts = []
        if field and field.startswith("-"):     # an option, named as typed: --out PATH
            parts.append(f"{field} {self.source}" if self.source else field)
        else:
            if self.source:
                parts.append(self.source)
            if field:
                parts.append(f"field '{field}'")
        prefix = ": ".join(parts)
        super().__init__(f"{prefix}: {problem}" if prefix else problem)


class GprmOutputError(GprmInputError):
    """An output that cannot be written (no space left, a file-size limit, a read-only file
    system, permissions): names the file and the cause. The commands show it as they show
    bad input: one line, exit code 2, no file left behind."""
