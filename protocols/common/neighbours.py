"""What a robot knows about its neighbours: their IDs and distances, as heard.

Every message of the global-coordinate-system protocol starts with the sender's ID, so each
reception refines the running mean of the distance to that neighbour (averaging the ranging
noise down). Only the robot's own receptions feed it.

The records offer the neighbour-record interface ``localize``'s offer too (``by_id``; a record's
``mean_mm``, ``samples`` and ``ambiguous``), so the scenarios read the distances the robots
measured the same way for both programs (:func:`scenarios.reference.measured_distances`).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

__all__ = ["Neighbour", "NeighbourTable"]


@dataclass(slots=True)
class Neighbour:
    """One neighbour as heard: mean measured distance (mm) and the number of samples."""

    distance_mm: float
    samples: int
    #: Never: phase 1 makes IDs unique among neighbours, and a duplicate is forgotten.
    ambiguous = False

    @property
    def mean_mm(self) -> float:
        """The mean measured distance, mm (``distance_mm``)."""
        return self.distance_mm


class NeighbourTable:
    """Neighbours by ID with their mean measured distances.

    Examples
    --------
    >>> t = NeighbourTable()
    >>> t.heard(7, 40); t.heard(7, 42)
    >>> t.distance(7), t[7].samples, 7 in t, 8 in t
    (41.0, 2, True, False)
    >>> sorted(t.by_id), t.by_id[7].mean_mm
    ([7], 41.0)
    """

    def __init__(self) -> None:
        self._by_id: dict[int, Neighbour] = {}
        #: The records by ID (read-only view).
        self.by_id = MappingProxyType(self._by_id)

    def heard(self, uid: int, distance_mm: float) -> None:
        """Record a reception from ``uid`` at ``distance_mm``."""
        n = self._by_id.get(uid)
        if n is None:
            self._by_id[uid] = Neighbour(float(distance_mm), 1)
        else:
            n.samples += 1
            n.distance_mm += (distance_mm - n.distance_mm) / n.samples

    def forget(self, uid: int) -> None:
        """Drop ``uid`` (it announced a new ID)."""
        self._by_id.pop(uid, None)

    def get(self, uid: int, default: Neighbour | None = None) -> Neighbour | None:
        """The neighbour ``uid``, or ``default`` if not heard."""
        return self._by_id.get(uid, default)

    def distance(self, uid: int) -> float:
        """Mean measured distance to ``uid``, mm."""
        return self._by_id[uid].distance_mm

    def ids(self) -> list[int]:
        """IDs of all neighbours heard, sorted."""
        return sorted(self._by_id)

    def __contains__(self, uid: object) -> bool:
        return uid in self._by_id

    def __getitem__(self, uid: int) -> Neighbour:
        return self._by_id[uid]

    def __len__(self) -> int:
        return len(self._by_id)
