"""The kilolib-style robot program API.

A protocol is a subclass of :class:`Kilobot` that overrides the kilolib callbacks::

    class Blink(Kilobot):
        def setup(self):
            self.on = False

        def loop(self):
            if self.kilo_ticks % 32 == 0:
                self.on = not self.on
                self.set_color(3 * self.on, 0, 0)

The simulation calls ``setup()`` once at start, ``loop()`` once every ``robot.loop_ticks`` ticks
of the robot's own clock, ``message_tx()`` at every transmit opportunity (return a
:class:`~kilonet.message.Message` or ``None``), ``message_tx_success()`` after a message went on
the air, and ``message_rx(message, distance)`` on every reception in callback mode. In polled
mode (the thesis's library) receptions wait in a 3-message buffer and the program polls them
with :meth:`Kilobot.get_message`; a program that overrides ``message_rx`` gets what is left in
the buffer through it after each ``loop()`` (:meth:`Kilobot.drain_messages`), so a kilolib v2
program receives in both modes.

**Blocking calls.** kilolib's ``delay(ms)`` blocks the loop while receptions and transmissions
go on (they run in interrupts). In Python, write ``setup`` or ``loop`` as a generator and
``yield self.delay(ms)``; such a robot runs as a SimPy process of its own. Plain functions keep
working and cost less.

A program knows only what a Kilobot knows: its ticks, its UID (if it has one), its calibration
values, its sensors (battery voltage, ambient light, temperature), its own random sources and
what arrives through the medium. It has no handle on the world.
"""

from __future__ import annotations

import ast
import inspect
import textwrap
import weakref
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import FunctionType
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np

from kilonet.errors import ProgramTypeError, shown
from kilonet.message import Message, message_crc
from kilonet.ranging import CalibrationTables, DistanceMeasurement, estimate_distance

if TYPE_CHECKING:
    from simpy.events import Timeout

    from kilonet.clock import KernelEnvironment, RobotClocks
    from kilonet.medium import InfraredMedium
    from kilonet.motion import Motion
    from kilonet.params import RobotParams
    from kilonet.sensors import Sensors
    from kilonet.trace import Trace

__all__ = [
    "ADC_CONVERSION_S",
    "CALLBACKS",
    "RESERVED_PREFIX",
    "RGB",
    "TICKS_PER_SEC",
    "TIMER_COUNTS_PER_S",
    "HasRobotServices",
    "Kilobot",
    "RobotServices",
    "RobotStopped",
    "callback_place",
    "check_kernel_names",
    "check_program_class",
]

#: kilolib's ``kilo_tx_period`` unit: timer-0 counts, 8 MHz / 1024 = 7812.5 per second.
TIMER_COUNTS_PER_S = 7812.5
#: kilolib's ``TICKS_PER_SEC`` macro (``kilolib.h``); :attr:`Kilobot.TICKS_PER_SEC` follows
#: ``robot.ticks_per_s`` when a run changes it.
TICKS_PER_SEC = 31
#: One ADC conversion of ``get_ambientlight``/``get_voltage``/``get_temperature``: 13 ADC
#: clock cycles at 8 MHz / 64 (kilolib's prescaler), in seconds of the robot's clock.
ADC_CONVERSION_S = 13 * 64 / 8e6


def RGB(r: int, g: int, b: int) -> int:
    """kilolib's ``RGB(r, g, b)`` macro: the three 2-bit channels packed in one byte
    (``r | g << 2 | b << 4``), which :meth:`Kilobot.set_color` accepts as its one argument.

    Raises
    ------
    ValueError
        If a channel is not an integer 0-3 (the C macro would silently mask it).

    Examples
    --------
    >>> RGB(3, 0, 0), RGB(0, 3, 0), RGB(1, 2, 3)
    (3, 12, 57)
    """
    color = (r, g, b)
    if any(not isinstance(c, int | np.integer) or not 0 <= c <= 3 for c in color):
        raise ValueError(f"RGB channels must be integers 0-3, got {color}")
    return int(r) | int(g) << 2 | int(b) << 4


#: Attribute names the kernel keeps in every robot start with this; a program must not use it.
RESERVED_PREFIX = "_k"


