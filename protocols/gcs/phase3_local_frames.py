"""Phase 3: each seed builds its local frame from two references (thesis §4.3, §5.3.2).

A seed A must learn the distances between pairs of its neighbours. It asks them one at a time
with a synchronous request/answer protocol:

1. A sends ``ASK(A → B, chunk k)``; B, if free (or already serving A), becomes busy with A and
   answers with its neighbour table, two entries a message, starting at chunk ``k``.
2. A asks again for the first chunk it still misses, until it holds B's whole table; then it
   sends ``ASK(A → B, DONE)`` and B is free again.
3. If B stays silent for ``gcs.ask_timeout_s`` (busy with another seed, or gone), A skips it and
   retries it later, ``gcs.ask_attempts`` times at most. A busy B that hears nothing from its
   seed for ``gcs.busy_reset_s`` resets itself (the seed broke down).

Tables are broadcast, so a seed also keeps every chunk it overhears from a neighbour answering
another seed, and does not ask a neighbour whose table it already holds.

When it has asked everyone, A chooses references B, C that see each other (each lists the
other, at matching distances: :func:`reference_candidates`) by the rule
``gcs.reference_rule`` (``max_angle``: the thesis's rule, maximise ∠BAC; ``best_conditioned``:
see :func:`kilonet.protocols.common.geometry.choose_references_best_conditioned`), places B = (|AB|,
0) and
C = (|AC| cos α, |AC| sin α) and announces both until the phase ends.

Messages (16-bit IDs; distances whole mm; coordinates int16 in 0.1 mm)::

    type 30 ASK    sender:uint16  target:uint16  chunk:uint8 (255: done)             5 bytes
    type 31 TABLE  sender:uint16  chunk:uint8 (bit 7: last)  2 × (id:uint16 d:uint8)  9 bytes
    type 32 REF    sender:uint16  reference:uint16  x:int16  y:int16                  8 bytes
"""

from __future__ import annotations

from kilonet.message import Message
from kilonet.protocols.common.geometry import (
    GeometryError,
    choose_references_best_conditioned,
    choose_references_max_angle,
    place_references,
)
from kilonet.protocols.gcs.base import GcsParams, GcsStage, Phase, gcs_layout

__all__ = [
    "ASK",
    "REF",
    "TABLE",
    "LocalFrames",
    "announce_reference",
    "receive_reference",
    "reference_candidates",
]

ASK = gcs_layout("ask", type=30, fields=[("target", "H"), ("chunk", "B")])
TABLE = gcs_layout(
    "table",
    type=31,
    fields=[("chunk", "B"), ("id1", "H"), ("d1", "B"), ("id2", "H"), ("d2", "B")],
)
REF = gcs_layout(
    "ref", type=32, fields=[("reference", "H"), ("x_mm", "h", 0.1), ("y_mm", "h", 0.1)]
)
DONE = 255
_LAST = 0x80
_NONE = 0xFFFF


def reference_candidates(
    distances_mm: dict[int, float],
    tables: dict[int, dict[int, int]],
    tolerance_mm: float,
) -> dict[tuple[int, int], tuple[float, float, float]]:
    """The pairs of a seed's neighbours that may serve as its references, with their distances.

    B and C qualify when each lists the other in its table and the two readings of their
    distance agree within ``tolerance_mm``. One direction is not enough: IDs are unique only
    among neighbours, so B's table may hold a *different* robot with C's ID, two hops from C,
    and a seed that took that namesake's distance for |BC| bends its whole frame
    (``docs/gcs.md``). An alias that also lists B, at a matching distance, is far less likely.

    Parameters
    ----------
    distances_mm : dict
        The seed's own distance to each neighbour whose table it holds, mm.
    tables : dict
        Each such neighbour's table: neighbour ID -> distance in whole mm.
    tolerance_mm : float
        Largest accepted difference between B's reading of |BC| and C's reading, mm.

    Returns
    -------
    dict
        ``{(b, c): (|AB|, |AC|, |BC|)}`` with ``b`` before ``c`` in ``distances_mm``'s order
        and |BC| the mean of the two readings, mm.

    Examples
    --------
    B (1) and C (2) see each other; D (3) is listed by B, but the 3 in B's table is another
    robot: D's table does not list B.

    >>> tables = {1: {2: 40, 3: 72}, 2: {1: 41, 3: 39}, 3: {2: 39}}
    >>> reference_candidates({1: 38.0, 2: 39.0, 3: 39.0}, tables, tolerance_mm=5.0)
    {(1, 2): (38.0, 39.0, 40.5), (2, 3): (39.0, 39.0, 39.0)}
    """
    ids = list(distances_mm)
    candidates = {}
    for i, b in enumerate(ids):
        for c in ids[i + 1 :]:
            d_bc, d_cb = tables[b].get(c), tables[c].get(b)
            if d_bc is None or d_cb is None or abs(d_bc - d_cb) > tolerance_mm:
                continue
            candidates[(b, c)] = (distances_mm[b], distances_mm[c], (d_bc + d_cb) / 2)
    return candidates


