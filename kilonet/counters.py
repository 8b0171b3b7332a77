"""Per-robot message counters of a medium.

Each counter is a plain list indexed by robot (scalar increments are what the hot path does).
Deliveries of fully clean transmissions are not counted receiver by receiver: the medium counts
them once per sender (:meth:`MediumCounters.clean_delivery`) and folds them into the
receivers' ``received`` counts whenever the sender's receiver list changes or someone reads the
counters, which saves a loop over receivers per message. Collided receptions are not counted
one by one either: the medium hands over each message's set of receivers where it collided
(:meth:`MediumCounters.collided`), and the sets are counted by NumPy a batch at a time, and
whenever someone reads the counters (:meth:`MediumCounters.as_dict`): on a busy channel most
receptions collide, and a Python loop over them would cost more than the rest of a message.

Examples
--------
>>> c = MediumCounters(3)
>>> c.sent[0] += 1
>>> c.clean_delivery(0)
>>> c.fold(0, receivers=[1, 2])
>>> c.as_dict()["received"], c.as_dict()["sent"]
([0, 1, 1], [1, 0, 0])
>>> c.clean_delivery(0)  # a second message of robot 0, which collided at robot 2
>>> c.collided({2})
>>> c.fold(0, receivers=[1, 2])
>>> c.as_dict()["received"], c.as_dict()["lost_collision"]
([0, 2, 1], [0, 0, 1])
"""

from __future__ import annotations

import operator
from collections.abc import Set
from itertools import chain

import numpy as np

__all__ = ["COUNTERS", "LOSS_CAUSES", "MediumCounters"]

#: Causes a reception can be lost to, as counted per receiving robot (``lost_<cause>``):
#: independent loss, a signal too weak near the link's edge, bodies on the line of sight,
#: overlapping receptions, a full polled buffer, a low battery, a faulty receiver, a message
#: whose CRC the sender got wrong.
LOSS_CAUSES = (
    "random",
    "signal",
    "occlusion",
    "collision",
    "overflow",
    "battery",
    "fault",
    "crc",
)

#: Collided messages whose receptions are counted at once (a few hundred kB of sets at most).
_COLLISION_BATCH = 512

#: Every counter, in table order: as a sender (``sent``, ``backoffs``: transmit opportunities
#: deferred because the robot sensed a carrier, ``bytes_sent``), then as a receiver.
COUNTERS = ("sent", "backoffs", "bytes_sent", "received", *(f"lost_{c}" for c in LOSS_CAUSES))


class MediumCounters:
    """The counters of :data:`COUNTERS` for ``n_robots`` robots."""

    __slots__ = (
        "_clean",
        "_collided",
        "_lists",
        "_n",
        "backoffs",
        "bytes_sent",
        "received",
        "sent",
    )

    def __init__(self, n_robots: int) -> None:
        self._n = n_robots
        self._lists = {name: [0] * n_robots for name in COUNTERS}
        self.sent = self._lists["sent"]
        self.backoffs = self._lists["backoffs"]
        self.bytes_sent = self._lists["bytes_sent"]
        self.received = self._lists["received"]
        self._clean = [0] * n_robots  # clean transmissions per sender not yet folded in
        self._collided: list[Set[int]] = []  # per message, the receivers where it collided

    def lost(self, cause: str) -> list[int]:
        """The per-robot list of receptions lost to ``cause`` (one of :data:`LOSS_CAUSES`)."""
        return self._lists[f"lost_{cause}"]

    def clean_delivery(self, sender: int) -> None:
        """Count one transmission of ``sender`` that every receiver got."""
        self._clean[sender] += 1

    def collided(self, receivers: Set[int]) -> None:
        """Count one message whose receptions at ``receivers`` collided, after it was counted
        as received there (by :meth:`clean_delivery` or one by one): ``received`` loses one
        and ``lost_collision`` gains one at each. The set must not change afterwards."""
        batch = self._collided
        batch.append(receivers)
        if len(batch) >= _COLLISION_BATCH:
            self._fold_collisions()

    def _fold_collisions(self) -> None:
        """Apply the pending :meth:`collided` sets to the counters (one NumPy count)."""
        batch = self._collided
        if not batch:
            return
        flat = np.fromiter(chain.from_iterable(batch), dtype=np.intp)
        counts = np.bincount(flat, minlength=self._n).tolist()
        batch.clear()
        received, lost = self.received, self._lists["lost_collision"]
        received[:] = map(operator.sub, received, counts)  # the same lists: others hold them
        lost[:] = map(operator.add, lost, counts)

    def fold(self, sender: int, receivers: list[int]) -> None:
        """Add ``sender``'s clean transmissions to ``receivers`` (its receiver list while they
        were counted)."""
        clean = self._clean[sender]
        if clean:
            received = self.received
            for r in receivers:
                received[r] += clean
            self._clean[sender] = 0

    def as_dict(self) -> dict[str, list[int]]:
        """Every counter by name, the pending collisions counted (:meth:`fold` each sender
        first for exact ``received`` counts)."""
        self._fold_collisions()
        return self._lists
