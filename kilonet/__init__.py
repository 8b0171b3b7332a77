"""kilonet: a discrete-event simulator for Kilobot swarms and their communication protocols.

The kernel (simulation, medium, robot API, models) lives here and imports no protocol.
"""

from kilonet.message import Layout, Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation

__all__ = ["Kilobot", "Layout", "Message", "Params", "Simulation"]
__version__ = "0.1.0"
