"""The follower seed's three frame robots (robots 1, 2, 3) and the message they share.

Robot 1 (:class:`Origin`) is the frame's origin, robot 2 (:class:`XAxisRobot`) lies on its +x axis
and robot 3 (:class:`ThirdRobot`) above it; each announces what it knows in a FRAME message
(:func:`encode`, :func:`decode`), from which the follower
(:mod:`kilonet.protocols.follower.follower`) trilaterates itself. The layouts are in
:mod:`kilonet.protocols.follower.follower`'s docstring.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from kilonet.message import Layout, Message
from kilonet.protocols.common.geometry import (
    GeometryError,
    place_references,
)
from kilonet.robot import Kilobot

ORIGIN, X_AXIS, THIRD, FOLLOWER = 1, 2, 3, 4

FRAME_BYTE = Layout(
    "trilateration",
    type=8,
    fields=[
        ("sender", "B"),
        ("known", "B"),
        ("x_mm", "b"),
        ("y_mm", "B"),
        ("d12_mm", "B"),
        ("d13_mm", "B"),
        ("d23_mm", "B"),
    ],
)
FRAME_WIDE = Layout(
    "trilateration_wide",
    type=9,
    fields=[
        ("sender", "B"),
        ("known", "B"),
        ("x_mm", "h", 0.1),
        ("y_mm", "h", 0.1),
        ("d12_mm", "H", 0.1),
    ],
)

Point = tuple[float, float]

#: Physical turns (counter-clockwise positive, rad) of successive escapes from a body the
#: robot is stuck against: round first, then sideways.


# ------------------------------------------------------------------------------ the message


class FrameReport(NamedTuple):
    """What a frame robot says about itself (mm); zeros where it has nothing to say."""

    sender: int
    known: bool
    x_mm: float = 0.0
    y_mm: float = 0.0
    d12_mm: float = 0.0
    d13_mm: float = 0.0
    d23_mm: float = 0.0


def encode(report: FrameReport, *, wide: bool = False) -> Message:
    """Pack a report into the byte layout (the seed's table) or the 16-bit variant.

    Raises
    ------
    kilonet.message.PayloadError
        If a value does not fit its field (e.g. ``x_mm`` beyond −128..127 in the byte layout).

    Examples
    --------
    >>> msg = encode(FrameReport(3, True, -12.4, 55.6, 70.0, 56.9, 80.2))
    >>> list(msg.data), msg.type
    ([3, 1, 244, 56, 70, 57, 80], 8)
    >>> decode(msg)
    FrameReport(sender=3, known=True, x_mm=-12, y_mm=56, d12_mm=70, d13_mm=57, d23_mm=80)
    """
    if wide:
        return FRAME_WIDE.pack(
            sender=report.sender,
            known=int(report.known),
            x_mm=report.x_mm,
            y_mm=report.y_mm,
            d12_mm=report.d12_mm,
        )
    return FRAME_BYTE.pack(
        sender=report.sender,
        known=int(report.known),
        x_mm=round(report.x_mm),
        y_mm=round(report.y_mm),
        d12_mm=round(report.d12_mm),
        d13_mm=round(report.d13_mm),
        d23_mm=round(report.d23_mm),
    )


def decode(message: Message) -> FrameReport | None:
    """Read a frame robot's report from either layout; ``None`` for other messages.

    The 16-bit variant carries no d13 and d23; for robot 3 they are recomputed from X, Y and
    d12 (exact up to the 0.1 mm storage).

    Examples
    --------
    >>> r = decode(encode(FrameReport(3, True, -12.34, 55.61, 70.02), wide=True))
    >>> [round(v, 2) for v in r[2:5]]
    [-12.3, 55.6, 70.0]
    >>> round(r.d13_mm, 2), round(r.d23_mm, 2)
    (56.94, 99.32)
    >>> decode(Message(b"\\x01", 1)) is None
    True
    """
    if FRAME_BYTE.matches(message):
        m = FRAME_BYTE.unpack(message)
        return FrameReport(m.sender, bool(m.known), m.x_mm, m.y_mm, m.d12_mm, m.d13_mm, m.d23_mm)
    if FRAME_WIDE.matches(message):
        m = FRAME_WIDE.unpack(message)
        d13 = d23 = 0.0
        if m.sender == THIRD:
            d13 = math.hypot(m.x_mm, m.y_mm)
            d23 = math.hypot(m.x_mm - m.d12_mm, m.y_mm)
        return FrameReport(m.sender, bool(m.known), m.x_mm, m.y_mm, m.d12_mm, d13, d23)
    return None


# ------------------------------------------------------------------------- frame robots


class _FrameMember(Kilobot):
    """Common part of robots 1–3: broadcast the report, blink the seed's colours.

    Parameters
    ----------
    samples : int
        Distance readings averaged before a robot flags its coordinates.
    wide : bool
        Send the 16-bit variant of the message instead of the byte layout.
    blink_s : float
        How long the LED stays on after a send or a reception, s.
    """

    role = 0
    tx_color = (0, 0, 0)

    def __init__(self, *, samples: int = 8, wide: bool = False, blink_s: float = 0.1) -> None:
        self.samples = samples
        self.wide = wide
        self.blink_s = blink_s

    def setup(self) -> None:
        self.known = False
        self.x_mm = self.y_mm = 0.0
        self.d12_mm = self.d13_mm = self.d23_mm = 0.0
        self._message: Message | None = None
        self._led_off_tick = 0

    def report(self) -> FrameReport:
        """What this robot currently broadcasts."""
        return FrameReport(
            self.role, self.known, self.x_mm, self.y_mm, self.d12_mm, self.d13_mm, self.d23_mm
        )

    def message_tx(self) -> Message | None:
        if self._message is None:
            self._message = encode(self.report(), wide=self.wide)
        return self._message

    def message_tx_success(self) -> None:
        self._blink(self.tx_color)

    def _blink(self, color: tuple[int, int, int]) -> None:
        self.set_color(*color)
        self._led_off_tick = self.kilo_ticks + max(1, round(self.blink_s * self.ticks_per_s))

    def loop(self) -> None:
        if self.color != (0, 0, 0) and self.kilo_ticks >= self._led_off_tick:
            self.set_color(0, 0, 0)

    def _set_known(self) -> None:
        self.known = True
        self._message = None
        self.log("frame", x_mm=self.x_mm, y_mm=self.y_mm, d12_mm=self.d12_mm)


class Origin(_FrameMember):
    """Robot 1, the frame's origin: coordinates (0, 0) from the start; white on send."""

    LED_KEY = (((3, 3, 3), "robot 1 (origin) sending"),)

    role = ORIGIN
    tx_color = (3, 3, 3)

    def setup(self) -> None:
        super().setup()
        self.known = True


class XAxisRobot(_FrameMember):
    """Robot 2, on the frame's +x axis: (d12, 0) once it has averaged ``samples`` readings of
    robot 1. Blue on send, yellow on handling a message from the origin."""

    LED_KEY = (((0, 0, 3), "robot 2 sending"), ((3, 3, 0), "heard robot 1"))

    role = X_AXIS
    tx_color = (0, 0, 3)

    def setup(self) -> None:
        super().setup()
        self._from_origin: list[int] = []

    def message_rx(self, message: Message, distance_mm: int) -> None:
        report = decode(message)
        if report is None or report.sender != ORIGIN:
            return
        self._blink((3, 3, 0))
        if self.known:
            return
        self._from_origin.append(distance_mm)
        if len(self._from_origin) >= self.samples:
            self.d12_mm = sum(self._from_origin) / len(self._from_origin)
            self.x_mm = self.d12_mm
            self._set_known()


class ThirdRobot(_FrameMember):
    """Robot 3: ``(x3, y3)`` from d12 (robot 2's flagged report) and its own averaged readings
    of robots 1 and 2 (the seed's triangle equations). Green on send, yellow on a message from
    robot 1, purple on one from robot 2."""

    LED_KEY = (
        ((0, 3, 0), "robot 3 sending"),
        ((3, 3, 0), "heard robot 1"),
        ((3, 0, 3), "heard robot 2"),
    )

    role = THIRD
    tx_color = (0, 3, 0)

    def setup(self) -> None:
        super().setup()
        self._from: dict[int, list[int]] = {ORIGIN: [], X_AXIS: []}

    def message_rx(self, message: Message, distance_mm: int) -> None:
        report = decode(message)
        if report is None or report.sender not in self._from:
            return
        self._blink((3, 3, 0) if report.sender == ORIGIN else (3, 0, 3))
        if self.known:
            return
        readings = self._from[report.sender]
        if len(readings) < self.samples:
            readings.append(distance_mm)
        if report.sender == X_AXIS and report.known:
            self.d12_mm = report.d12_mm
        if self.d12_mm > 0 and all(len(r) >= self.samples for r in self._from.values()):
            d13 = sum(self._from[ORIGIN]) / self.samples
            d23 = sum(self._from[X_AXIS]) / self.samples
            try:
                _, (self.x_mm, self.y_mm) = place_references(self.d12_mm, d13, d23)
            except GeometryError as exc:
                # Readings that form no triangle (or put robot 3 within 1 mm of the 1→2
                # axis, too close to tell its side): start over with fresh ones.
                self.log("frame_rejected", reason=str(exc))
                self._from = {ORIGIN: [], X_AXIS: []}
                return
            self.d13_mm, self.d23_mm = d13, d23
            self._set_known()
