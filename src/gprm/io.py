"""File helpers for library users: the same atomic writers and checked readers every stage
uses (an interrupted write never leaves a half-written file; NetCDF files get the CF
attributes of docs/data-formats.md; a missing or unreadable input is a
:class:`~gprm.errors.GprmInputError` naming the file).

The implementation lives in the package-internal ``gprm._io``; this module is its public
face, so scripts and notebooks need no private module.
"""

from gprm._io import (atomic_path, open_netcdf, read_json, write_json_atomic,
                      write_netcdf_atomic, write_text_atomic)

__all__ = ["atomic_path", "open_netcdf", "read_json", "write_json_atomic",
           "write_netcdf_atomic", "write_text_atomic"]
