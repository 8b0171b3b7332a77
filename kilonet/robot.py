"""The kilolib-style robot program API.

A protocol is a subclass of :class:`Kilobot` that overrides the kilolib callbacks::

    class Blink(Kilobot):
        def setup(self):
            self.on = False

        def loop(self):
            if self.kilo_ticks % 32 == 0:
                self.on = not self.on
                self.set_color(3 * self.on, 0, 0)

The simulation calls ``setup()`` once at start, ``loop()`` every ``robot.loop_period_s``,
``message_tx()`` at every transmit opportunity (about every ``robot.tx_period_s``; return a
:class:`~kilonet.message.Message` or ``None``), ``message_tx_success()`` after a message went on
the air, and ``message_rx(message, distance_mm)`` on every reception in callback mode. In polled
mode (the thesis's library) receptions wait in a 3-message buffer and the program polls them
with :meth:`Kilobot.get_message`.

A program knows only what a Kilobot knows: its ticks, its (optional) UID, its battery voltage,
its own random source and what arrives through the medium. It has no handle on the world.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.message import Message

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = ["Kilobot", "RobotStopped"]


class RobotStopped(RuntimeError):
    """Raised when a program uses a robot that has stopped (crash, removal, flat battery)."""


class Kilobot:
    """Base class of robot programs; override the kilolib callbacks you need.

    Attributes provided by the simulation once the robot is attached:

    ``kilo_ticks``
        Clock ticks since start (``robot.ticks_per_s``, 32 per simulated second by default).
    ``kilo_uid``
        Hardware UID (the robot's index) if ``robot.hardware_uids`` is on.
    ``rand``
        This robot's own :class:`numpy.random.Generator` (kilolib's ``rand_hard``/``rand_soft``).

    The simulation keeps its handles in attributes named ``_sim``, ``_env``, ``_tps``,
    ``_index``, ``_rx_buffer`` and ``_color``: a program must not use these names.
    """

    # The simulation's handles live in slots inside the object: kilo_ticks reads two of them
    # on almost every call into a program, robot after robot in no order, and an object's
    # own slots are the fewest cache lines to touch. Programs keep a __dict__ for their state.
    __slots__ = (
        "__dict__",
        "__weakref__",
        "_color",
        "_env",
        "_index",
        "_rx_buffer",
        "_sim",
        "_tps",
        "rand",
    )

    # kilolib's motor calibration values; any non-zero value runs a motor.
    kilo_straight_left = 70
    kilo_straight_right = 70
    kilo_turn_left = 70
    kilo_turn_right = 70

    _sim: Simulation
    _index: int
    rand: np.random.Generator

    # -- callbacks a program overrides -------------------------------------------------------
    def setup(self) -> None:
        """Called once when the robot starts."""

    def loop(self) -> None:
        """Called every ``robot.loop_period_s``; not scheduled at all if not overridden."""

    def message_tx(self) -> Message | None:
        """Return the message to offer at this transmit opportunity, or ``None``."""
        return None

    def message_tx_success(self) -> None:
        """Called after the offered message went on the air."""

    def message_rx(self, message: Message, distance_mm: int) -> None:
        """Called on every reception in callback mode, with the estimated distance in mm."""

    # -- the kilolib API a program calls -----------------------------------------------------
    def _attach(self, sim: Simulation, index: int, rng: np.random.Generator) -> None:
        self._sim = sim
        self._env = sim.env
        self._tps = sim.params.robot.ticks_per_s
        self._index = index
        self.rand = rng
        self._rx_buffer: deque[tuple[Message, int]] = deque(maxlen=sim.params.robot.rx_buffer)
        self._color = (0, 0, 0)

    @property
    def kilo_ticks(self) -> int:
        """Clock ticks since the robot started."""
        return int(self._env._now * self._tps)

    @property
    def polled(self) -> bool:
        """Whether receptions wait in the polled buffer (the thesis's library) rather than
        arriving through ``message_rx``; fixed for a run, like a kilolib build option."""
        return self._sim.params.robot.rx_mode == "polled"

    @property
    def ticks_per_s(self) -> float:
        """kilolib's ``TICKS_PER_SEC`` for this robot (32 by default)."""
        return self._sim.params.robot.ticks_per_s

    @property
    def kilo_uid(self) -> int:
        """The hardware UID.

        Raises
        ------
        AttributeError
            If the scenario runs without hardware UIDs (``robot.hardware_uids = false``).
        """
        if not self._sim.params.robot.hardware_uids:
            raise AttributeError(
                "kilo_uid is not available: this run has robot.hardware_uids = false "
                "(robots must build their own IDs, as in the thesis)"
            )
        return self._index

    def rand_soft(self) -> int:
        """A random byte 0–255, like kilolib's ``rand_soft()``."""
        return int(self.rand.integers(256))

    def set_color(self, r: int, g: int, b: int) -> None:
        """Set the RGB LED; each channel 0–3 as kilolib's ``RGB(r, g, b)``.

        Raises
        ------
        ValueError
            If a channel is not an integer in 0–3.
        """
        color = (r, g, b)
        if any(not isinstance(c, int | np.integer) or not 0 <= c <= 3 for c in color):
            raise ValueError(f"set_color channels must be integers 0-3, got {color}")
        color = (int(r), int(g), int(b))
        if color != self._color:
            self._color = color
            self._sim.trace.led(self._sim.env.now, self._index, color)

    @property
    def color(self) -> tuple[int, int, int]:
        """The LED colour last set."""
        return self._color

    def set_motors(self, left: int, right: int) -> None:
        """Run the vibration motors (0–255 each; any non-zero value runs a motor).

        Both on: forward. Left only: pivot clockwise (turn right). Right only: pivot
        counter-clockwise (turn left). As on the robot, the resulting speed and turn rate carry
        this robot's own error.
        """
        for value in (left, right):
            if not 0 <= value <= 255:
                raise ValueError(f"motor values must be 0-255, got ({left}, {right})")
        self._sim.motion.set_motors(self._index, left > 0, right > 0)

    def spinup_motors(self) -> None:
        """kilolib's motor spin-up; the simulated motors need none."""

    def get_message(self) -> tuple[Message, int] | None:
        """Polled mode: the oldest buffered ``(message, distance_mm)``, or ``None``."""
        return self._rx_buffer.popleft() if self._rx_buffer else None

    def get_voltage(self) -> float:
        """Battery voltage in volts."""
        return self._sim.battery.voltage(self._index)

    def log(self, event: str, **fields: Any) -> None:
        """Record a protocol event (name and fields) in the run's trace."""
        self._sim.trace.event(self._sim.env.now, self._index, event, fields)
