"""Vibration-motor motion: kilolib's motor commands, a motor curve with stalls, pivot turns about
a leg, per-robot errors, and bodies that slide along each other.

**Directions** (kilolib, ``kilolib.h``): ``set_motors(left, right)``; ``set_motors(kilo_turn_left,
0)`` turns the robot **left** (counter-clockwise), ``set_motors(0, kilo_turn_right)`` right, both
motors drive it forward. Headings are counter-clockwise from +x.

**Motor curve.** A duty cycle ``v`` (0-255) gives a motor the drive ``a = (v - offset) / gain``
(Kilombo's ``skilobot.c``: offset 60, 15 duty per unit), with ``offset`` and ``gain`` drawn per
motor (``motion.motor_offset_sd``, ``motion.motor_gain_sd``). Drive 1 is the robot's *true* best
value: it turns at ``turn_deg_s`` on that motor alone and, with both motors at drive 1, goes
straight at ``speed_mm_s`` (each robot with its own ``speed_error``/``turn_error`` on top). A
stopped motor starts only at ``start_drive`` or more, or after ``spinup_motors()`` (kilolib: full
duty for 15 ms "to overcome the effects of static friction"); a running one stalls below
``stall_drive`` (Kilombo's 0.5); drive saturates at ``max_drive`` (kilolib warns against duty
above 90, about drive 2, Kilombo's upper cut-off). The calibration values a robot stores
(``kilo_turn_left``, ``kilo_straight_left``, ...) are its true best values plus an error of
``N(0, calibration_sd)`` duty, as a calibration by eye leaves them.

**Kinematics.** One motor alone pivots the body about its rear leg on that side (Kilombo: the
leg at ``pivot_angle_deg`` = 125.5° from the heading, "measured from kilobot PCB design files",
at the body radius), so the centre moves on an arc and a turn also displaces the robot. Both
motors drive it forward at ``speed * (a_l + a_r) / 2`` and yaw it at ``drift_gain * turn *
(a_l - a_r)`` (the stronger left motor curves it left). The battery's motor factor scales the
drives.

**Contact.** Bodies never overlap: a move that would make two discs overlap goes to contact and
the rest of the step slides along the other disc's tangent (Kilombo and ARGoS let bodies push or
slide; they never stick).

**Integration.** One timer for the whole swarm runs every ``step_s`` while any robot moves; it
integrates every moving robot's pose (exactly along its arc within a step) and rebuilds the
medium's links once. ``set_motors`` integrates that robot up to now first. A static swarm pays
nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from kilonet.clock import Timer

if TYPE_CHECKING:
    from collections.abc import Callable

    from kilonet.battery import Battery
    from kilonet.clock import KernelEnvironment
    from kilonet.params import MotionParams
    from kilonet.trace import Trace
    from kilonet.world import World

__all__ = [
    "Calibration",
    "Motion",
    "MotorState",
    "contact_distance",
    "motor_drive",
    "pose_after",
    "slide",
]


def motor_drive(
    duty: int, offset: float, gain: float, running: bool, params: MotionParams
) -> tuple[float, bool]:
    """The drive a motor at ``duty`` gives, and whether it runs.

    Parameters
    ----------
    duty : int
        Duty cycle 0-255 (kilolib's ``set_motors`` value).
    offset, gain : float
        This motor's curve: drive ``(duty - offset) / gain``.
    running : bool
        Whether the motor runs now (a running motor keeps going down to ``stall_drive``; a
        stopped one needs ``start_drive``).

    Examples
    --------
    >>> from kilonet.params import MotionParams
    >>> p = MotionParams()
    >>> motor_drive(75, 60.0, 15.0, True, p), motor_drive(75, 60.0, 15.0, False, p)
    ((1.0, True), (0.0, False))
    >>> motor_drive(255, 60.0, 15.0, False, p), motor_drive(64, 60.0, 15.0, True, p)
    ((2.0, True), (0.0, False))
    """
    if duty <= 0:
        return 0.0, False
    drive = (duty - offset) / gain
    runs = drive >= (params.stall_drive if running else params.start_drive)
    return (min(drive, params.max_drive), True) if runs else (0.0, False)


def pose_after(
    x_mm: float,
    y_mm: float,
    heading_rad: float,
    drive_left: float,
    drive_right: float,
    dt_s: float,
    *,
    speed_mm_s: float,
    turn_rad_s: float,
    pivot_mm: tuple[float, float],
    drift_gain: float,
) -> tuple[float, float, float]:
    """Pose after ``dt_s`` with constant drives, without obstacles.

    ``pivot_mm`` is the left rear leg in the body frame (forward, left), mm; the right leg is
    its mirror image.

    Examples
    --------
    A left pivot (left motor alone, counter-clockwise) by 90° about the leg at (-10, 10) mm:

    >>> x, y, h = pose_after(0, 0, 0, 1.0, 0.0, 2.0, speed_mm_s=10, turn_rad_s=math.pi / 4,
    ...                      pivot_mm=(-10.0, 10.0), drift_gain=0.5)
    >>> round(x, 9), round(y, 9), round(math.degrees(h), 9)
    (0.0, 20.0, 90.0)
    >>> pose_after(0, 0, 0, 1.0, 1.0, 2.0, speed_mm_s=10, turn_rad_s=1.0,
    ...            pivot_mm=(-10.0, 10.0), drift_gain=0.5)
    (20.0, 0.0, 0.0)
    """
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    if drive_left > 0 and drive_right > 0:
        v = speed_mm_s * (drive_left + drive_right) / 2
        w = drift_gain * turn_rad_s * (drive_left - drive_right)
        if abs(w * dt_s) < 1e-12:
            return x_mm + v * dt_s * c, y_mm + v * dt_s * s, float(heading_rad)
        h = heading_rad + w * dt_s
        radius = v / w  # an arc about the centre of curvature, on the left for w > 0
        return (
            x_mm + radius * (math.sin(h) - s),
            y_mm - radius * (math.cos(h) - c),
            h,
        )
    if drive_left > 0:
        w, fwd, lat = turn_rad_s * drive_left, pivot_mm[0], pivot_mm[1]
    elif drive_right > 0:
        w, fwd, lat = -turn_rad_s * drive_right, pivot_mm[0], -pivot_mm[1]
    else:
        return x_mm, y_mm, float(heading_rad)
    px, py = x_mm + fwd * c - lat * s, y_mm + fwd * s + lat * c  # the leg, on the table
    dh = w * dt_s
    cd, sd = math.cos(dh), math.sin(dh)
    rx, ry = x_mm - px, y_mm - py
    return px + rx * cd - ry * sd, py + rx * sd + ry * cd, heading_rad + dh


def contact_distance(
    start_mm: np.ndarray, direction: np.ndarray, others_mm: np.ndarray, diameter_mm: float
) -> tuple[float, int]:
    """How far a disc can travel from ``start_mm`` along unit ``direction`` before touching
    one of ``others_mm``, and which (``(inf, -1)`` when none is in the way).

    Examples
    --------
    >>> contact_distance(np.zeros(2), np.array([1.0, 0.0]), np.array([[50.0, 0.0]]), 33.0)
    (17.0, 0)
    >>> contact_distance(np.zeros(2), np.array([-1.0, 0.0]), np.array([[50.0, 0.0]]), 33.0)
    (inf, -1)
    """
    if len(others_mm) == 0:
        return math.inf, -1
    w = others_mm - start_mm
    along = w @ direction
    disc = along**2 - np.einsum("ij,ij->i", w, w) + diameter_mm**2
    # A disc only grazed, or touched while moving along its tangent, is not in the way.
    hits = np.flatnonzero((along > 1e-9) & (disc > 1e-9))
    if len(hits) == 0:
        return math.inf, -1
    gaps = along[hits] - np.sqrt(disc[hits])
    k = int(np.argmin(gaps))
    return max(0.0, float(gaps[k])), int(hits[k])


def slide(
    start_mm: np.ndarray, move_mm: np.ndarray, others_mm: np.ndarray, diameter_mm: float
) -> tuple[np.ndarray, bool]:
    """Where a disc that tries to move by ``move_mm`` ends up, sliding along the discs it
    touches instead of overlapping them; and whether it touched one.

    Up to three contacts per move: each time the disc goes to contact, the rest of the move
    loses its component into the disc it touched.

    Examples
    --------
    Driving at a disc off-centre slides around it (never closer than a diameter):

    >>> end, touched = slide(np.zeros(2), np.array([40.0, 0.0]), np.array([[40.0, 20.0]]), 33.0)
    >>> touched, bool(np.hypot(*(end - [40.0, 20.0])) >= 33.0 - 1e-9), bool(end[0] > 18.7)
    (True, True, True)
    """
    pos = np.array(start_mm, dtype=float)
    rest = np.array(move_mm, dtype=float)
    touched = False
    for _ in range(3):
        length = math.hypot(*rest)
        if length < 1e-12:
            break
        direction = rest / length
        free, k = contact_distance(pos, direction, others_mm, diameter_mm)
        if free >= length:
            pos += rest
            break
        touched = True
        pos += free * direction
        rest -= free * direction
        normal = pos - others_mm[k]
        normal /= math.hypot(*normal)
        into = rest @ normal
        if into < 0:
            rest -= into * normal
    return pos, touched


@dataclass(frozen=True)
class Calibration:
    """A robot's stored motor calibration (kilolib's EEPROM values), duty cycles 0-255."""

    turn_left: int
    turn_right: int
    straight_left: int
    straight_right: int


@dataclass
class MotorState:
    """One robot's motor commands and which motors run."""

    duty: tuple[int, int] = (0, 0)
    running: tuple[bool, bool] = (False, False)
    drive: tuple[float, float] = (0.0, 0.0)


