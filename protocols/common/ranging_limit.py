"""Which distance estimates a program may range with: kilolib's saturate beyond its tables.

A Kilobot hears other robots farther away than it can measure them. kilolib's
``estimate_distance`` interpolates the receiver's calibration tables, which end at
:data:`TABLES_END_MM` centre to centre (65 mm between the bodies); beyond them it extrapolates
the last segment while the readings approach their floor, so an estimate there grows ever more
slowly than the true distance and a far robot reads much nearer than it stands. A careful
program therefore takes an estimate above a limit of its own (a protocol parameter, at most
where the tables end) as "heard, distance unknown": it does not range with it, and treats the
sender as no neighbour of its geometry. Each protocol decides what else such a reception may
still tell it (an ID, a hop count).

:func:`trusted_range` is that rule, the one place the protocols apply it.
"""

from __future__ import annotations

__all__ = ["TABLES_END_MM", "trusted_range"]

#: Where kilolib's calibration tables end, centre to centre: 65 mm between the bodies plus the
#: 33 mm body diameter, mm.
TABLES_END_MM = 98.0


def trusted_range(distance_mm: float, max_mm: float) -> bool:
    """Whether a reception's distance estimate ``distance_mm`` may be ranged with, under a
    protocol's limit ``max_mm`` (both mm): estimates above the limit are not.

    Examples
    --------
    >>> trusted_range(85, 85.0), trusted_range(86, 85.0), trusted_range(116, 100.0)
    (True, False, False)
    """
    return distance_mm <= max_mm
