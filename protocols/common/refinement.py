"""Distributed refinement: every robot keeps improving its position from its neighbours'
broadcast positions and the distances both ends measured to each other.

The swarm minimises the stress ``Σ₍ᵢⱼ₎ (|pᵢ − pⱼ| − dᵢⱼ)²`` over all measured pairs, one robot
at a time: at each round a robot takes one Gauss–Newton step on its own terms of that sum,
holding its neighbours at the positions they last announced (:func:`gauss_newton_step`) — an
asynchronous block coordinate descent. Each step solves a 2 × 2 system in closed form (no numpy:
tiny arrays are slower than plain floats), down-weights residuals beyond ``huber_mm`` (a
neighbour announcing a wrong position pulls with a bounded force) and is capped at
``max_step_mm``. :class:`Refiner` adds a share of the previous step to each new one (heavy-ball
momentum): the slowest, longest-wavelength corrections of a block coordinate descent move every
robot a little the same way round after round, and momentum lets them build up.

**Symmetric distances.** The descent only moves downhill on a common objective if both ends of a
pair fit the same distance. Robot i averages what it receives from j, j what it receives from i:
two independent estimates of one distance. Robots therefore report their means to each other
(DIST) and both ends fit the mean of the two *reports* (:func:`agreed_range_mm`): i's last
report to j and j's last report to i, the same two numbers at both ends, however old. Each
report is about the neighbour whose mean moved farthest since the robot last reported it
(:func:`next_report`): with a report every few transmit periods and up to 18 neighbours, a plain
turn would reach each neighbour about once a run.

::

    DIST (83)  sender:uint16  x:int16  y:int16 (0.1 mm)  neighbour:uint16  distance:uint8
                                                                                   9 bytes

DIST carries the sender's position too, so it squeezes the distance into one byte: tenths of a
millimetre modulo 256 (a 25.6 mm cycle, :func:`distance_code`). The neighbour it is about
measured the same distance itself and takes the value of that cycle nearest to its own mean
(:func:`unwrap_distance`): a 0.1 mm resolution as long as the two means differ by less than
12.8 mm.

**Settling.** A robot is *settled* when, over its last ``settle_rounds`` rounds, it moved less
than ``settle_mm`` (:class:`SettleWindow`): the displacement over a window rather than the last
step, because the slow corrections move every robot a little at every step, and the announced
positions' 0.1 mm rounding makes single steps jitter. A program with a hop structure can climb
settledness back to a root (``localize`` does,
:mod:`kilonet.protocols.localize.phase3_termination`); one without stops a robot when it and every
neighbour it refines against are settled (:func:`neighbourhood_settled`).

Nothing here knows a protocol: give it positions and distances, in any frame. ``localize`` runs
it on every located robot (:mod:`kilonet.protocols.localize.program`), the thesis pipeline as a last
phase on its merged estimates (:mod:`kilonet.protocols.gcs.phase7_refinement`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from typing import Protocol

from kilonet.message import Layout

__all__ = [
    "DIST",
    "DISTANCE_CYCLE_MM",
    "DISTANCE_STEP_MM",
    "Refiner",
    "ReportRecord",
    "SettleWindow",
    "agreed_range_mm",
    "distance_code",
    "gauss_newton_step",
    "neighbourhood_settled",
    "next_report",
    "unwrap_distance",
]

#: Neighbours closer than this to the robot's estimate give no direction and are skipped, mm.
_COINCIDENT_MM = 1e-6
#: One step of the DIST distance code, and its cycle, mm.
DISTANCE_STEP_MM = 0.1
DISTANCE_CYCLE_MM = 256 * DISTANCE_STEP_MM

DIST = Layout(
    "dist",
    type=83,
    fields=[
        ("sender", "H"),
        ("x_mm", "h", 0.1),
        ("y_mm", "h", 0.1),
        ("neighbour", "H"),
        ("distance", "B"),
    ],
)


def distance_code(distance_mm: float) -> int:
    """A mean distance as DIST's one-byte code (tenths of a mm, modulo 256).

    Examples
    --------
    >>> distance_code(40.0), distance_code(65.6), distance_code(25.6)
    (144, 144, 0)
    """
    return round(distance_mm / DISTANCE_STEP_MM) % 256


def unwrap_distance(code: int, near_mm: float) -> float:
    """The distance with DIST code ``code`` nearest to ``near_mm``, mm.

    Examples
    --------
    >>> round(unwrap_distance(distance_code(61.37), near_mm=60.2), 6)
    61.4
    >>> round(unwrap_distance(distance_code(61.37), near_mm=49.0), 6)  # 12.4 mm off: still
    61.4
    >>> round(unwrap_distance(distance_code(61.37), near_mm=48.0), 6)  # 13.4 mm off: next cycle
    35.8
    """
    base = code * DISTANCE_STEP_MM
    return base + round((near_mm - base) / DISTANCE_CYCLE_MM) * DISTANCE_CYCLE_MM


def agreed_range_mm(own_mm: float, sent_mm: float | None, reported_mm: float | None) -> float:
    """The distance to a neighbour that both ends fit, mm: the mean of this robot's last report
    to it (``sent_mm``, as the neighbour decoded it) and the neighbour's last report to this
    robot (``reported_mm``); this robot's own mean ``own_mm`` stands in for a report not made or
    not heard yet.

    Examples
    --------
    >>> agreed_range_mm(50.25, None, None), agreed_range_mm(50.25, None, 50.75)
    (50.25, 50.5)
    >>> agreed_range_mm(50.25, 49.75, 50.75)  # the two reports: what the other end fits too
    50.25
    """
    if reported_mm is None:
        return own_mm
    return 0.5 * ((own_mm if sent_mm is None else sent_mm) + reported_mm)


class ReportRecord(Protocol):
    """What :func:`next_report` reads of a neighbour record."""

    uid: int
    samples: int
    ambiguous: bool
    sent_mm: float | None
    sent_round: int

    @property
    def mean_mm(self) -> float: ...


def next_report(records: Iterable[ReportRecord]) -> ReportRecord | None:
    """The neighbour to report next: the largest change of this robot's mean since its last
    report, in DIST's 0.1 mm steps (never reported: first), then the oldest report, then the
    smallest ID; None without an unambiguous neighbour.

    Examples
    --------
    >>> from types import SimpleNamespace as Record
    >>> a, b, c = (Record(uid=u, samples=1, ambiguous=False, mean_mm=m, sent_mm=None,
    ...                   sent_round=-1) for u, m in ((1, 40.0), (2, 50.0), (3, 60.0)))
    >>> next_report([a, b, c]).uid  # none reported yet: the smallest ID
    1
    >>> a.sent_mm, a.sent_round = 40.0, 7
    >>> b.sent_mm, b.sent_round = 49.7, 5  # b's mean moved 0.3 mm since
    >>> next_report([a, b, c]).uid, next_report([a, b]).uid
    (3, 2)
    >>> b.sent_mm = 50.02  # less than a step: the older report goes first
    >>> next_report([a, b]).uid
    2
    """
    best, best_key = None, None
    for n in records:
        if n.ambiguous or n.samples == 0:
            continue
        sent = n.sent_mm
        steps = math.inf if sent is None else round(abs(n.mean_mm - sent) / DISTANCE_STEP_MM)
        key = (steps, -n.sent_round, -n.uid)
        if best_key is None or key > best_key:
            best, best_key = n, key
    return best


def gauss_newton_step(
    x_mm: float,
    y_mm: float,
    links: Iterable[tuple[float, float, float]],
    *,
    huber_mm: float,
    max_step_mm: float,
    fix_y: bool = False,
) -> tuple[float, float, float]:
    """One robust Gauss–Newton step of a robot's position against its neighbours.

    Parameters
    ----------
    x_mm, y_mm : float
        The robot's current estimate, mm.
    links : iterable of (x_mm, y_mm, distance_mm)
        Each neighbour's announced position and the distance to it.
    huber_mm : float
        Residuals up to this count fully; a larger residual r counts with weight
        ``huber_mm / |r|`` (Huber's loss), mm.
    max_step_mm : float
        The step is shortened to at most this length, mm.
    fix_y : bool
        Move along x only (the frame's axis robot, whose y is 0 by definition).

    Returns
    -------
    x_mm, y_mm : float
        The new estimate; the old one if the neighbours do not determine a step (fewer than
        two directions, or one along the fixed axis only).
    rms_mm : float
        Root mean square of the residuals ``|p − pⱼ| − dⱼ`` at the old estimate (NaN without
        links).

    Examples
    --------
    Three neighbours around the truth (30, 20); from (31, 19) one step lands within 0.05 mm:

    >>> links = [(0.0, 0.0, math.hypot(30, 20)), (60.0, 0.0, math.hypot(30, 20)),
    ...          (30.0, 60.0, 40.0)]
    >>> x, y, rms = gauss_newton_step(31.0, 19.0, links, huber_mm=3.0, max_step_mm=5.0)
    >>> round(x, 1), round(y, 1), round(rms, 3)
    (30.0, 20.0, 1.006)
    >>> x, y, _ = gauss_newton_step(31.0, 19.0, links, huber_mm=3.0, max_step_mm=0.5)
    >>> round(math.hypot(x - 31.0, y - 19.0), 9)
    0.5
    >>> gauss_newton_step(31.0, 19.0, links[:1], huber_mm=3.0, max_step_mm=5.0)[:2]
    (31.0, 19.0)
    """
    hxx = hxy = hyy = gx = gy = sq = 0.0
    count = 0
    for nx_mm, ny_mm, d_mm in links:
        dx, dy = x_mm - nx_mm, y_mm - ny_mm
        r = math.sqrt(dx * dx + dy * dy)
        if r < _COINCIDENT_MM:
            continue
        res = r - d_mm
        sq += res * res
        count += 1
        w = 1.0 if abs(res) <= huber_mm else huber_mm / abs(res)
        ux, uy = dx / r, dy / r
        wux, wuy = w * ux, w * uy
        hxx += wux * ux
        hxy += wux * uy
        hyy += wuy * uy
        gx += wux * res
        gy += wuy * res
    if count == 0:
        return x_mm, y_mm, math.nan
    rms = math.sqrt(sq / count)
    if fix_y:
        if hxx <= 1e-9:
            return x_mm, y_mm, rms
        sx, sy = -gx / hxx, 0.0
    else:
        det = hxx * hyy - hxy * hxy
        if det <= 1e-9 * (hxx + hyy) ** 2:
            return x_mm, y_mm, rms
        sx = (-gx * hyy + gy * hxy) / det
        sy = (-gy * hxx + gx * hxy) / det
    length = math.hypot(sx, sy)
    if length > max_step_mm:
        sx, sy = sx * max_step_mm / length, sy * max_step_mm / length
    return x_mm + sx, y_mm + sy, rms


class SettleWindow:
    """Whether a position has stopped moving: less than ``settle_mm`` over the last
    ``rounds`` rounds.

    Examples
    --------
    >>> w = SettleWindow(settle_mm=0.1, rounds=3)
    >>> [w.add(x, 0.0) for x in (0.0, 0.5, 0.52, 0.54, 0.56)]
    [False, False, False, False, True]
    >>> w.add(0.8, 0.0), w.settled
    (False, False)
    """

    __slots__ = ("_history", "rounds", "settle_mm", "settled")

    def __init__(self, *, settle_mm: float, rounds: int) -> None:
        self.settle_mm = settle_mm
        self.rounds = rounds
        self._history: deque[tuple[float, float]] = deque(maxlen=rounds + 1)
        self.settled = False

    def add(self, x_mm: float, y_mm: float) -> bool:
        """Record this round's position; return whether the robot is settled now."""
        history = self._history
        history.append((x_mm, y_mm))
        if len(history) <= self.rounds:
            self.settled = False
        else:
            x0, y0 = history[0]
            self.settled = math.hypot(x_mm - x0, y_mm - y0) < self.settle_mm
        return self.settled

    def reset(self) -> None:
        """Forget the history (the position was replaced, not refined)."""
        self._history.clear()
        self.settled = False


class Refiner:
    """One robot's refinement: robust Gauss–Newton steps with heavy-ball momentum, and whether
    the position has settled.

    Each round the step is the Gauss–Newton step (:func:`gauss_newton_step`) plus ``momentum``
    times the previous step, capped at ``max_step_mm``. Momentum below 1 keeps the iteration
    stable (for a synchronous Jacobi iteration, any momentum in [0, 1) is); it speeds up the
    corrections that keep one direction round after round and averages out those that flip.

    Parameters
    ----------
    huber_mm, max_step_mm : float
        As in :func:`gauss_newton_step`, mm.
    momentum : float
        Share of the previous step added to each new one (0: plain Gauss–Newton).
    settle_mm, settle_rounds
        As in :class:`SettleWindow`.

    Examples
    --------
    A robot between four fixed neighbours at exact distances reaches the truth (30, 20); one
    Gauss–Newton step nearly lands there, and momentum overshoots a little before it settles:

    >>> links = [(0.0, 0.0, math.hypot(30, 20)), (60.0, 0.0, math.hypot(30, 20)),
    ...          (30.0, 60.0, 40.0), (0.0, 40.0, math.hypot(30, 20))]
    >>> r = Refiner(huber_mm=3.0, max_step_mm=5.0, momentum=0.5, settle_mm=0.01, settle_rounds=3)
    >>> x, y = 35.0, 15.0
    >>> for _ in range(40):
    ...     x, y = r.step(x, y, links)
    >>> round(x, 3), round(y, 3), r.settled
    (30.0, 20.0, True)
    """

    __slots__ = ("_step", "huber_mm", "max_step_mm", "momentum", "settle")

    def __init__(
        self,
        *,
        huber_mm: float,
        max_step_mm: float,
        momentum: float,
        settle_mm: float,
        settle_rounds: int,
    ) -> None:
        self.huber_mm = huber_mm
        self.max_step_mm = max_step_mm
        self.momentum = momentum
        self.settle = SettleWindow(settle_mm=settle_mm, rounds=settle_rounds)
        self._step = (0.0, 0.0)

    @property
    def settled(self) -> bool:
        """Whether the position moved less than ``settle_mm`` over the last rounds."""
        return self.settle.settled

    def step(
        self,
        x_mm: float,
        y_mm: float,
        links: Iterable[tuple[float, float, float]],
        *,
        fix_y: bool = False,
        origin: tuple[float, float] = (0.0, 0.0),
    ) -> tuple[float, float]:
        """This round's new position from ``(x_mm, y_mm)`` and the neighbours' ``links``
        (announced x, y and distance, mm); ``fix_y`` moves along x only. The settle test
        measures the position relative to ``origin`` (mm): in a frame that nothing anchors,
        the neighbours' centroid, so that the whole neighbourhood drifting together counts
        as settled."""
        gx, gy, _ = gauss_newton_step(
            x_mm, y_mm, links, huber_mm=self.huber_mm, max_step_mm=self.max_step_mm, fix_y=fix_y
        )
        px, py = self._step
        sx = gx - x_mm + self.momentum * px
        sy = 0.0 if fix_y else gy - y_mm + self.momentum * py
        length = math.hypot(sx, sy)
        if length > self.max_step_mm:
            sx, sy = sx * self.max_step_mm / length, sy * self.max_step_mm / length
        self._step = (sx, sy)
        x, y = x_mm + sx, y_mm + sy
        self.settle.add(x - origin[0], y - origin[1])
        return x, y

    def hold(self, x_mm: float, y_mm: float) -> None:
        """This round the position stays where it is (a robot that fixes the frame)."""
        self._step = (0.0, 0.0)
        self.settle.add(x_mm, y_mm)

    def reset(self) -> None:
        """The position was replaced, not refined: forget the last step and the history."""
        self._step = (0.0, 0.0)
        self.settle.reset()


def neighbourhood_settled(settled: bool, neighbours_settled: Iterable[bool]) -> bool:
    """The stopping rule of a refinement without a hop structure: a robot may stop once it and
    every neighbour it refines against are settled (a robot with no such neighbour: once it is).

    Examples
    --------
    >>> neighbourhood_settled(True, [True, True]), neighbourhood_settled(True, [True, False])
    (True, False)
    >>> neighbourhood_settled(False, []), neighbourhood_settled(True, [])
    (False, True)
    """
    return settled and all(neighbours_settled)