@dataclass(frozen=True)
class RobotServices:
    """What the kernel gives the robots of a run: the parts a program reaches through the
    kilolib API, and nothing else (no world, no other robot). The simulation wires it once.

    Attributes
    ----------
    env : KernelEnvironment
        The run's clock (``kilo_ticks``, ``delay``).
    params : RobotParams
        The run's ``robot`` section.
    clocks : RobotClocks
        Each robot's oscillator.
    calibration_tables : sequence of CalibrationTables
        Each robot's ``kilo_irhigh``/``kilo_irlow`` (``estimate_distance``).
    uids : sequence of int or None
        Each robot's hardware UID, or ``None`` without ``robot.hardware_uids``.
    trace : Trace
        Where the LED and protocol events are recorded.
    medium : InfraredMedium
        The robot's transceiver: its transmit period, carrier sense.
    motion : Motion
        Its motors and their calibration.
    sensors : Sensors
        Its ADC readings (light, battery, temperature).
    """

    env: KernelEnvironment
    params: RobotParams
    clocks: RobotClocks
    calibration_tables: Sequence[CalibrationTables]
    uids: Sequence[int] | None
    trace: Trace
    medium: InfraredMedium
    motion: Motion
    sensors: Sensors


class HasRobotServices(Protocol):
    """What :meth:`Kilobot._attach` needs of a run (a :class:`~kilonet.simulation.Simulation`):
    its :class:`RobotServices`. Named by this protocol so that the robot API does not import
    the simulation, which imports it."""

    robot_services: RobotServices


class RobotStopped(RuntimeError):
    """Raised when a program uses a robot that has stopped (crash, removal, flat battery)."""


