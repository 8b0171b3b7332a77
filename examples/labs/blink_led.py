"""Blink the LED (Kilobotics lab 0): ``blink_led.c``, ported line by line.

Red for half a second, blue for half a second, and again.

Changes of syntax: ``delay(500)`` is ``yield self.delay(500)`` in a generator ``loop``; ``RGB(r,
g, b)`` becomes ``set_color(r, g, b)``. Run::

    python -m examples.labs.blink_led [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

from kilonet.robot import Kilobot

__all__ = ["BlinkLed"]


class BlinkLed(Kilobot):
    """``blink_led.c``: red and blue, half a second each."""

    def setup(self):
        # Put any setup code here. This is run once before entering the loop.
        pass

    def loop(self):
        # Put the main code here. This is run repeatedly.

        # Set the LED red.
        self.set_color(1, 0, 0)
        # Wait half a second (500 ms).
        yield self.delay(500)
        # Set the LED blue.
        self.set_color(0, 0, 1)
        # Wait half a second (500 ms).
        yield self.delay(500)


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("blink_led", BlinkLed, measures.blink_led)
