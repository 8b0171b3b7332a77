"""Move to light (Kilobotics lab 5): ``move_to_light.c``, ported line by line.

The robot averages 300 ambient-light samples, turns right while the light is below
``THRESH_LO``, turns left once it is above ``THRESH_HI``, and keeps its turn in between; the
alternating pivots about its two rear legs walk it towards the light. The lab needs one
robot, kilonet at least two: ``move_to_light.csv`` places two, 250 mm on either side of the
light source that ``move_to_light.toml`` defines (which also says why those readings).

Changes of syntax: ``current_motion`` and ``current_light`` are attributes; ``sum`` is
``total`` (``sum`` is a Python builtin); ``sample_light`` is a generator, called with ``yield
from``, and retries a failed sample (-1, the ADC busy with an arriving message) after ``yield
self.delay(1)``: in Python simulated time passes only where the program yields, where the C
loop spins while the message arrives. Run::

    python -m examples.labs.move_to_light [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

try:  # part of the examples package (python -m examples.labs.move_to_light, the tests)
    from .lab_common import LEFT, RIGHT, MotionLab
except ImportError:  # loaded as a file of its own (kilonet run --program ...)
    from lab_common import LEFT, RIGHT, MotionLab

__all__ = ["THRESH_HI", "THRESH_LO", "MoveToLight"]

# Constants for light following.
THRESH_LO = 300
THRESH_HI = 600


class MoveToLight(MotionLab):
    """``move_to_light.c``: zigzag towards the light between two thresholds."""

    current_light = 0

    def sample_light(self):
        """Function to sample light (a generator: ``yield from self.sample_light()``)."""
        # The ambient light sensor gives noisy readings. To mitigate this,
        # we take the average of 300 samples in quick succession.

        number_of_samples = 0
        total = 0

        while number_of_samples < 300:
            sample = self.get_ambientlight()

            # -1 indicates a failed sample, which should be discarded.
            if sample != -1:
                total = total + sample
                number_of_samples = number_of_samples + 1
            else:
                yield self.delay(1)

        # Compute the average.
        self.current_light = total // number_of_samples

    def setup(self):
        # This ensures that the robot starts moving.
        self.set_motion(LEFT)

    def loop(self):
        yield from self.sample_light()

        if self.current_light < THRESH_LO:
            self.set_motion(RIGHT)
        elif self.current_light > THRESH_HI:
            self.set_motion(LEFT)


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("move_to_light", MoveToLight, measures.move_to_light)
