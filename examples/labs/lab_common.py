"""What the Kilobotics labs share: kilolib's ``NORMAL`` message type and the labs' ``set_motion``.

``orbit_planet.c``, ``disperse.c`` and ``move_to_light.c`` each define the same motion helper:
four motions (``STOP``, ``FORWARD``, ``LEFT``, ``RIGHT``) and a ``set_motion(new_motion)`` that
acts only when the motion changes, spinning the motors up before each move. Here it is written
once, as :class:`MotionLab`, a Kilobot base class with ``current_motion`` (starting at ``STOP``,
as the C global does) and :meth:`MotionLab.set_motion`.
"""

from __future__ import annotations

from kilonet.message import NORMAL  # kilolib's message type for a program's own messages
from kilonet.robot import Kilobot

__all__ = ["FORWARD", "LEFT", "NORMAL", "RIGHT", "STOP", "MotionLab"]

# Constants for the motion handling function.
STOP = 0
FORWARD = 1
LEFT = 2
RIGHT = 3


class MotionLab(Kilobot):
    """A Kilobot program with the labs' ``set_motion``."""

    current_motion = STOP

    def set_motion(self, new_motion: int) -> None:
        """Switch to ``new_motion`` (``STOP``, ``FORWARD``, ``LEFT``, ``RIGHT``); only take an
        action if the motion is being changed."""
        if self.current_motion != new_motion:
            self.current_motion = new_motion

            if self.current_motion == STOP:
                self.set_motors(0, 0)
            elif self.current_motion == FORWARD:
                self.spinup_motors()
                self.set_motors(self.kilo_straight_left, self.kilo_straight_right)
            elif self.current_motion == LEFT:
                self.spinup_motors()
                self.set_motors(self.kilo_turn_left, 0)
            elif self.current_motion == RIGHT:
                self.spinup_motors()
                self.set_motors(0, self.kilo_turn_right)
