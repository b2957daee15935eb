"""gprm: from ground-test vibration data of the LISA Pathfinder release mechanism (GPRM)
to a validated 3D electro-mechanical model, and from that model to the test mass in flight.

The package is laid out along the pipeline; each stage imports only from the ones before it::

    params -> model -> simulate -> campaign -> fit -> predict | flight -> report -> run

(predict and flight are siblings: both use the fit and the simulation, neither imports the
other; docs/README.md, "Package layout").

The command line (`gprm`, see :mod:`gprm.cli`) is a thin layer over these modules.
"""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("gprm")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.1.0"

from gprm.errors import GprmInputError

__all__ = ["GprmInputError", "__version__"]