class Kilobot:
    """Base class of robot programs; override the kilolib callbacks you need.

    Attributes provided by the simulation once the robot is attached (kilolib's globals):

    ``kilo_ticks``
        Ticks of this robot's own clock since the start (nominally ``ticks_per_s``, 31 a
        second; each robot's oscillator runs a little fast or slow).
    ``kilo_uid``
        The robot's UID (settable; its index or the placement's ``uid`` column).
    ``kilo_turn_left``, ``kilo_turn_right``, ``kilo_straight_left``, ``kilo_straight_right``
        The motor calibration values stored on this robot (duty cycles, about 75).
    ``kilo_tx_period``
        The transmit period in kilolib's timer counts (3906 = 0.5 s; settable).
    ``rand``
        This robot's own :class:`numpy.random.Generator`, for Python programs (a Kilobot has
        ``rand_hard`` and ``rand_soft``, which are here too).

    The simulation keeps its handles in attributes whose names start with ``_k``
    (:data:`RESERVED_PREFIX`); a program that defines or sets such a name is refused when the
    simulation is built or right after its ``setup()``. Every other name, ``_rate`` or
    ``_index`` included, is the program's own.
    """

    # The simulation's handles live in slots inside the object: kilo_ticks reads three of them
    # on almost every call into a program, robot after robot in no order, and an object's
    # own slots are the fewest cache lines to touch. Programs keep a __dict__ for their state.
    __slots__ = (
        "__dict__",
        "__weakref__",
        "_kadc",
        "_kcolor",
        "_kdelay",
        "_kenv",
        "_khardware",
        "_kindex",
        "_kprocess",
        "_krate",
        "_krx",
        "_kservices",
        "_ksoft",
        "_ktables",
        "_ktheta",
        "_ktrace",
        "_ktx_period",
        "_kuid",
        "kilo_straight_left",
        "kilo_straight_right",
        "kilo_turn_left",
        "kilo_turn_right",
        "rand",
    )

    _kservices: RobotServices
    _khardware: Mapping[str, Any]
    _kindex: int
    rand: np.random.Generator

    #: What the program's LED colours mean, for the key of a run's animations:
    #: ``((r, g, b), meaning)`` pairs, kilolib levels 0-3 per channel, in the order to show.
    LED_KEY: ClassVar[tuple[tuple[tuple[int, int, int], str], ...]] = ()

    # -- callbacks a program overrides -------------------------------------------------------
    def setup(self) -> Any:
        """Called once when the robot starts (may be a generator that yields delays)."""

    def loop(self) -> Any:
        """Called every ``robot.loop_ticks`` ticks (may be a generator that yields delays);
        not scheduled at all if not overridden."""

    def message_tx(self) -> Message | None:
        """Return the message to offer at this transmit opportunity, or ``None``."""
        return None

    def message_tx_success(self) -> None:
        """Called after the offered message went on the air."""

    def message_rx(self, message: Message, distance: int | DistanceMeasurement) -> None:
        """Called on every reception in callback mode: the distance estimate in mm (or the raw
        :class:`~kilonet.ranging.DistanceMeasurement` with ``robot.rx_distance = "raw"``)."""

    def position_estimate(self) -> tuple[float, float, str] | None:
        """What a program believes its position is now: ``(x_mm, y_mm, frame)`` in the
        coordinates of its frame, named by ``frame`` (robots of one frame share coordinates),
        or ``None`` while it has no estimate.

        Not a kilolib callback: an instrument. The simulation samples it every
        ``trace.estimates_period_s`` for programs that override it, into the run's
        ``estimates`` table, so that animations show what each robot held at each moment. It
        must not change the program's state.
        """
        return None

    # -- attachment (the simulation calls this) ----------------------------------------------
    def _attach(
        self,
        sim: HasRobotServices,
        index: int,
        rng: np.random.Generator,
        hardware: Mapping[str, Any] | None = None,
    ) -> None:
        """Make this program robot ``index`` of ``sim``, drawing from ``rng``, carrying the
        extra ``hardware`` parts (name -> this robot's part; see :meth:`hardware`). The robot
        keeps ``sim.robot_services`` and its parts, not the simulation."""
        self._khardware = hardware or {}
        services = self._kservices = sim.robot_services
        self._kenv = services.env
        self._ktrace = services.trace
        self._kindex = index
        clocks = services.clocks
        self._krate = clocks.rate_hz(index)
        self._ktheta = float(clocks.phase[index])
        self.rand = rng
        self._krx: deque[tuple[Message, int]] = deque(maxlen=services.params.rx_buffer)
        self._kcolor = (0, 0, 0)
        self._kuid = services.uids[index] if services.uids is not None else None
        self._ksoft = [0xAA, 0]  # rand_soft's seed and accumulator, as kilolib starts them
        self._kdelay = None  # the delay a generator program has not yielded yet
        self._kadc = None  # (callback time, end) of the last ADC reading
        self._kprocess = False  # runs as a SimPy process (a generator setup or loop)
        self._ktx_period: int | None = None  # kilo_tx_period as the program last set it
        self._ktables: CalibrationTables = services.calibration_tables[index]
        cal = services.motion.calibrations[index]
        self.kilo_turn_left, self.kilo_turn_right = cal.turn_left, cal.turn_right
        self.kilo_straight_left, self.kilo_straight_right = cal.straight_left, cal.straight_right

    # -- the clock ---------------------------------------------------------------------------
    @property
    def kilo_ticks(self) -> int:
        """Ticks of this robot's clock since the start."""
        return int(self._kenv._kt * self._krate + self._ktheta)  # the kernel clock, no call

    @property
    def ticks_per_s(self) -> float:
        """kilolib's ``TICKS_PER_SEC`` (31): the nominal rate; this robot's true rate differs
        by its clock error."""
        return self._kservices.params.ticks_per_s

    @property
    def TICKS_PER_SEC(self) -> int:
        """kilolib's ``TICKS_PER_SEC`` as an integer: 31, or ``robot.ticks_per_s`` rounded
        when a run sets another nominal rate (Kilombo's 32)."""
        return round(self._kservices.params.ticks_per_s)

    def delay(self, ms: float) -> Timeout:
        """kilolib's ``delay(ms)``: in a generator ``setup`` or ``loop``, ``yield
        self.delay(ms)`` pauses the program for ``ms`` milliseconds of its own clock, while
        receptions and transmissions go on.

        Raises
        ------
        RuntimeError
            If called from a plain (non-generator) ``setup`` or ``loop``, where nothing can
            block; or if the previous delay was not yielded.
        ValueError
            If ``ms`` is not a number >= 0 (a NaN or a text would reach the event queue,
            which cannot place it in time).
        """
        if not self._kprocess:
            raise RuntimeError(
                f"robot {self._kindex}: delay() blocks only in a generator setup/loop; write "
                "`yield self.delay(ms)` there"
            )
        if self._kdelay is not None:
            raise RuntimeError(f"robot {self._kindex}: delay() was called without `yield`")
        try:
            valid = ms >= 0  # False for a NaN
        except TypeError:  # not a number
            valid = False
        if not valid:
            raise ValueError(f"delay(ms) needs a number of ms >= 0, got {ms!r}")
        self._kdelay = self._kenv.timeout(self._kservices.clocks.true_s(self._kindex, ms / 1000.0))
        return self._kdelay

    @property
    def kilo_tx_period(self) -> int:
        """kilolib's transmit period in timer counts (default 3906). kilolib's timer adds 255
        counts a tick and offers a message at the first tick past this many, so the period is
        ``kilo_tx_period // 255 + 1`` ticks (3906: 16 ticks, 0.524 s of this robot's clock)."""
        if self._ktx_period is not None:
            return self._ktx_period
        own_s = self._kservices.medium.tx_period_own_s(self._kindex)
        ticks = own_s * TIMER_COUNTS_PER_S / 256
        if abs(ticks - 16) < 1e-9:
            return 3906
        return round(own_s * TIMER_COUNTS_PER_S)

    @kilo_tx_period.setter
    def kilo_tx_period(self, counts: int) -> None:
        if not 0 < counts <= 0xFFFF:
            raise ValueError(f"kilo_tx_period is a uint16 of timer counts > 0, got {counts}")
        self._ktx_period = int(counts)
        ticks = counts // 255 + 1
        self._kservices.medium.set_tx_period(self._kindex, ticks * 256 / TIMER_COUNTS_PER_S)

    # -- identity and randomness -------------------------------------------------------------
    @property
    def kilo_uid(self) -> int:
        """The robot's UID (kilolib reads it from the EEPROM; programs may overwrite it).

        Raises
        ------
        AttributeError
            If the run has no hardware UIDs (``robot.hardware_uids = false``) and the program
            has not set one.
        """
        if self._kuid is None:
            raise AttributeError(
                "kilo_uid is not available: this run has robot.hardware_uids = false "
                "(robots must build their own IDs, as in the thesis)"
            )
        return self._kuid

    @kilo_uid.setter
    def kilo_uid(self, uid: int) -> None:
        if not 0 <= uid <= 0xFFFF:
            raise ValueError(f"kilo_uid is a uint16, got {uid}")
        self._kuid = int(uid)

    def rand_soft(self) -> int:
        """kilolib's ``rand_soft()``: a byte from a tiny xorshift generator that starts in
        the same state on every robot (seed 0xAA), so all robots draw the same sequence
        unless they call :meth:`rand_seed`.

        Examples
        --------
        >>> bot = Kilobot.__new__(Kilobot); bot._ksoft = [0xAA, 0]
        >>> [bot.rand_soft() for _ in range(4)]
        [253, 21, 184, 123]
        """
        seed, acc = self._ksoft
        seed ^= (seed << 3) & 0xFF
        seed ^= seed >> 5
        seed ^= acc >> 2
        self._ksoft = [seed, (acc + 1) & 0xFF]
        return seed

    def rand_seed(self, seed: int) -> None:
        """kilolib's ``rand_seed(seed)``: set :meth:`rand_soft`'s seed byte."""
        self._ksoft[0] = int(seed) & 0xFF

    def rand_hard(self) -> int:
        """kilolib's ``rand_hard()``: a random byte from hardware noise, different on every
        robot (here: this robot's own generator)."""
        return int(self.rand.integers(256))

    # -- the LED and the motors --------------------------------------------------------------
    def set_color(self, r: int, g: int | None = None, b: int | None = None) -> None:
        """Set the RGB LED: ``set_color(r, g, b)``, each channel 0–3, or kilolib's
        ``set_color(RGB(r, g, b))`` with one packed byte (see :func:`RGB`).

        Raises
        ------
        ValueError
            If a channel is not an integer in 0–3, or a packed colour not one of 0–63.
        """
        color = (r, g, b)
        if r.__class__ is int and g.__class__ is int and b.__class__ is int:
            # the common case, checked without a call (loops set it often)
            if color == self._kcolor:
                return  # the colour it has: valid already
            if not (0 <= r <= 3 and 0 <= g <= 3 and 0 <= b <= 3):
                raise ValueError(f"set_color channels must be integers 0-3, got {color}")
        else:
            if g is None and b is None:
                if not isinstance(r, int | np.integer) or not 0 <= r <= 63:
                    raise ValueError(f"set_color(RGB(r, g, b)) takes a byte 0-63, got {r!r}")
                r, g, b = r & 3, (r >> 2) & 3, (r >> 4) & 3
            color = (r, g, b)
            if any(not isinstance(c, int | np.integer) or not 0 <= c <= 3 for c in color):
                raise ValueError(f"set_color channels must be integers 0-3, got {color}")
            color = (int(r), int(g), int(b))
        if color != self._kcolor:
            self._kcolor = color
            self._ktrace.led(self._kenv.now, self._kindex, color)

    @property
    def color(self) -> tuple[int, int, int]:
        """The LED colour last set."""
        return self._kcolor

    def set_motors(self, left: int, right: int) -> None:
        """kilolib's ``set_motors(left, right)``: duty cycles 0–255.

        ``set_motors(kilo_turn_left, 0)`` turns left (counter-clockwise, pivoting about the
        left rear leg), ``set_motors(0, kilo_turn_right)`` right, ``set_motors(kilo_straight_left,
        kilo_straight_right)`` goes forward. A motor at rest needs :meth:`spinup_motors` (or a
        high duty) to start; see :mod:`kilonet.motion` for the curve.

        Raises
        ------
        ValueError
            If a value is not an integer 0-255.
        """
        for value in (left, right):
            if not isinstance(value, int | np.integer) or not 0 <= value <= 255:
                raise ValueError(f"motor values must be integers 0-255, got ({left}, {right})")
        self._kservices.motion.set_motors(self._kindex, int(left), int(right))

    def spinup_motors(self) -> None:
        """kilolib's ``spinup_motors()``: both motors at full duty, which starts a motor at
        rest. (kilolib then waits 15 ms; here the next ``set_motors`` follows at once, so the
        burst moves the robot by nothing instead of about 0.3 mm.)"""
        self._kservices.motion.set_motors(self._kindex, 255, 255)

    # -- messages and receptions -------------------------------------------------------------
    @staticmethod
    def message_crc(message: Message) -> int:
        """kilolib's ``message_crc(&msg)``: the CRC a receiver expects (see
        :func:`kilonet.message.message_crc`); ``replace(msg, crc=self.message_crc(msg))``."""
        return message_crc(message)

    def get_message(self) -> tuple[Message, int] | None:
        """Polled mode: the oldest buffered ``(message, distance)``, or ``None``."""
        return self._krx.popleft() if self._krx else None

    def drain_messages(self) -> int:
        """Polled mode: hand every buffered message, oldest first, to ``message_rx``; the
        number handed over (0 in callback mode, where nothing is buffered).

        The simulation calls it after every ``loop()`` of a program that overrides
        ``message_rx``, so such a program receives in polled mode too (a tick late at most);
        a program calls it itself to take its messages at a point of its choosing.
        """
        buffer, receive, n = self._krx, self.message_rx, 0
        while buffer:
            receive(*buffer.popleft())
            n += 1
        return n

    def estimate_distance(self, distance: int | DistanceMeasurement) -> int:
        """kilolib's ``estimate_distance(&d)``: centre-to-centre mm from a raw measurement, on
        this robot's calibration tables (an estimate already in mm is returned unchanged)."""
        return estimate_distance(distance, self._ktables)

    # -- sensors -----------------------------------------------------------------------------
    def get_ambientlight(self) -> int:
        """kilolib's ``get_ambientlight()``: a 10-bit reading of the light where the robot
        stands, or -1 while a message is arriving (the ADC is busy measuring it)."""
        if self._kadc_busy():
            return -1
        return self._kservices.sensors.ambient_light(self._kindex)

    def get_voltage(self) -> int:
        """kilolib's ``get_voltage()``: a 10-bit reading of the battery (about ``169 * V +
        6``: 547 at 3.2 V, 716 at 4.2 V), or -1 while a message is arriving."""
        if self._kadc_busy():
            return -1
        return self._kservices.sensors.voltage_reading(self._kindex)

    def get_temperature(self) -> int:
        """kilolib's ``get_temperature()``: a 10-bit reading of the ATmega328P's temperature
        sensor against its 1.1 V reference (about 292 at 25 °C), or -1 while a message is
        arriving."""
        if self._kadc_busy():
            return -1
        return self._kservices.sensors.temperature_reading(self._kindex)

    def _kadc_busy(self) -> bool:
        """Whether this ADC reading finds a message arriving. Each reading takes
        :data:`ADC_CONVERSION_S` of the robot's time, and readings in one callback follow each
        other, so a callback that spins on ``while get_ambientlight() == -1`` (kilolib's
        idiom) reads a real value once the message has ended, as on the robot, although the
        simulation's clock stands still until the callback returns."""
        now = self._kenv.now
        last = self._kadc
        at = last[1] + ADC_CONVERSION_S if last is not None and last[0] == now else now
        self._kadc = (now, at)
        return self._kservices.medium.channel.busy(self._kindex, at)  # a carrier at `at`

    # -- extra hardware ----------------------------------------------------------------------
    def hardware(self, name: str) -> Any:
        """The extra hardware ``name`` this robot carries (a maze robot's camera, wall sensor
        and cell drive): the part that whoever built the run fitted to it
        (``Simulation(hardware=...)``), which reads the world the way a sensor does.

        Raises
        ------
        LookupError
            If this robot carries no such hardware.
        """
        part = self._khardware.get(name)
        if part is None:
            raise LookupError(
                f"robot {self._kindex} carries no {name!r} hardware; the run fits it with "
                "Simulation(hardware={...})"
            )
        return part

    # -- the run's record --------------------------------------------------------------------
    def log(self, event: str, **fields: Any) -> None:
        """Record a protocol event (name and fields) in the run's trace."""
        self._ktrace.event(self._kenv.now, self._kindex, event, fields)

    @property
    def polled(self) -> bool:
        """Whether receptions wait in the polled buffer (the thesis's library) rather than
        arriving through ``message_rx``; fixed for a run, like a kilolib build option."""
        return self._kservices.params.rx_mode == "polled"


