"""Gradient (Kilobotics lab 3): ``gradient_simple.c``, ported line by line.

The seed (the robot whose ``kilo_uid`` is ``SEED_ID``, 42) has gradient 0; every other robot
takes one more than the smallest gradient it hears, so each robot's gradient becomes its hop
count from the seed, shown by its LED (white 0, red 1, green 2, blue 3, magenta 4, yellow 5
and more). ``gradient_simple.csv`` places 30 robots in three rows, uids 32-61: the seed (uid
42) is the left end of the middle row.

Changes of syntax: the C globals are attributes set in ``setup``; ``message.crc =
message_crc(&message)`` builds a new :class:`~kilonet.message.Message` (messages are
immutable); ``m->data[0]`` is ``m.data[0]``; ``RGB(r, g, b)`` becomes ``set_color(r, g, b)``.
Run::

    python -m examples.labs.gradient_simple [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

from dataclasses import replace

from kilonet.message import Message, message_crc
from kilonet.robot import Kilobot

try:  # part of the examples package (python -m examples.labs.gradient_simple, the tests)
    from .lab_common import NORMAL
except ImportError:  # loaded as a file of its own (kilonet run --program ...)
    from lab_common import NORMAL

__all__ = ["GRADIENT_MAX", "SEED_ID", "GradientSimple"]

# Since 1 byte (8 bits) of the message is used to communicate gradients, the
# maximum possible gradient is 2^8 - 1 = 255.
GRADIENT_MAX = 255
# This is an arbitrary number, but it's important that exactly one robot in the
# group is calibrated to have this ID.
SEED_ID = 42


class GradientSimple(Kilobot):
    """``gradient_simple.c``: a hop-count gradient from the robot with uid ``SEED_ID``."""

    def setup(self):
        self.own_gradient = GRADIENT_MAX
        self.received_gradient = 0
        self.new_message = 0

        # If the robot is the seed, its gradient should be 0: overwrite the
        # previously set value of GRADIENT_MAX.
        if self.kilo_uid == SEED_ID:
            self.own_gradient = 0

        # Set the transmission message.
        self.message = Message(bytes([self.own_gradient]), NORMAL)
        self.message = replace(self.message, crc=message_crc(self.message))

    def loop(self):
        # Only pay attention to messages if this robot is not the seed.
        if self.kilo_uid != SEED_ID:
            if self.new_message == 1:
                # If a neighbor's gradient is 2 or more less than this robot's
                # gradient, reduce the latter to the neighbor's gradient + 1.
                if self.own_gradient > self.received_gradient + 1:
                    self.own_gradient = self.received_gradient + 1

                    # Update the transmission message whenever the gradient changes.
                    self.message = Message(bytes([self.own_gradient]), NORMAL)
                    self.message = replace(self.message, crc=message_crc(self.message))

                self.new_message = 0

        # Set the LED color based on the gradient.
        if self.own_gradient == 0:
            self.set_color(1, 1, 1)  # White
        elif self.own_gradient == 1:
            self.set_color(1, 0, 0)  # Red
        elif self.own_gradient == 2:
            self.set_color(0, 1, 0)  # Green
        elif self.own_gradient == 3:
            self.set_color(0, 0, 1)  # Blue
        elif self.own_gradient == 4:
            self.set_color(1, 0, 1)  # Magenta
        elif self.own_gradient >= 5:
            self.set_color(1, 1, 0)  # Yellow

    def message_tx(self):
        return self.message

    def message_rx(self, m, d):
        # Only process this message if the previous one has been processed.
        if self.new_message == 0:
            self.new_message = 1
            self.received_gradient = m.data[0]


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("gradient_simple", GradientSimple, measures.gradient_simple)
