"""Distributed refinement: every robot keeps improving its position from its neighbours'
broadcast positions and the distances it measured to them.

The swarm minimises the stress ``Σ₍ᵢⱼ₎ (|pᵢ − pⱼ| − dᵢⱼ)²`` over all measured pairs, one robot
at a time: at each round a robot takes one Gauss–Newton step on its own terms of that sum,
holding its neighbours at the positions they last announced (:func:`gauss_newton_step`) — an
asynchronous block coordinate descent, which only moves downhill on the common objective as
long as both ends of a pair fit the same distance (hence the symmetric distances of
:mod:`protocols.localize_base`). Each step solves a 2 × 2 system in closed form (no numpy:
tiny arrays are slower than plain floats), down-weights residuals beyond ``huber_mm`` (a
neighbour announcing a wrong position pulls with a bounded force) and is capped at
``max_step_mm``.

A robot is *settled* when, over its last ``settle_rounds`` rounds, it moved less than
``settle_mm`` (:class:`SettleWindow`): the displacement over a window rather than the last
step, because the slowest, longest-wavelength corrections move every robot a little at every
step, and the announced positions' 0.1 mm rounding makes single steps jitter.

Nothing here knows a protocol: give it positions and distances, in any frame. ``localize``
runs it on every located robot (:mod:`protocols.localize`); it is written so that the
thesis pipeline can run it as a last phase on its merged estimates too.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable

__all__ = ["SettleWindow", "gauss_newton_step"]

#: Neighbours closer than this to the robot's estimate give no direction and are skipped, mm.
_COINCIDENT_MM = 1e-6


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