#: The callbacks the simulation calls on a program, and the arguments it passes each.
CALLBACKS: Mapping[str, tuple[str, ...]] = {
    "setup": (),
    "loop": (),
    "message_tx": (),
    "message_tx_success": (),
    "message_rx": ("message", "distance"),
    "position_estimate": (),
}

#: What a program class may redefine of :class:`Kilobot`: its callbacks and its LED key.
#: Every other name of the class is the kilolib API the simulation runs the robot with.
_OVERRIDABLE = frozenset(CALLBACKS) | {"LED_KEY"}


def check_program_class(cls: type[Kilobot]) -> None:
    """Refuse a program class the kernel would run wrongly, or fail in, without naming the
    program: the error (a :class:`~kilonet.errors.ProgramTypeError`) names the program's file
    and line. Checked once per class (the first simulation built with it), so no call pays for it.

    Raises
    ------
    kilonet.errors.ProgramTypeError
        (a ``TypeError``) If a class of the program defines a name starting with
        :data:`RESERVED_PREFIX` (the kernel's own attributes) or another name of the kilolib
        API (``delay``, ``set_color``, ``_attach``, ...); defines a callback
        (:data:`CALLBACKS`) that is not a method (``loop = None``), is ``async`` (never
        awaited: it would never run) or cannot take the arguments the simulation passes;
        defines an :attr:`~Kilobot.LED_KEY` that is not ``((r, g, b), meaning)`` pairs; or
        overrides a generator ``setup``/``loop`` with a plain function that calls
        ``super().setup()``/``super().loop()`` (that call only builds the parent's generator
        and throws it away: the parent's code never runs).

    Examples
    --------
    >>> class Parent(Kilobot):
    ...     def setup(self):
    ...         yield self.delay(10)
    >>> class Child(Parent):
    ...     def setup(self):
    ...         super().setup()
    >>> check_program_class(Child)
    Traceback (most recent call last):
    ...
    kilonet.errors.ProgramTypeError: ...: Child.setup is a plain function but calls super()...
    >>> class Fixed(Parent):
    ...     def setup(self):
    ...         yield from super().setup()
    >>> check_program_class(Fixed)
    """
    if cls in _CHECKED:
        return
    own = [k for k in cls.__mro__ if k is not Kilobot and issubclass(k, Kilobot)]
    for klass in own:
        for name in vars(klass):
            if name.startswith(RESERVED_PREFIX):
                raise ProgramTypeError(
                    f"{klass.__name__}.{name}: names starting with {RESERVED_PREFIX!r} are the "
                    "kernel's; rename it",
                    *_attribute_place(klass, name),
                )
            if name in vars(Kilobot) and name not in _OVERRIDABLE and not name.startswith("__"):
                raise ProgramTypeError(
                    f"{klass.__name__}.{name} replaces Kilobot.{name}, part of the kilolib API "
                    "the simulation runs the robot with; give yours another name",
                    *_attribute_place(klass, name),
                )
    for name, args in CALLBACKS.items():
        _check_callback(cls, name, args)
    _check_led_key(cls)
    for method in ("setup", "loop"):
        for i, klass in enumerate(own):
            fn = vars(klass).get(method)
            if fn is None or inspect.isgeneratorfunction(fn):
                continue
            code = getattr(fn, "__code__", None)
            if code is None or "super" not in code.co_names or method not in code.co_names:
                continue
            parent = next((k for k in own[i + 1 :] if method in vars(k)), None)
            if parent is not None and inspect.isgeneratorfunction(vars(parent)[method]):
                raise ProgramTypeError(
                    f"{klass.__name__}.{method} is a plain function but calls super().{method}(), "
                    f"which is a generator ({parent.__name__}.{method}): that call does not run "
                    f"it; make {klass.__name__}.{method} a generator with "
                    f"`yield from super().{method}()`",
                    code.co_filename,
                    code.co_firstlineno,
                )
    _CHECKED.add(cls)


