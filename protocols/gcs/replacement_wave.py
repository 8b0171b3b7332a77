"""The re-placement wave of phase 7, as far as phase 6 needs it: the layouts of a refining
robot's global position (GPOS, GPOS_PLACED, GPOS_SETTLED) and when the wave has reached a robot
still merging (:func:`wave_reached`, :class:`PlacedNeighbours`).

Phase 6 (:mod:`kilonet.protocols.gcs.phase6_merging`) ends for a robot the wave has reached, and
phase 7 (:mod:`kilonet.protocols.gcs.phase7_refinement`) sends these messages: both import them from
here, so that no phase imports from a later one. Message layouts (9 bytes each)::

    type 73 GPOS          sender:uint16  x:int16  y:int16 (0.1 mm)  root:uint16  salt:uint8
    type 75 GPOS_PLACED   the same, from a robot the wave has placed
    type 74 GPOS_SETTLED  the same, from a placed robot that has settled or is done
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from kilonet.message import Message
from kilonet.protocols.gcs.base import gcs_layout
from kilonet.protocols.gcs.frame_keys import Root

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = [
    "GPOS",
    "GPOS_PLACED",
    "GPOS_SETTLED",
    "PLACED_TYPES",
    "PlacedNeighbours",
    "wave_reached",
]

_GPOS_FIELDS = [("x_mm", "h", 0.1), ("y_mm", "h", 0.1), ("root", "H"), ("salt", "B")]
#: A refining robot's global position and root, before the wave has placed it; GPOS_SETTLED:
#: the same from a placed one that has settled (or is done: its estimate frozen).
GPOS = gcs_layout("gpos", type=73, fields=_GPOS_FIELDS)
GPOS_SETTLED = gcs_layout("gpos_settled", type=74, fields=_GPOS_FIELDS)
#: The same from a robot placed by the re-placement wave that has not settled yet.
GPOS_PLACED = gcs_layout("gpos_placed", type=75, fields=_GPOS_FIELDS)
#: A neighbour silent this long is left out, s (it crashed, was removed, or merges again).
STALE_S = 3.0
#: The placed positions, by message type.
_PLACED_LAYOUTS = {layout.type: layout for layout in (GPOS_PLACED, GPOS_SETTLED)}
#: Their type bytes: a receiver reads its clock for :meth:`PlacedNeighbours.take` only for these.
PLACED_TYPES = frozenset(_PLACED_LAYOUTS)


def wave_reached(own: Root | None, roots: Iterable[Root]) -> bool:
    """Whether the re-placement wave has reached a robot still merging in frame ``own``
    (``None``: it has no estimate): at least three of its placed neighbours — ``roots``, the
    frame of each — lie in one frame whose root is ``own`` or better. Merging is then over for
    it (:meth:`kilonet.protocols.gcs.phase6_merging.FrameMerging.finished`): the refinement places
    it from those neighbours, whatever merging's estimate says.

    Examples
    --------
    >>> from kilonet.protocols.gcs.frame_keys import FrameKey
    >>> a, b = Root(False, FrameKey(3, 9)), Root(False, FrameKey(5, 1))
    >>> wave_reached(b, [a, a, b])  # three placed, but in two frames
    False
    >>> wave_reached(b, [a, a, a]), wave_reached(None, [b, b, b])
    (True, True)
    >>> wave_reached(a, [b, b, b])  # b is worse than its own frame: merging decides
    False
    """
    counts: dict[Root, int] = {}
    for root in roots:
        if own is None or not own < root:
            counts[root] = counts.get(root, 0) + 1
            if counts[root] >= 3:
                return True
    return False


class PlacedNeighbours:
    """The neighbours a merging robot heard announce a position placed by the re-placement
    wave (GPOS_PLACED, GPOS_SETTLED), with their frames: what :func:`wave_reached` reads.

    Parameters
    ----------
    ticks_per_s : float
        The robot's clock rate, kilo_ticks per s: a neighbour not heard for ``STALE_S`` no
        longer counts.
    """

    __slots__ = ("_heard", "_stale_ticks")

    def __init__(self, ticks_per_s: float) -> None:
        self._stale_ticks = STALE_S * ticks_per_s
        self._heard: dict[int, tuple[Root, int]] = {}  # sender: (root, tick heard)

    def take(self, message: Message, tick: int) -> None:
        """Record ``message`` if it is a placed position, heard at ``tick``."""
        layout = _PLACED_LAYOUTS.get(message.type)
        if layout is not None:
            m = layout.unpack(message)
            self._heard[m.sender] = (Root.from_wire(m.root, m.salt), tick)

    def reached(self, own: Root | None, tick: int) -> bool:
        """:func:`wave_reached` over the neighbours heard in the last ``STALE_S``."""
        oldest = tick - self._stale_ticks
        return wave_reached(own, (root for root, heard in self._heard.values() if heard >= oldest))
