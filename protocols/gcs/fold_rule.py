"""Deciding, on one settled robot, whether its own global position is a fold in its frame, and
what to do about it: a pure rule (issue 46, item 3), with no state and no messages.

The split check (:mod:`kilonet.protocols.gcs.split_detection`) compares each settled
same-frame neighbour's broadcast position with the distance this robot measures to it. A bad
fix shows there as one robot inconsistent with most of its neighbours, while each of those
neighbours is inconsistent with that one robot only. So the robot that acts is the one
inconsistent with a **majority**, and at least two, of the settled same-frame neighbours it
compared (:func:`is_outlier`): with the rule on every robot, the neighbours of a bad fix keep
their positions (one disagreement in several is no majority) and the bad fix moves.

Its repair (:func:`refit`): drop its own position and multilaterate a new one from those
neighbours' positions and its own measured distances
(:func:`kilonet.protocols.common.geometry.multilaterate`, with its collinearity, residual and
mirror checks). A refit whose residual exceeds the check's tolerance would still disagree with
them: then the robot cannot be placed in the frame consistently and leaves it (a split).
With fewer than three neighbours compared the robot does neither: two circles meet in two
points, so a position that fits them exists but is ambiguous, and "no point fits" cannot be
said. :func:`fold_decision` puts the two together, with the confirm time: a disagreement must
last before the robot acts, as the check's flags clear when merging moves the frame.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from kilonet.protocols.common.geometry import multilaterate

__all__ = ["MIN_ANCHORS", "FoldDecision", "fold_decision", "is_outlier", "refit"]

#: Neighbours a refit needs, and the rule needs before it acts (see the module docstring).
MIN_ANCHORS = 3


def is_outlier(mismatches_mm: Mapping[int, float], tolerance_mm: float) -> bool:
    """Whether a robot whose distances to its settled same-frame neighbours differ from the
    measured ones by ``mismatches_mm`` (neighbour ID → |computed − measured|, mm, every
    neighbour compared) is the outlier: the mismatch exceeds ``tolerance_mm`` for more than
    half of them, and for at least two.

    Examples
    --------
    >>> is_outlier({1: 30.0, 2: 25.0, 3: 2.0}, 8.0)
    True
    >>> is_outlier({1: 30.0, 2: 1.0, 3: 2.0}, 8.0)  # one disagreement in three: a neighbour's
    False
    >>> is_outlier({1: 30.0}, 8.0)  # one neighbour cannot outvote this robot
    False
    """
    bad = sum(m > tolerance_mm for m in mismatches_mm.values())
    return bad >= 2 and 2 * bad > len(mismatches_mm)


def refit(
    anchors: Mapping[int, tuple[float, float, float]], *, tolerance_mm: float, sigma_mm: float
) -> tuple[float, float] | None:
    """A new global position from neighbours' positions and measured distances, mm, or
    ``None`` if it cannot be had consistently.

    Parameters
    ----------
    anchors : Mapping[int, tuple[float, float, float]]
        Neighbour ID → ``(x_mm, y_mm, measured_mm)``: its broadcast position and the distance
        this robot measures to it.
    tolerance_mm : float
        The split check's tolerance: the fit's residual RMSE must stay within it, or the
        refit position would be flagged again.
    sigma_mm : float
        Ranging error assumed (sets the collinearity and mirror checks).

    Examples
    --------
    >>> square = {1: (0.0, 0.0, 50.0), 2: (60.0, 0.0, 50.0), 3: (30.0, 60.0, 20.0)}
    >>> [round(c, 1) for c in refit(square, tolerance_mm=8.0, sigma_mm=2.5)]
    [30.0, 40.0]
    >>> refit(dict(list(square.items())[:2]), tolerance_mm=8.0, sigma_mm=2.5) is None
    True
    """
    if len(anchors) < MIN_ANCHORS:
        return None
    uids = sorted(anchors)
    xy = np.array([anchors[u][:2] for u in uids], dtype=float)
    ranges = np.array([anchors[u][2] for u in uids], dtype=float)
    fix = multilaterate(xy, ranges, sigma_mm=sigma_mm, max_rmse_mm=tolerance_mm)
    return (fix.x_mm, fix.y_mm) if fix.ok else None


@dataclass(frozen=True, slots=True)
class FoldDecision:
    """What :func:`fold_decision` decided.

    Attributes
    ----------
    action : str
        ``"keep"`` (not the outlier, or too few neighbours to act on), ``"wait"`` (the
        outlier, not yet for the confirm time),
        ``"repair"`` (take ``position``) or ``"split"`` (leave the frame).
    position : tuple[float, float] or None
        The refit position, mm (``"repair"`` only).
    """

    action: Literal["keep", "wait", "repair", "split"]
    position: tuple[float, float] | None = None


def fold_decision(
    anchors: Mapping[int, tuple[float, float, float]],
    mismatches_mm: Mapping[int, float],
    *,
    outlier_for_s: float | None,
    confirm_s: float,
    tolerance_mm: float,
    sigma_mm: float,
) -> FoldDecision:
    """The rule on one settled robot.

    Parameters
    ----------
    anchors : Mapping[int, tuple[float, float, float]]
        Settled same-frame neighbours: ID → ``(x_mm, y_mm, measured_mm)``.
    mismatches_mm : Mapping[int, float]
        The split check's comparison with each of them, mm (:func:`is_outlier`).
    outlier_for_s : float or None
        How long the robot has been the outlier without interruption, s (``None``: it is not).
    confirm_s : float
        How long it must have been before it acts, s.
    tolerance_mm, sigma_mm : float
        As :func:`refit` takes them.

    Examples
    --------
    >>> near = {1: (0.0, 0.0, 50.0), 2: (60.0, 0.0, 50.0), 3: (30.0, 60.0, 40.0)}
    >>> bad = {1: 1.0, 2: 30.0, 3: 40.0}
    >>> fold_decision(near, bad, outlier_for_s=5.0, confirm_s=10.0, tolerance_mm=8.0,
    ...               sigma_mm=2.5).action
    'wait'
    >>> fold_decision(near, bad, outlier_for_s=12.0, confirm_s=10.0, tolerance_mm=8.0,
    ...               sigma_mm=2.5).action  # 50, 50 and 40 mm fit no point: it leaves
    'split'
    """
    if len(anchors) < MIN_ANCHORS or not is_outlier(mismatches_mm, tolerance_mm):
        return FoldDecision("keep")
    if outlier_for_s is None or outlier_for_s < confirm_s:
        return FoldDecision("wait")
    position = refit(anchors, tolerance_mm=tolerance_mm, sigma_mm=sigma_mm)
    return FoldDecision("split") if position is None else FoldDecision("repair", position)
