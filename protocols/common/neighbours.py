"""What a robot knows about its neighbours: their IDs and distances, as heard.

Every message of both localization protocols (``gcs``, ``localize``) starts with the sender's
ID, so each reception adds a distance sample to the sender's :class:`Neighbour` record; the
record's mean averages the ranging noise down, and its sum of squares gives the spread of the
samples (:meth:`NeighbourTable.noise_mm`). Only the robot's own receptions feed it.

One table serves both programs (:class:`NeighbourTable`); ``localize`` subclasses the record
for what else it learns about each neighbour (:class:`kilonet.protocols.localize.base.Neighbour`).
The table can also

* age its records: each reception stamps the robot's round, and :meth:`NeighbourTable.fresh`
  leaves out those silent for ``stale_rounds`` rounds (``localize``);
* tell two robots sharing an ID: a sample farther than ``duplicate_mm`` from its ID's mean
  marks the record ambiguous, and the table ignores it from then on (``localize``; ``gcs``
  makes IDs unique among neighbours in its phase 1 and forgets a duplicate, so it leaves the
  test off).

The scenarios read the distances the robots measured through ``by_id`` and a record's
``mean_mm``, ``samples`` and ``ambiguous`` (:func:`kilonet.scenarios.reference.measured_distances`).
"""

from __future__ import annotations

import math
from bisect import insort
from operator import attrgetter
from types import MappingProxyType
from typing import Generic, TypeVar

__all__ = ["Neighbour", "NeighbourTable"]


class Neighbour:
    """One neighbour ID as heard.

    Attributes
    ----------
    uid : int
        Its ID.
    distance_sum_mm, distance_sq_sum_mm2, samples
        Sum, sum of squares and count of the distance estimates received from it (mm, mm²).
    heard_round : int
        The robot's round (its count of rounds of work) at the last reception (0 when the
        program keeps no rounds).
    ambiguous : bool
        Two robots seem to use this ID; the table ignores the record.
    """

    __slots__ = (
        "ambiguous",
        "distance_sq_sum_mm2",
        "distance_sum_mm",
        "heard_round",
        "samples",
        "uid",
    )

    def __init__(self, uid: int) -> None:
        self.uid = uid
        self.distance_sum_mm = 0.0
        self.distance_sq_sum_mm2 = 0.0
        self.samples = 0
        self.heard_round = 0
        self.ambiguous = False

    @property
    def mean_mm(self) -> float:
        """Mean of the distance estimates received from this neighbour, mm."""
        return self.distance_sum_mm / self.samples


R = TypeVar("R", bound=Neighbour)
_uid_of = attrgetter("uid")