#: The program classes :func:`check_program_class` passed (each is checked once a process).
_CHECKED: weakref.WeakSet[type] = weakref.WeakSet()


def _check_callback(cls: type[Kilobot], name: str, args: tuple[str, ...]) -> None:
    """Refuse callback ``name`` of ``cls`` if the simulation cannot call it with ``args`` (see
    :func:`check_program_class`)."""
    owner = next(k for k in cls.__mro__ if name in vars(k))
    if owner is Kilobot:
        return
    raw = vars(owner)[name]
    call = f"{name}({', '.join(args)})"
    if isinstance(raw, FunctionType | staticmethod | classmethod):
        bound = raw.__get__(_PROBE, cls)
    elif callable(raw) and not hasattr(type(raw), "__get__"):
        bound = raw  # a callable object: called as it is, without the robot
    elif hasattr(type(raw), "__get__") and not isinstance(raw, property):
        return  # another descriptor (a partialmethod, ...): what it gives is its own affair
    else:
        raise ProgramTypeError(
            f"{owner.__name__}.{name} = {shown(raw)} is not a method: the simulation calls {call}; "
            f"define def {name}(self{''.join(', ' + a for a in args)}) or leave it out",
            *_attribute_place(owner, name),
        )
    function = getattr(raw, "__func__", raw)
    code = getattr(function, "__code__", None)
    place = callback_place(cls, name)
    if inspect.iscoroutinefunction(function) or inspect.isasyncgenfunction(function):
        raise ProgramTypeError(
            f"{owner.__name__}.{name} is a coroutine function (async def): the simulation "
            f"calls {call} and never awaits it, so its body would never run; write a plain "
            "def (a generator with `yield self.delay(ms)` to wait)",
            *place,
        )
    try:
        signature = inspect.signature(bound)
    except (TypeError, ValueError):  # a callable without a signature Python can read
        return
    try:
        signature.bind(*args)
    except TypeError:
        spelled = inspect.signature(function) if code else signature
        raise ProgramTypeError(
            f"{owner.__name__}.{name}{spelled} cannot take the arguments {call} the simulation "
            "calls it with",
            *place,
        ) from None


