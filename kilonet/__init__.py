"""kilonet: a discrete-event simulator for Kilobot swarms and their communication protocols.

The kernel (simulation, medium, robot API, models) lives here and imports no protocol.
"""

from importlib.metadata import PackageNotFoundError, version

from kilonet.message import Layout, Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation

__all__ = ["Kilobot", "Layout", "Message", "Params", "Simulation"]

try:
    __version__ = version("kilonet")  # the installed distribution's, from pyproject.toml
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "unknown"
