"""Simple movement (Kilobotics lab 1.1): ``simple_movement.c``, ported line by line.

Forward for 2 s (green), left for 2 s (red), right for 2 s (blue), stop for half a second (LED
off), and again; each move blocks the loop in ``delay``.

Changes of syntax: ``delay(ms)`` is ``yield self.delay(ms)`` in a generator ``loop``; ``RGB(r,
g, b)`` becomes ``set_color(r, g, b)``. Run::

    python -m examples.labs.simple_movement [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

from kilonet.robot import Kilobot

__all__ = ["SimpleMovement"]


class SimpleMovement(Kilobot):
    """``simple_movement.c``: forward, left, right for 2 s each, then a 0.5 s stop."""

    def loop(self):
        # Set the LED green.
        self.set_color(0, 1, 0)
        # Spinup the motors to overcome friction.
        self.spinup_motors()
        # Move straight for 2 seconds (2000 ms).
        self.set_motors(self.kilo_straight_left, self.kilo_straight_right)
        yield self.delay(2000)

        # Set the LED red.
        self.set_color(1, 0, 0)
        # Spinup the motors to overcome friction.
        self.spinup_motors()
        # Turn left for 2 seconds (2000 ms).
        self.set_motors(self.kilo_turn_left, 0)
        yield self.delay(2000)

        # Set the LED blue.
        self.set_color(0, 0, 1)
        # Spinup the motors to overcome friction.
        self.spinup_motors()
        # Turn right for 2 seconds (2000 ms).
        self.set_motors(0, self.kilo_turn_right)
        yield self.delay(2000)

        # Set the LED off.
        self.set_color(0, 0, 0)
        # Stop for half a second (500 ms).
        self.set_motors(0, 0)
        yield self.delay(500)


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("simple_movement", SimpleMovement, measures.movement)