def callback_place(cls: type[Kilobot], name: str) -> tuple[str | None, int | None]:
    """The file and line where program class ``cls`` defines callback ``name`` (the line of
    its ``def``), for an error message; ``(None, None)`` if that is not known.

    Examples
    --------
    >>> callback_place(Kilobot, "loop")[1] > 0
    True
    """
    owner = next((k for k in cls.__mro__ if name in vars(k)), None)
    if owner is None:
        return None, None
    raw = vars(owner)[name]
    code = getattr(getattr(raw, "__func__", raw), "__code__", None)
    return (code.co_filename, code.co_firstlineno) if code else _attribute_place(owner, name)


def _check_led_key(cls: type[Kilobot]) -> None:
    """Refuse a :attr:`Kilobot.LED_KEY` that is not ``((r, g, b), meaning)`` pairs with
    levels 0-3 (the run's outputs read it once the run is over)."""
    key = cls.LED_KEY
    try:
        valid = all(
            len(colour) == 3
            and all(isinstance(c, int | np.integer) and 0 <= c <= 3 for c in colour)
            and isinstance(meaning, str)
            for colour, meaning in key
        )
    except (TypeError, ValueError):  # not pairs of a colour and a meaning
        valid = False
    if not valid:
        owner = next(k for k in cls.__mro__ if "LED_KEY" in vars(k))
        raise ProgramTypeError(
            f"{owner.__name__}.LED_KEY = {shown(key)}: give ((r, g, b), meaning) pairs, "
            "levels 0-3, as (((3, 0, 0), 'leader'),)",
            *_attribute_place(owner, "LED_KEY"),
        )


