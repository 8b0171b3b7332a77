"""Synchronization (Kilobotics lab 6): ``sync.c``, ported line by line.

Every robot flashes white (and buzzes its motors) once every ``PERIOD`` ticks and sends how
many ticks have passed since its last flash. A robot that hears a neighbour running behind
resets later, one running ahead sooner: at each flash it moves its next flash by the sum of
the discrepancies it heard in that period divided by ``RESET_TIME_ADJUSTMENT_DIVIDER`` (capped
at ``RESET_TIME_ADJUSTMENT_MAX``), so the flashes of a group fall together although each robot
counts on its own clock. ``sync.csv`` packs 19 robots in a hexagon, 1 mm apart; ``sync.toml``
keeps them in place (see there).

Changes of syntax: the C globals are attributes set in ``setup``; ``delay(10 * rand_hard())``
is ``yield self.delay(10 * self.rand_hard())`` in a generator ``setup``; ``message.crc =
message_crc(&message)`` builds a new :class:`~kilonet.message.Message` (messages are
immutable); C's integer ``/`` and ``%`` (which truncate towards zero) are
:func:`kilonet.cint.c_div` and :func:`kilonet.cint.c_mod`, because Python's ``//`` and ``%``
round towards minus infinity. Run::

    python -m examples.labs.sync [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

from dataclasses import replace

from kilonet.cint import c_div, c_mod  # C's / and %, which truncate towards zero
from kilonet.message import Message, message_crc
from kilonet.robot import Kilobot

try:  # part of the examples package (python -m examples.labs.sync, the tests)
    from .lab_common import NORMAL
except ImportError:  # loaded as a file of its own (kilonet run --program ...)
    from lab_common import NORMAL

__all__ = [
    "PERIOD",
    "RESET_TIME_ADJUSTMENT_DIVIDER",
    "RESET_TIME_ADJUSTMENT_MAX",
    "Sync",
    "c_div",
    "c_mod",
]

# Nominal period with which to blink; approximately 2 seconds. This will be
# be the period of every robot once the swarm has synchronized.
PERIOD = 50
# Affects the size of the reset time adjustment for every discrepancy
# with a neighbor. A larger value means smaller adjustments. As a rule of thumb
# this value should increase with the average number of neighbors each robot has.
RESET_TIME_ADJUSTMENT_DIVIDER = 120
# A cap on the absolute value of the reset time adjustment.
RESET_TIME_ADJUSTMENT_MAX = 30


class Sync(Kilobot):
    """``sync.c``: flash together with the neighbours."""

    def setup(self):
        self.reset_time = 0
        self.last_reset = 0
        self.reset_time_adjustment = 0

        # Set the message.
        self.message = Message(bytes([0]), NORMAL)
        self.message = replace(self.message, crc=message_crc(self.message))

        # Introduce a random delay so the robots don't become instantly
        # synchronized by the run signal.
        self.set_color(1, 0, 0)
        yield self.delay(10 * self.rand_hard())
        self.set_color(0, 0, 0)

    def loop(self):
        if self.kilo_ticks >= self.reset_time:
            self.reset_time_adjustment = c_div(
                self.reset_time_adjustment, RESET_TIME_ADJUSTMENT_DIVIDER
            )

            # Apply a cap to the absolute value of the reset time adjustment.
            if self.reset_time_adjustment < -RESET_TIME_ADJUSTMENT_MAX:
                self.reset_time_adjustment = -RESET_TIME_ADJUSTMENT_MAX
            elif self.reset_time_adjustment > RESET_TIME_ADJUSTMENT_MAX:
                self.reset_time_adjustment = RESET_TIME_ADJUSTMENT_MAX

            self.last_reset = self.kilo_ticks
            self.reset_time = self.kilo_ticks + PERIOD + self.reset_time_adjustment

            self.reset_time_adjustment = 0

            # Set the LED white and turn the motors on.
            self.set_color(1, 1, 1)
            self.set_motors(150, 150)
        # After 1 clock tick, turn the LED and motors off.
        elif self.kilo_ticks > (self.last_reset + 1):
            self.set_color(0, 0, 0)
            self.set_motors(0, 0)

        # Only send the current time if it can fit in 1 byte (8 bits), which
        # corresponds to a maximum of 2^8 - 1 = 255. Otherwise, set the message
        # CRC to 0 so neighbors ignore the message.
        if (self.kilo_ticks - self.last_reset) < 255:
            self.message = Message(bytes([self.kilo_ticks - self.last_reset]), NORMAL)
            self.message = replace(self.message, crc=message_crc(self.message))
        else:
            self.message = replace(self.message, crc=0)

    def message_tx(self):
        return self.message

    def message_rx(self, m, d):
        my_timer = self.kilo_ticks - self.last_reset
        rx_timer = m.data[0]
        timer_discrepancy = my_timer - rx_timer

        # Reset time adjustment due to this message - to be combined with the
        # overall reset time adjustment.
        rx_reset_time_adjustment = 0

        if timer_discrepancy > 0:
            # The neighbor is trailing behind: move the reset time forward
            # (reset later).
            if timer_discrepancy < c_div(PERIOD, 2):
                rx_reset_time_adjustment = timer_discrepancy
            # The neighbor is running ahead: move the reset time backward
            # (reset sooner).
            else:
                rx_reset_time_adjustment = c_mod(-(PERIOD - timer_discrepancy), PERIOD)
        elif timer_discrepancy < 0:
            # The neighbor is running ahead: move the reset time backward
            # (reset sooner).
            if -timer_discrepancy < c_div(PERIOD, 2):
                rx_reset_time_adjustment = timer_discrepancy
            # The neighbor is trailing behind: move the reset time forward
            # (reset later).
            else:
                rx_reset_time_adjustment = c_mod(PERIOD + timer_discrepancy, PERIOD)

        # Combine the reset time adjustment due to this message with the overall
        # reset time adjustment.
        self.reset_time_adjustment = self.reset_time_adjustment + rx_reset_time_adjustment


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("sync", Sync, measures.sync)