class Motion:
    """Motor state and pose integration for all robots of a simulation.

    Parameters
    ----------
    params : MotionParams
        ``motion.*``.
    env : KernelEnvironment
        The run's clock.
    world : World
        The poses it moves (and the robots it checks for contact).
    trace : Trace
        Where poses are recorded.
    rng : numpy.random.Generator
        The ``motion`` stream (each robot's speed, turn rate, motor curves and calibration).

    The battery (motor time, the speed factor of a low battery) and the medium (links change
    when a robot moves) are connected afterwards with :meth:`connect`: programs read their
    calibration from here before those exist.
    """

    def __init__(
        self,
        params: MotionParams,
        env: KernelEnvironment,
        world: World,
        trace: Trace,
        rng: np.random.Generator,
    ) -> None:
        self.params = p = params
        self._env, self._world, self._trace = env, world, trace
        self._battery: Battery | None = None
        self._moved: Callable[[], None] = _unconnected
        n = len(world.positions_mm)
        self.speed_mm_s = p.speed_mm_s * np.clip(1 + rng.normal(0, p.speed_error, n), 0.1, None)
        self.turn_rad_s = np.radians(p.turn_deg_s) * np.clip(
            1 + rng.normal(0, p.turn_error, n), 0.1, None
        )
        # Motor curves, per robot and motor (left, right), and the calibration stored from them.
        self.offset = p.motor_offset + rng.normal(0.0, p.motor_offset_sd, (n, 2))
        self.gain = p.motor_gain * np.clip(1 + rng.normal(0.0, p.motor_gain_sd, (n, 2)), 0.1, None)
        best = self.offset + self.gain
        stored = np.clip(
            np.rint(best[:, None, :] + rng.normal(0, p.calibration_sd, (n, 2, 2))), 1, 255
        )
        self.calibrations = [
            Calibration(int(t[0]), int(t[1]), int(s[0]), int(s[1])) for t, s in stored.astype(int)
        ]
        angle = math.radians(p.pivot_angle_deg)
        self._pivot = (p.pivot_radius_mm * math.cos(angle), p.pivot_radius_mm * math.sin(angle))
        # The fastest a robot's centre can move, mm/s: forward, or on a pivot's arc.
        self._max_speed = (
            p.max_drive * np.maximum(self.speed_mm_s, self.turn_rad_s * p.pivot_radius_mm)
        ).tolist()
        self.motors = [MotorState() for _ in range(n)]
        self._last_update = [0.0] * n
        self._moving: set[int] = set()
        self._dirty = False  # a robot moved since the links were last rebuilt
        self._timer = Timer(env, self._tick, None)
        self._timer_on = False
        self._watchers: list[Callable[[int, int, int], None]] = []
        self.blocked_count = [0] * n

    def connect(self, battery: Battery, moved: Callable[[], None]) -> None:
        """Wire the battery it drains and ``moved()``, called after robots moved (the medium
        rebuilds its links)."""
        self._battery = battery
        self._moved = moved

    def pivot_rate_rad_s(self, robot: int, motor: int, duty: int) -> float:
        """How fast ``robot`` turns on one running motor (0 left, 1 right) at ``duty``, rad/s
        (ground truth: what an observer timing the robot would find; the battery aside)."""
        drive, _ = motor_drive(
            duty, self.offset[robot, motor], self.gain[robot, motor], True, self.params
        )
        return float(self.turn_rad_s[robot] * drive)

    def watch(self, listener: Callable[[int, int, int], None]) -> None:
        """Call ``listener(robot, left, right)`` on every motor command of a running robot
        (``spinup_motors()`` is ``255, 255``), before it takes effect; :mod:`kilonet.testing`
        records runs with it."""
        self._watchers.append(listener)

    def set_motors(self, robot: int, left: int, right: int) -> None:
        """Set the duty cycles of ``robot``'s motors; its pose is integrated up to now first."""
        if not self._world.running[robot]:
            return
        for listener in self._watchers:
            listener(robot, left, right)
        self._integrate(robot)
        state = self.motors[robot]
        drives, running = [], []
        for m, duty in enumerate((left, right)):
            a, runs = motor_drive(
                duty, self.offset[robot, m], self.gain[robot, m], state.running[m], self.params
            )
            drives.append(a)
            running.append(runs)
        state.duty, state.running, state.drive = (left, right), tuple(running), tuple(drives)
        if any(running):
            self._moving.add(robot)
            if not self._timer_on:
                self._timer_on = True
                self._timer.schedule(self.params.step_s)
        else:
            self._moving.discard(robot)

    def stop(self, robot: int) -> None:
        """Stop the motors of ``robot`` (it crashed, was removed or its battery died)."""
        self._integrate(robot)
        self.motors[robot] = MotorState()
        self._moving.discard(robot)

    def _tick(self, _timer: Timer) -> None:
        for robot in sorted(self._moving):
            self._integrate(robot)
        if self._dirty:
            self._dirty = False
            self._moved()
        if self._moving:
            self._timer.schedule(self.params.step_s)
        else:
            self._timer_on = False

    def _integrate(self, robot: int) -> None:
        now = self._env.now
        dt = now - self._last_update[robot]
        self._last_update[robot] = now
        state = self.motors[robot]
        if dt <= 0 or not any(state.running):
            return
        battery = self._battery
        battery.motor_s[robot] += dt * sum(state.running)
        factor = float(battery.motor_factor[robot])
        left, right = state.drive[0] * factor, state.drive[1] * factor
        world = self._world
        x, y = world.positions_mm[robot]
        h = float(world.heading_rad[robot])
        steps = max(1, math.ceil(dt / self.params.step_s - 1e-9))
        others = self._others(robot, dt)
        touched = False
        for _ in range(steps):
            nx_, ny_, h = pose_after(
                x,
                y,
                h,
                left,
                right,
                dt / steps,
                speed_mm_s=float(self.speed_mm_s[robot]),
                turn_rad_s=float(self.turn_rad_s[robot]),
                pivot_mm=self._pivot,
                drift_gain=self.params.drift_gain,
            )
            end, hit = slide(
                np.array([x, y]), np.array([nx_ - x, ny_ - y]), others, world.diameter_mm
            )
            touched |= hit
            x, y = float(end[0]), float(end[1])
        if touched:
            self.blocked_count[robot] += 1
        moved = (x, y) != tuple(world.positions_mm[robot])
        world.positions_mm[robot] = (x, y)
        world.heading_rad[robot] = h % (2 * math.pi)
        self._trace.pose(now, robot, x, y, world.heading_rad[robot])
        if moved:
            self._dirty = True

    def _others(self, robot: int, dt_s: float) -> np.ndarray:
        """Centres of the present robots that ``robot`` could touch within ``dt_s``."""
        world = self._world
        others = np.flatnonzero(world.present)
        others = others[others != robot]
        pos = world.positions_mm[others]
        reach = world.diameter_mm + 1e-6 + dt_s * self._max_speed[robot]
        return pos[np.hypot(*(pos - world.positions_mm[robot]).T) <= reach]

    def move_to(
        self,
        robot: int,
        heading_rad: float,
        target_mm: np.ndarray,
        on_arrival: Callable[[bool], None],
        *,
        drive_mm: float | None = None,
    ) -> None:
        """A closed-loop drive: turn in place to ``heading_rad`` at this robot's turn rate, then
        go straight to ``target_mm`` at its speed (the battery slows both); the motors run and
        drain the battery as they would. Another body on the way to the target stops the robot
        where it stands. ``drive_mm`` is how far the motors drive (default: to the target; a
        robot bumping into a wall drives without getting anywhere). ``on_arrival(moved)`` is
        called at the end.

        This is what a robot with a heading sensor and wall-following controller achieves (the
        maze hardware uses it); programs on plain Kilobots use :meth:`set_motors`.
        """
        world, env, trace, battery = self._world, self._env, self._trace, self._battery
        if not world.running[robot]:
            on_arrival(False)
            return
        self._integrate(robot)
        factor = float(battery.motor_factor[robot])
        turn = abs((heading_rad - world.heading_rad[robot] + math.pi) % (2 * math.pi) - math.pi)
        # A robot configured with no speed at all never gets there (1e-9: no division by zero).
        turn_s = turn / max(self.turn_rad_s[robot] * factor, 1e-9)
        start = world.positions_mm[robot].copy()
        distance = float(np.hypot(*(np.asarray(target_mm) - start)))
        driven = distance if drive_mm is None else drive_mm
        straight_s = driven / max(self.speed_mm_s[robot] * factor, 1e-9)
        trace.pose(env.now, robot, *start, world.heading_rad[robot])

        def turned(_t: Timer) -> None:
            if not world.running[robot]:
                on_arrival(False)
                return
            world.heading_rad[robot] = heading_rad % (2 * math.pi)
            battery.motor_s[robot] += turn_s  # one motor pivots
            trace.pose(env.now, robot, *world.positions_mm[robot], world.heading_rad[robot])
            Timer(env, arrived, None).schedule(straight_s)

        def arrived(_t: Timer) -> None:
            if not world.running[robot]:
                on_arrival(False)
                return
            battery.motor_s[robot] += 2 * straight_s  # both motors run
            direction = (np.asarray(target_mm) - start) / max(distance, 1e-12)
            free, _ = contact_distance(start, direction, self._all_others(robot), world.diameter_mm)
            moved = distance > 0 and free >= distance
            if moved:
                world.positions_mm[robot] = target_mm
                self._moved()
            trace.pose(env.now, robot, *world.positions_mm[robot], world.heading_rad[robot])
            on_arrival(moved)

        Timer(env, turned, None).schedule(turn_s)

    def _all_others(self, robot: int) -> np.ndarray:
        world = self._world
        others = np.flatnonzero(world.present)
        return world.positions_mm[others[others != robot]]


def _unconnected() -> None:
    raise RuntimeError("Motion.connect() was not called: nothing rebuilds the links")
