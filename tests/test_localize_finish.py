"""The settled wave's stillness rule: a placed robot counts for the wave when its mean
position has stopped moving over ``still_rounds``, however much it jitters, and not while a
slow drift carries it (protocols/localize/phase3_termination.py)."""

from __future__ import annotations

import math

import numpy as np

from kilonet.protocols.localize.phase3_termination import centre_drift_mm, settled_at

ROUNDS = 10
SPAN = 40
SETTLE_MM = 0.5
UNSETTLE_MM = 1.5


def _still_rounds(track: np.ndarray) -> list[bool]:
    """Round by round, whether a robot moving along ``track`` (k, 2) counts as still: the
    drift test of its mean with the settle hysteresis on that mean, as Termination runs it."""
    anchor, out, seen = None, [], []
    for position in map(tuple, track):
        seen.append(position)
        drift, centre = centre_drift_mm(seen, ROUNDS, SPAN)
        anchor = (
            None if centre is None else settled_at(anchor, centre, drift < SETTLE_MM, UNSETTLE_MM)
        )
        out.append(anchor is not None)
    return out


def test_a_robot_that_jitters_about_a_point_is_still_and_stays_so():
    # 3 mm of jitter round by round: the settle test's window (0.5 mm over 10 rounds) fails
    # in most rounds; the mean over 10 rounds moves by about 1 mm / sqrt(10) * sqrt(2).
    rng = np.random.default_rng(1)
    track = np.array([100.0, -40.0]) + rng.normal(0.0, 1.0, (200, 2))
    window = [math.dist(track[k], track[k - ROUNDS]) < SETTLE_MM for k in range(ROUNDS, len(track))]
    assert np.mean(window) < 0.2
    still = _still_rounds(track)
    assert not any(still[: SPAN - 1])  # not before the span is recorded
    assert all(still[SPAN:])


def test_a_robot_that_drifts_slowly_is_never_still_though_the_settle_test_passes():
    # 0.02 mm a round (0.1 mm/s, a ring's slow bend): 0.2 mm over the settle test's 10
    # rounds, which it passes; the mean moves 0.6 mm over the span, which it does not.
    track = np.column_stack([0.02 * np.arange(300), np.zeros(300)])
    assert all(
        math.dist(track[k], track[k - ROUNDS]) < SETTLE_MM for k in range(ROUNDS, len(track))
    )
    assert not any(_still_rounds(track))
    # Slower than settle_mm over the span it is still.
    assert all(_still_rounds(track / 2.0)[SPAN:])


def test_a_robot_that_starts_moving_again_is_no_longer_still():
    # Still at the origin, then it walks off at 1 mm a round: still no longer within two
    # rounds of its mean leaving the hysteresis radius.
    track = np.vstack([np.zeros((60, 2)), np.column_stack([np.arange(1.0, 41.0), np.zeros(40)])])
    still = _still_rounds(track)
    assert all(still[SPAN:60])
    assert not any(still[65:])


def test_the_drift_needs_a_span_of_positions():
    assert centre_drift_mm([(0.0, 0.0)] * (SPAN - 1), ROUNDS, SPAN) == (math.inf, None)
    drift, centre = centre_drift_mm([(1.0, 2.0)] * SPAN, ROUNDS, SPAN)
    assert drift == 0.0 and centre == (1.0, 2.0)
