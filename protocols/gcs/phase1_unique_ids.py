"""Phase 1: locally unique IDs (thesis §4.1, §5.3.2 "Phase 1").

Each robot draws a random ID of ``id_bits`` bits and a random 8-bit salt and broadcasts both.
A neighbour that hears

* its own ID from another robot,
* one ID with two different salts, or
* one ID at two distances more than ``duplicate_distance_mm`` apart (the thesis's rule)

knows two robots share that ID and broadcasts a CONFLICT for it; the holders draw again,
avoiding IDs they know are taken, and announce the new ID with the old one so neighbours drop the
stale entry. The salt goes beyond the thesis: two holders at the same distance from every
observer are otherwise never told apart.

Messages (kilolib v2 payload, 16-bit ID fields)::

    type 10 ID        sender:uint16  salt:uint8  previous:uint16 (= sender if none)   5 bytes
    type 11 CONFLICT  sender:uint16  duplicate:uint16                                4 bytes

Time-out: the phase lasts ``gcs.ids_s`` seconds; a CONFLICT, and the old ID after a redraw,
are repeated at three transmit opportunities.
"""

from __future__ import annotations

from kilonet.message import Message
from kilonet.protocols.gcs.base import GcsParams, GcsStage, Phase, gcs_layout

__all__ = ["CONFLICT", "ID", "UniqueIds", "is_duplicate"]

ID = gcs_layout("id", type=10, fields=[("salt", "B"), ("previous", "H")])
CONFLICT = gcs_layout("conflict", type=11, fields=[("duplicate", "H")])
_REPEATS = 3
#: Readings of one ID, at least, before their distances may tell two robots apart.
_MIN_SAMPLES = 2


def is_duplicate(
    known_salt: int,
    salt: int,
    known_distance_mm: float | None,
    samples: int,
    distance_mm: float,
    duplicate_distance_mm: float,
) -> bool:
    """Whether an ID heard again belongs to a second robot: it comes with another salt than
    the first time, or (the thesis's rule) at a distance more than ``duplicate_distance_mm``
    from the mean of at least two earlier readings (``known_distance_mm``, ``None`` if never
    ranged).

    Examples
    --------
    >>> is_duplicate(7, 7, 40.0, 2, 55.0, 12.0), is_duplicate(7, 7, 40.0, 1, 55.0, 12.0)
    (True, False)
    >>> is_duplicate(7, 8, None, 0, 40.0, 12.0)
    True
    """
    far_apart = (
        known_distance_mm is not None
        and samples >= _MIN_SAMPLES
        and abs(distance_mm - known_distance_mm) > duplicate_distance_mm
    )
    return salt != known_salt or far_apart


class UniqueIds(Phase):
    """Phase 1 on one robot."""

    name = GcsStage.IDS

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's window, s: ``gcs.ids_s``."""
        return p.ids_s

    def start(self) -> None:
        r = self.robot
        self.salts: dict[int, int] = {}  # ID -> salt heard with it
        self.pending_conflicts: list[int] = []
        self.previous: int | None = None
        self.announce = 0
        uid = self._draw()
        r.take_id(uid, int(r.rand.integers(256)))
        self.redraws = 0

    def _draw(self) -> int:
        r = self.robot
        taken = set(r.table.ids()) | {r.uid}
        space = 1 << self.params.id_bits
        free = space - len(taken)
        for _ in range(64):
            uid = int(r.rand.integers(space))
            if uid not in taken or free <= 0:
                return uid
        return uid

    def _redraw(self) -> None:
        r = self.robot
        self.previous = r.uid
        self.announce = _REPEATS
        uid = self._draw()
        r.take_id(uid, int(r.rand.integers(256)))
        self.redraws += 1
        r.log("id", uid=r.uid, previous=self.previous)

    def message_tx(self) -> Message | None:
        r = self.robot
        if self.pending_conflicts:
            return CONFLICT.pack(sender=r.uid, duplicate=self.pending_conflicts.pop(0))
        previous = r.uid
        if self.previous is not None and self.announce > 0:
            self.announce -= 1
            previous = self.previous
        return ID.pack(sender=r.uid, salt=r.salt, previous=previous)

    def message_rx(self, message: Message, distance_mm: int) -> None:
        r = self.robot
        if ID.matches(message):
            m = ID.unpack(message)
            if m.previous != m.sender:
                r.table.forget(m.previous)
                self.salts.pop(m.previous, None)
            if m.sender == r.uid:
                self._redraw()
                return
            salt = self.salts.setdefault(m.sender, m.salt)
            known = r.table.get(m.sender)
            if is_duplicate(
                salt,
                m.salt,
                None if known is None else known.mean_mm,
                0 if known is None else known.samples,
                distance_mm,
                self.params.duplicate_distance_mm,
            ):
                self._report(m.sender)
        elif CONFLICT.matches(message):
            m = CONFLICT.unpack(message)
            if m.duplicate == r.uid:
                self._redraw()
            else:
                r.table.forget(m.duplicate)
                self.salts.pop(m.duplicate, None)

    def finish(self) -> None:
        r = self.robot
        r.learn_salts({uid: salt for uid, salt in self.salts.items() if uid in r.table})

    def _report(self, uid: int) -> None:
        r = self.robot
        r.table.forget(uid)
        self.salts.pop(uid, None)
        r.log("duplicate", uid=uid)
        self.pending_conflicts.extend([uid] * _REPEATS)