class LocalFrames(Phase):
    """Phase 3 on one robot: every robot answers seeds; seeds also ask and build a frame."""

    name = GcsStage.FRAMES

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's window, s: ``gcs.frames_s``."""
        return p.frames_s

    def start(self) -> None:
        r = self.robot
        tps = r.ticks_per_s
        self.ask_timeout = round(self.params.ask_timeout_s * tps)
        self.busy_reset = round(self.params.busy_reset_s * tps)
        # Answering side.
        entries = [(uid, round(r.table.distance(uid))) for uid in r.table.ids()]
        self.my_chunks = [entries[i : i + 2] for i in range(0, len(entries), 2)] or [[]]
        self.serving: int | None = None
        self.serving_since = 0
        self.next_chunk = 0
        # Asking side (seeds): tables heard, by neighbour: chunk -> entries, and last chunk.
        self.tables: dict[int, dict[int, list[tuple[int, int]]]] = {}
        self.last_chunk: dict[int, int] = {}
        # A seed that built its frame in an earlier epoch (kilonet.protocols.gcs.recovery) keeps it:
        # the positions located in it must stay valid.
        self.queue = [uid for uid in r.table.ids()] if r.is_seed and not r.references else []
        self.attempts = dict.fromkeys(self.queue, 0)
        self.asking: int | None = None
        self.asked_at = 0
        self.references: list[tuple[int, float, float]] = list(r.references)
        self.tried = bool(r.references)  # the seed has chosen (or failed to choose) references
        self.skipped = 0

    # -- answering ---------------------------------------------------------------------------
    def _answer(self) -> Message | None:
        r = self.robot
        if self.serving is None:
            return None
        if r.kilo_ticks - self.serving_since > self.busy_reset:
            r.log("busy_reset", seed=self.serving)
            self.serving = None
            return None
        k = self.next_chunk
        if k >= len(self.my_chunks):
            return None
        chunk = self.my_chunks[k] + [(_NONE, 0)] * (2 - len(self.my_chunks[k]))
        self.next_chunk = k + 1
        flag = _LAST if k == len(self.my_chunks) - 1 else 0
        (id1, d1), (id2, d2) = chunk
        return TABLE.pack(
            sender=r.uid, chunk=k | flag, id1=id1, d1=min(d1, 255), id2=id2, d2=min(d2, 255)
        )

    # -- asking (seeds) ----------------------------------------------------------------------
    def _complete(self, uid: int) -> bool:
        last = self.last_chunk.get(uid)
        return last is not None and all(k in self.tables[uid] for k in range(last + 1))

    def _first_missing(self, uid: int) -> int:
        chunks = self.tables.get(uid, {})
        k = 0
        while k in chunks:
            k += 1
        return k

    def _ask(self) -> Message | None:
        r = self.robot
        now = r.kilo_ticks
        if self.asking is not None:
            uid = self.asking
            if self._complete(uid):
                self.asking = None
                return ASK.pack(sender=r.uid, target=uid, chunk=DONE)
            if now - self.asked_at > self.ask_timeout:
                self.skipped += 1
                self.asking = None
                if self.attempts[uid] < self.params.ask_attempts:
                    self.queue.append(uid)
            else:
                return ASK.pack(sender=r.uid, target=uid, chunk=self._first_missing(uid))
        while self.queue:
            uid = self.queue.pop(0)
            if self._complete(uid):
                continue
            self.attempts[uid] += 1
            self.asking, self.asked_at = uid, now
            return ASK.pack(sender=r.uid, target=uid, chunk=self._first_missing(uid))
        if not self.tried:
            self._choose_references()
        return self._announce()

    def _choose_references(self) -> None:
        r = self.robot
        ids = [uid for uid in r.table.ids() if self._complete(uid)]
        tables = {uid: dict(e for chunk in self.tables[uid].values() for e in chunk) for uid in ids}
        candidates = reference_candidates(
            {uid: r.table.distance(uid) for uid in ids},
            tables,
            tolerance_mm=4 * self.params.sigma_mm + 1.0,
        )
        self.tried = True
        if not candidates:
            r.log("frame_failed", neighbours=len(r.table), complete=len(ids))
            return
        rule = (
            choose_references_max_angle
            if self.params.reference_rule == "max_angle"
            else choose_references_best_conditioned
        )
        try:
            (b, c), score = rule(candidates)
            (xb, yb), (xc, yc) = place_references(*candidates[(b, c)])
        except GeometryError as exc:  # every candidate triangle is degenerate
            r.log("frame_failed", reason=str(exc))
            return
        self.references = [(b, xb, yb), (c, xc, yc)]
        r.references = self.references
        r.estimate.locate(r.own_key, (0.0, 0.0))
        r.log("frame", b=b, c=c, score=float(score), asked=len(ids), skipped=self.skipped)

    def _announce(self) -> Message | None:
        return announce_reference(self.robot)

    # -- phase interface ---------------------------------------------------------------------
    def message_tx(self) -> Message | None:
        # Answering a seed comes first: that seed is waiting on this robot.
        answer = self._answer()
        if answer is not None:
            return answer
        return self._ask() if self.robot.is_seed else None

    def message_rx(self, message: Message, distance_mm: int) -> None:
        r = self.robot
        if ASK.matches(message):
            m = ASK.unpack(message)
            if m.target != r.uid:
                return
            if m.chunk == DONE:
                if self.serving == m.sender:
                    self.serving = None
            elif self.serving in (None, m.sender):
                if self.serving is None:
                    self.serving_since = r.kilo_ticks
                self.serving = m.sender
                self.next_chunk = m.chunk
                self.serving_since = r.kilo_ticks
        elif TABLE.matches(message) and r.is_seed:
            m = TABLE.unpack(message)
            k = m.chunk & ~_LAST
            entries = [(uid, d) for uid, d in ((m.id1, m.d1), (m.id2, m.d2)) if uid != _NONE]
            self.tables.setdefault(m.sender, {})[k] = entries
            if m.chunk & _LAST:
                self.last_chunk[m.sender] = k
            if m.sender == self.asking:
                self.asked_at = r.kilo_ticks  # it answers: keep waiting for the rest
        else:
            receive_reference(r, message)

    def finish(self) -> None:
        r = self.robot
        if r.is_seed and not self.tried:
            self._choose_references()


def announce_reference(robot) -> Message | None:
    """A seed's next REF message (its references in turn), or ``None`` without references."""
    refs = robot.references
    if not refs:
        return None
    robot.ref_turn = (robot.ref_turn + 1) % len(refs)
    uid, x, y = refs[robot.ref_turn]
    return REF.pack(sender=robot.uid, reference=uid, x_mm=x, y_mm=y)


def receive_reference(robot, message: Message) -> None:
    """A REF naming this robot locates it in the seed's frame."""
    if not REF.matches(message):
        return
    m = REF.unpack(message)
    key = robot.frame_key(m.sender)
    if m.reference == robot.uid and key not in robot.estimate.frames:
        robot.estimate.locate(key, (m.x_mm, m.y_mm))
        if not robot.is_seed:
            robot.role = "reference"
        robot.log("reference", seed=m.sender, x_mm=m.x_mm, y_mm=m.y_mm)
