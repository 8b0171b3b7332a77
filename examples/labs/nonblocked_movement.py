"""Non-blocked movement (Kilobotics lab 1.2): ``nonblocked_movement.c``, ported line by line.

Every 64 ticks (about 2 s) the robot changes state: forward (green), then left (red, the left
motor alone: it turns counter-clockwise about its left rear leg), then right (blue), and again,
without ever blocking in ``delay``: the loop compares ``kilo_ticks`` with the last update.

Changes of syntax: the C globals are attributes set in ``setup``; ``RGB(r, g, b)`` becomes
``set_color(r, g, b)``. Run::

    python -m examples.labs.nonblocked_movement [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

from kilonet.robot import Kilobot

__all__ = ["FORWARD_GREEN", "LEFT_RED", "RIGHT_BLUE", "NonblockedMovement"]

# Declare constants.
LEFT_RED = 0
RIGHT_BLUE = 1
FORWARD_GREEN = 2


class NonblockedMovement(Kilobot):
    """``nonblocked_movement.c``: forward, left, right, 64 ticks each."""

    def setup(self):
        self.state = FORWARD_GREEN
        self.last_state_update = self.kilo_ticks

    def loop(self):
        # Update the state every 64 clock ticks (roughly 2 seconds).
        if self.kilo_ticks > (self.last_state_update + 64):
            self.last_state_update = self.kilo_ticks

            if self.state == FORWARD_GREEN:
                self.set_color(0, 1, 0)
                self.spinup_motors()
                self.set_motors(self.kilo_straight_left, self.kilo_straight_right)

                # Set the next state.
                self.state = LEFT_RED
            elif self.state == LEFT_RED:
                self.set_color(1, 0, 0)
                self.spinup_motors()
                self.set_motors(self.kilo_turn_left, 0)

                # Set the next state.
                self.state = RIGHT_BLUE
            elif self.state == RIGHT_BLUE:
                self.set_color(0, 0, 1)
                self.spinup_motors()
                self.set_motors(0, self.kilo_turn_right)

                # Set the next state.
                self.state = FORWARD_GREEN


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("nonblocked_movement", NonblockedMovement, measures.movement)
