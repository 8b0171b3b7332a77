"""The orbit lab (Kilobotics lab 4): ``orbit_star.c`` and ``orbit_planet.c``, ported line by line.

The star sends a message at every transmit opportunity and blinks magenta for 100 ms after each
one it sent. The planet keeps the star at ``DESIRED_DISTANCE``: on every message it turns left
(away) when closer than that, right (towards the star) when farther, and drives forward when
closer than ``TOO_CLOSE_DISTANCE``. Because a one-motor turn pivots the body about a rear leg,
the alternating turns walk the planet around the star (clockwise: the star on its right).

On the robots the two programs are two hex files flashed onto different robots. Here they are
:class:`OrbitStar` and :class:`OrbitPlanet`, and :class:`Orbit` runs both as one program (the
robot whose ``kilo_uid`` is ``STAR_UID`` is the star), so ``kilonet run --program`` can run the
lab: ``orbit.csv`` places the star (uid 0) and a planet (uid 1) 60 mm apart.

Changes of syntax: the C globals are attributes set in ``setup``; ``RGB(r, g, b)`` becomes
``set_color(r, g, b)``; ``estimate_distance(d)`` is ``self.estimate_distance(d)`` (the star's
changes are :mod:`examples.labs.speaker_listener`'s). Run::

    python -m examples.labs.orbit [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

try:  # part of the examples package (python -m examples.labs.orbit, the tests)
    from .lab_common import FORWARD, LEFT, RIGHT, MotionLab
    from .speaker_listener import TestSpeaker
except ImportError:  # loaded as a file of its own (kilonet run --program examples/labs/orbit.py)
    from lab_common import FORWARD, LEFT, RIGHT, MotionLab
    from speaker_listener import TestSpeaker

__all__ = [
    "DESIRED_DISTANCE",
    "STAR_UID",
    "TOO_CLOSE_DISTANCE",
    "Orbit",
    "OrbitPlanet",
    "OrbitStar",
]

# Constants for orbit control.
TOO_CLOSE_DISTANCE = 40
DESIRED_DISTANCE = 60

#: The robot that runs orbit_star when both programs run as :class:`Orbit`.
STAR_UID = 0


class OrbitStar(TestSpeaker):
    """``orbit_star.c``: send a message all the time, blink magenta for each one sent. The C
    file is ``test_speaker.c`` to the letter (only comments differ), so this is
    :class:`~examples.labs.speaker_listener.TestSpeaker`."""


class OrbitPlanet(MotionLab):
    """``orbit_planet.c``: orbit the star at ``DESIRED_DISTANCE`` mm."""

    def setup(self):
        self.distance = 0
        self.new_message = 0

    def loop(self):
        # Update the motion whenever a message is received.
        if self.new_message == 1:
            self.new_message = 0

            # If too close, move forward to get back into orbit.
            if self.distance < TOO_CLOSE_DISTANCE:
                self.set_color(0, 1, 0)
                self.set_motion(FORWARD)
            # If not too close, turn left or right depending on distance,
            # to maintain orbit.
            else:
                if self.distance < DESIRED_DISTANCE:
                    self.set_color(1, 0, 0)
                    self.set_motion(LEFT)
                else:
                    self.set_color(0, 0, 1)
                    self.set_motion(RIGHT)

    def message_rx(self, m, d):
        self.new_message = 1
        self.distance = self.estimate_distance(d)


class Orbit(OrbitPlanet, OrbitStar):
    """Both programs in one: the robot with ``kilo_uid == STAR_UID`` runs :class:`OrbitStar`,
    every other robot :class:`OrbitPlanet` (the planet sends nothing, as orbit_planet.c
    registers no ``message_tx``)."""

    def setup(self):
        self.star = self.kilo_uid == STAR_UID
        (OrbitStar if self.star else OrbitPlanet).setup(self)

    def loop(self):
        if self.star:
            yield from OrbitStar.loop(self)
        else:
            OrbitPlanet.loop(self)

    def message_tx(self):
        return OrbitStar.message_tx(self) if self.star else None

    def message_tx_success(self):
        OrbitStar.message_tx_success(self)

    def message_rx(self, m, d):
        if not self.star:
            OrbitPlanet.message_rx(self, m, d)


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("orbit", Orbit, measures.orbit)
