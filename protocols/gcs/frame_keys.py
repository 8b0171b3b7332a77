"""Names of local frames and the ranks that order merged frames, with their wire form.

A **frame key** names a seed's local frame by the seed's ID and phase-1 salt: IDs are unique
only among a robot's neighbours, so two seeds three hops apart may share one; with the salt,
two frames are confused only if both match. A **root** is the frame a merged frame is aligned
to: a frame key, and whether its seed is an edge seed of a recovery epoch
(:mod:`kilonet.protocols.gcs.recovery`), whose frames rank after every elected seed's. A **rank** is
a seed's root and its hops from it (:mod:`kilonet.protocols.gcs.phase6_merging`); smaller is better.

All three are :class:`~typing.NamedTuple` values, ordered as their fields: ``Rank`` by
(edge, root ID, root salt, hops), exactly as the integers ``((edge · 2¹⁵ + ID) · 256 + salt) ·
256 + hops`` the protocol once packed them into. Why tuples: they are dict keys and compared on
the per-reception path, and a tuple hashes and compares in C, while a frozen dataclass costs
more to create and compares in Python; plain ints would be cheaper still but put the packing
back into every module. To keep creation off that path, robots build a neighbour's key once
(:meth:`kilonet.protocols.gcs.program.GcsRobot.frame_key`) and values read off the wire are interned
(``from_wire``): a swarm hears the same few keys and ranks again and again (``docs/gcs.md``,
"Speed").

Wire form (little-endian, as :class:`kilonet.message.Layout` packs fields)::

    frame key   id:uint16  salt:uint8
    root        id:uint16 (bit 15: edge seed; IDs have at most 15 bits)  salt:uint8
    rank        root (3 bytes)  hops:uint8

Examples
--------
>>> own = Rank.own(FrameKey(uid=7, salt=200), edge=False)
>>> own < Rank.own(FrameKey(7, 201), edge=False) < Rank.own(FrameKey(2, 0), edge=True)
True
>>> child = own.one_hop_further()
>>> child.hops, child.wire()
(1, (7, 200, 1))
>>> Rank.from_wire(*Rank(Root(True, FrameKey(3, 9)), 4).wire())
Rank(root=Root(edge=True, key=FrameKey(uid=3, salt=9)), hops=4)
>>> Root(True, FrameKey(3, 9)).number
8389385
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

__all__ = ["EDGE_BIT", "MAX_HOPS", "FrameKey", "Rank", "Root"]

#: How many distinct values each ``from_wire`` keeps interned (least recently used go first).
_INTERNED = 4096

#: Bit of a root's ID field that marks an edge seed's frame.
EDGE_BIT = 0x8000
#: Hops a rank can carry (uint8); a seed never takes a rank one hop beyond it.
MAX_HOPS = 0xFF


class FrameKey(NamedTuple):
    """The name of a seed's local frame: the seed's ID and its phase-1 salt (0-255)."""

    uid: int
    salt: int

    @staticmethod
    @lru_cache(maxsize=_INTERNED)
    def from_wire(uid: int, salt: int) -> FrameKey:
        """The frame key an ID field and a salt field carry (interned)."""
        return FrameKey(uid, salt)


class Root(NamedTuple):
    """The frame a merged frame is aligned to; elected seeds' frames order before edge seeds'.

    Parameters
    ----------
    edge : bool
        The root ranks after every elected seed's: its seed is an edge seed (a recovery
        epoch's), or an isolated seed (no merging group). A new frame, or one that merges with
        nothing, cannot win robots over from a merged frame they are located in too.
    key : FrameKey
        The root's frame.
    """

    edge: bool
    key: FrameKey

    @property
    def wire_id(self) -> int:
        """The root's ID field on the wire: the seed's ID, bit 15 set for an edge seed."""
        return self.key.uid | EDGE_BIT if self.edge else self.key.uid

    @property
    def number(self) -> int:
        """One integer per root, ``wire_id · 256 + salt``: how merged frames are labelled
        (:attr:`label`)."""
        return (self.wire_id << 8) | self.key.salt

    @property
    def label(self) -> str:
        """The merged frame's name in ``robots.csv`` and the estimates table:
        ``root<number>``."""
        return f"root{self.number}"

    @staticmethod
    @lru_cache(maxsize=_INTERNED)
    def from_wire(wire_id: int, salt: int) -> Root:
        """The root an ID field (bit 15: edge) and a salt field carry (interned)."""
        return Root(bool(wire_id & EDGE_BIT), FrameKey.from_wire(wire_id & ~EDGE_BIT, salt))


class Rank(NamedTuple):
    """A seed's place in the merge: the root its frame has been aligned to and its hops from
    that root. Smaller ranks are better: a seed follows the partner of the best rank."""

    root: Root
    hops: int

    @staticmethod
    def own(key: FrameKey, *, edge: bool) -> Rank:
        """A seed's rank before it has been aligned to anything: its own frame, 0 hops."""
        return Rank(Root(edge, key), 0)

    def one_hop_further(self) -> Rank:
        """The rank of a seed that follows a seed of this rank."""
        return Rank(self.root, self.hops + 1)

    def wire(self) -> tuple[int, int, int]:
        """``(root ID field, root salt, hops)``, the three fields a rank travels in."""
        root = self.root
        return root.wire_id, root.key.salt, self.hops

    @staticmethod
    @lru_cache(maxsize=_INTERNED)
    def from_wire(wire_id: int, salt: int, hops: int) -> Rank:
        """The rank three message fields carry (see :meth:`wire`; interned)."""
        return Rank(Root.from_wire(wire_id, salt), hops)
