"""kilonet: a discrete-event simulator for Kilobot swarms and their communication protocols.

The kernel (simulation, medium, robot API, models) lives here and imports no protocol. The
names below are imported on first use (:mod:`kilonet.lazy`).
"""

from importlib.metadata import PackageNotFoundError, version

from kilonet.lazy import lazy_exports

__all__ = ["Kilobot", "Layout", "Message", "Params", "Simulation"]

try:
    __version__ = version("kilonet")  # the installed distribution's, from pyproject.toml
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "unknown"

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "Kilobot": "kilonet.robot",
        "Layout": "kilonet.message",
        "Message": "kilonet.message",
        "Params": "kilonet.params",
        "Simulation": "kilonet.simulation",
    },
    globals(),
)
