"""Disperse (Kilobotics lab 7): ``disperse.c``, ported line by line.

Every robot sends a message all the time. Once a second (every 32 ticks) a robot that heard
any message in that second picks a random motion (forward with probability 1/2, green; left
1/4, red; right 1/4, blue); a robot that heard nothing stops (white). Robots in a crowd keep
moving until nobody is in range of anybody. ``disperse.csv`` places 20 robots touching, in a
hexagonal clump.

Changes of syntax: the C globals are attributes set in ``setup``; ``message.crc =
message_crc(&message)`` builds a new :class:`~kilonet.message.Message` (messages are
immutable); ``RGB(r, g, b)`` becomes ``set_color(r, g, b)``. Run::

    python -m examples.labs.disperse [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

from dataclasses import replace

from kilonet.message import Message, message_crc

try:  # part of the examples package (python -m examples.labs.disperse, the tests)
    from .lab_common import FORWARD, LEFT, NORMAL, RIGHT, STOP, MotionLab
except ImportError:  # loaded as a file of its own (kilonet run --program ...)
    from lab_common import FORWARD, LEFT, NORMAL, RIGHT, STOP, MotionLab

__all__ = ["Disperse"]


class Disperse(MotionLab):
    """``disperse.c``: move at random while anybody is heard, stop when nobody is."""

    def setup(self):
        self.new_message = 0
        self.last_motion_update = 0

        # Initialize an empty message.
        self.message = Message(b"", NORMAL)
        self.message = replace(self.message, crc=message_crc(self.message))

    def loop(self):
        if self.kilo_ticks > self.last_motion_update + 32:
            self.last_motion_update = self.kilo_ticks

            # If a message was received within the last second, set a random motion.
            if self.new_message == 1:
                self.new_message = 0

                # Generate an 8-bit random number (between 0 and 2^8 - 1 = 255).
                random_number = self.rand_hard()

                # Compute the remainder of random_number when divided by 4.
                # This gives a new random number in the set {0, 1, 2, 3}.
                random_direction = random_number % 4

                # There is a 50% chance of random_direction being 0 OR 1, in which
                # case set the LED green and move forward.
                if (random_direction == 0) or (random_direction == 1):
                    self.set_color(0, 1, 0)
                    self.set_motion(FORWARD)
                # There is a 25% chance of random_direction being 2, in which case
                # set the LED red and move left.
                elif random_direction == 2:
                    self.set_color(1, 0, 0)
                    self.set_motion(LEFT)
                # There is a 25% chance of random_direction being 3, in which case
                # set the LED blue and move right.
                elif random_direction == 3:
                    self.set_color(0, 0, 1)
                    self.set_motion(RIGHT)
            # If no messages were received within the last second, set the LED white
            # and stop moving.
            else:
                self.set_color(1, 1, 1)
                self.set_motion(STOP)

    def message_rx(self, m, d):
        self.new_message = 1

    def message_tx(self):
        return self.message


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("disperse", Disperse, measures.disperse)
