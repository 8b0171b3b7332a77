"""Per-robot message counters of a medium.

Each counter is a plain list indexed by robot (scalar increments are what the hot path does).
Deliveries of fully clean transmissions are not counted receiver by receiver: the medium counts
them once per sender (:meth:`MediumCounters.clean_delivery`) and folds them into the
receivers' ``received`` counts whenever the sender's receiver list changes or someone reads the
counters, which saves a loop over receivers per message.

Examples
--------
>>> c = MediumCounters(3)
>>> c.sent[0] += 1
>>> c.clean_delivery(0)
>>> c.fold(0, receivers=[1, 2])
>>> c.as_dict()["received"], c.as_dict()["sent"]
([0, 1, 1], [1, 0, 0])
"""

from __future__ import annotations

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

#: Every counter, in table order: as a sender (``sent``, ``backoffs``: transmit opportunities
#: deferred because the robot sensed a carrier, ``bytes_sent``), then as a receiver.
COUNTERS = ("sent", "backoffs", "bytes_sent", "received", *(f"lost_{c}" for c in LOSS_CAUSES))


class MediumCounters:
    """The counters of :data:`COUNTERS` for ``n_robots`` robots."""

    __slots__ = ("_clean", "_lists", "backoffs", "bytes_sent", "received", "sent")

    def __init__(self, n_robots: int) -> None:
        self._lists = {name: [0] * n_robots for name in COUNTERS}
        self.sent = self._lists["sent"]
        self.backoffs = self._lists["backoffs"]
        self.bytes_sent = self._lists["bytes_sent"]
        self.received = self._lists["received"]
        self._clean = [0] * n_robots  # clean transmissions per sender not yet folded in

    def lost(self, cause: str) -> list[int]:
        """The per-robot list of receptions lost to ``cause`` (one of :data:`LOSS_CAUSES`)."""
        return self._lists[f"lost_{cause}"]

    def clean_delivery(self, sender: int) -> None:
        """Count one transmission of ``sender`` that every receiver got."""
        self._clean[sender] += 1

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
        """Every counter by name (fold first for exact ``received`` counts)."""
        return self._lists