class NeighbourTable(Generic[R]):
    """A robot's neighbour records by ID.

    Parameters
    ----------
    duplicate_mm : float
        A sample farther than this from its ID's mean marks the ID ambiguous (``localize``
        sets it from the noise it measures; infinite: no test).
    stale_rounds : int
        Records not heard for this many of the robot's rounds are left out of :meth:`fresh`.
    duplicate_after : int
        Samples an ID needs before the duplicate test applies to it (its mean must be good,
        and the robot's noise estimate made, first).

    Examples
    --------
    >>> t = NeighbourTable()
    >>> _ = t.heard(7, 40); _ = t.heard(7, 42)
    >>> t.distance(7), t[7].samples, 7 in t, 8 in t
    (41.0, 2, True, False)
    >>> sorted(t.by_id), t.by_id[7].mean_mm
    ([7], 41.0)

    With the duplicate test and ageing on:

    >>> nbs = NeighbourTable(duplicate_mm=6.0, stale_rounds=15, duplicate_after=4)
    >>> for d in (40, 49, 40, 42):  # 9 mm off at the second sample: too early to judge
    ...     _ = nbs.heard(7, d, 1)
    >>> nbs[7].mean_mm, nbs[7].ambiguous
    (42.75, False)
    >>> _ = nbs.heard(7, 62, 2)  # another robot with ID 7, 20 mm farther
    >>> nbs[7].ambiguous, [n.uid for n in nbs.fresh(5)]
    (True, [])
    >>> _ = nbs.heard(8, 50, 3)
    >>> [n.uid for n in nbs.fresh(18)], [n.uid for n in nbs.fresh(19)]
    ([8], [])
    >>> nbs.samples_total  # receptions from every ID
    6
    """

    #: The record class the table makes for a new ID (a subclass of :class:`Neighbour`).
    record_type: type[R] = Neighbour  # type: ignore[assignment]

    def __init__(
        self,
        *,
        duplicate_mm: float = math.inf,
        stale_rounds: int = 0,
        duplicate_after: int = 3,
    ) -> None:
        self._by_id: dict[int, R] = {}
        #: The records by ID (read-only view).
        self.by_id = MappingProxyType(self._by_id)
        self._in_id_order: list[R] = []  # by_id's records sorted by ID, for fresh() and ids()
        #: Receptions recorded, from every neighbour.
        self.samples_total = 0
        self._duplicate_mm = duplicate_mm
        self._duplicate_after = duplicate_after
        self._test_from = self._samples_to_test()
        self.stale_rounds = stale_rounds

    @property
    def duplicate_mm(self) -> float:
        """A sample farther than this from its ID's mean marks the ID ambiguous, mm (infinite:
        no test); a program may set it as it learns its noise."""
        return self._duplicate_mm

    @duplicate_mm.setter
    def duplicate_mm(self, value: float) -> None:
        self._duplicate_mm = value
        self._test_from = self._samples_to_test()

    @property
    def duplicate_after(self) -> int:
        """Samples an ID needs before the duplicate test applies to it."""
        return self._duplicate_after

    @duplicate_after.setter
    def duplicate_after(self, value: int) -> None:
        self._duplicate_after = value
        self._test_from = self._samples_to_test()

    def _samples_to_test(self) -> float:
        """The samples from which :meth:`heard` tests for a duplicate: ``duplicate_after``, or
        never (``inf``) when ``duplicate_mm`` is ``inf`` (or NaN), where no sample can fail the
        test (gcs): then a reception skips its arithmetic."""
        return self._duplicate_after if self._duplicate_mm < math.inf else math.inf

    def heard(self, uid: int, distance_mm: float, stamp: int = 0) -> R:
        """Record a reception from ``uid`` at ``distance_mm`` in round ``stamp``; return its
        record. (Runs on every reception: plain attribute arithmetic only.)"""
        n = self._by_id.get(uid)
        if n is None:
            n = self._by_id[uid] = self.record_type(uid)
            insort(self._in_id_order, n, key=_uid_of)
        elif n.samples >= self._test_from and abs(distance_mm * n.samples - n.distance_sum_mm) > (
            self._duplicate_mm * n.samples
        ):
            n.ambiguous = True
        n.distance_sum_mm += distance_mm
        n.distance_sq_sum_mm2 += distance_mm * distance_mm
        n.samples += 1
        n.heard_round = stamp
        self.samples_total += 1
        return n

    def forget(self, uid: int) -> None:
        """Drop ``uid`` (in ``gcs``, it announced a new ID)."""
        n = self._by_id.pop(uid, None)
        if n is not None:
            self._in_id_order.remove(n)

    def noise_mm(self, min_samples: int, default_mm: float) -> float:
        """This robot's own estimate of the ranging noise per reception: the median, over
        unambiguous neighbours heard at least ``min_samples`` times, of the standard deviation
        of their distance estimates (mm; ``default_mm`` until there is one). The median keeps
        a neighbour whose ID two robots share from inflating it.

        Examples
        --------
        >>> nbs = NeighbourTable(duplicate_mm=6.0, stale_rounds=5)
        >>> for d in (40, 42, 40, 42, 41):
        ...     _ = nbs.heard(1, d, 1)
        >>> nbs.noise_mm(5, 1.0), nbs.noise_mm(6, 1.0)
        (1.0, 1.0)
        >>> for d in (50, 54, 50, 54, 52):
        ...     _ = nbs.heard(2, d, 1)
        >>> for d in (60, 60, 60, 60, 60):
        ...     _ = nbs.heard(3, d, 1)
        >>> nbs.noise_mm(5, 1.0)
        1.0
        >>> for d in (70, 76, 70, 76, 73):
        ...     _ = nbs.heard(4, d, 1)
        >>> nbs.noise_mm(5, 1.0)
        1.5
        """
        # The square root keeps the order: take the median of the variances, then its root.
        variances = [
            (n.distance_sq_sum_mm2 - n.distance_sum_mm**2 / n.samples) / (n.samples - 1)
            for n in self._by_id.values()
            if n.samples >= min_samples and not n.ambiguous
        ]
        if not variances:
            return default_mm
        variances.sort()
        middle = len(variances) // 2
        if len(variances) % 2:
            return math.sqrt(max(variances[middle], 0.0))
        low, high = (math.sqrt(max(v, 0.0)) for v in variances[middle - 1 : middle + 1])
        return 0.5 * (low + high)

    def fresh(self, stamp: int, rounds: int | None = None) -> list[R]:
        """Unambiguous records heard within the last ``rounds`` (default ``stale_rounds``)
        rounds before round ``stamp``, by ID."""
        oldest = stamp - (self.stale_rounds if rounds is None else rounds)
        return [n for n in self._in_id_order if n.heard_round >= oldest and not n.ambiguous]

    def known(self) -> list[R]:
        """Every unambiguous record, however long ago it was heard, by ID (after DONE the
        placed robots of ``localize`` fall silent, and what they last said is final)."""
        return [n for n in self._in_id_order if not n.ambiguous]

    def get(self, uid: int, default: R | None = None) -> R | None:
        """The record of ``uid``, or ``default`` if not heard."""
        return self._by_id.get(uid, default)

    def distance(self, uid: int) -> float:
        """Mean measured distance to ``uid``, mm."""
        return self._by_id[uid].mean_mm

    def ids(self) -> list[int]:
        """IDs of all neighbours heard, sorted."""
        return [n.uid for n in self._in_id_order]

    def __getitem__(self, uid: int) -> R:
        return self._by_id[uid]

    def __contains__(self, uid: object) -> bool:
        return uid in self._by_id

    def __len__(self) -> int:
        return len(self._by_id)