#: What a method is bound to when its signature is checked (any object: nothing is called).
_PROBE = object()


def _attribute_place(klass: type, name: str | None = None) -> tuple[str | None, int | None]:
    """The file and line where class ``klass`` defines ``name`` (the class's own line without
    ``name`` or if that cannot be found; ``(None, None)`` without source): for an error
    message only."""
    try:
        lines, first = inspect.getsourcelines(klass)
        file = inspect.getsourcefile(klass)
    except (OSError, TypeError):
        return None, None
    if name is None:
        return file, first
    try:
        body = ast.parse(textwrap.dedent("".join(lines))).body[0].body
    except (SyntaxError, IndexError, AttributeError):
        return file, first
    for node in body:
        targets: list[ast.expr] = []
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            if node.name == name:
                return file, first + node.lineno - 1
        elif isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign | ast.AugAssign):
            targets = [node.target]
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            return file, first + node.lineno - 1
    return file, first


def check_kernel_names(robot: Kilobot, index: int, slots: dict[str, Any]) -> None:
    """Refuse a program that set an attribute starting with :data:`RESERVED_PREFIX` (the
    simulation calls it after ``setup()`` and when a run stops, with the values its kernel
    slots must hold).

    Raises
    ------
    kilonet.errors.ProgramTypeError
        (a ``TypeError``) If such a name is in the robot's ``__dict__``, or a slot in
        ``slots`` no longer holds that value; it names the program's class and its line.
    """
    names = [k for k in vars(robot) if k.startswith(RESERVED_PREFIX)]
    names += [k for k, v in slots.items() if getattr(robot, k, None) != v]
    if names:
        cls = type(robot)
        raise ProgramTypeError(
            f"robot {index} ({cls.__name__}) set {', '.join(names)}: names starting "
            f"with {RESERVED_PREFIX!r} are the kernel's; rename them",
            *_attribute_place(cls),
        )
