"""Shared parts of the ``localize`` protocol: its parameters, what a robot knows about each
neighbour, and the distance reports that make every measured distance symmetric.

Every message of the protocol starts with the sender's 16-bit ID, so every reception adds a
distance sample to the sender's :class:`Neighbour` record, in the neighbour table common to
both protocols (:mod:`kilonet.protocols.common.neighbours`; its mean averages the ranging noise
down). Both ends of a pair fit the same distance, agreed through the symmetric distance
reports of :mod:`kilonet.protocols.common.refinement` (DIST, and the choice of neighbour of
:func:`~kilonet.protocols.common.refinement.next_report`); one transmit opportunity in
``localize.dist_every`` carries a report::

    NBR  (85)  sender:uint16  neighbour:uint16  distance:uint16 (0.01 mm)            6 bytes

A robot without a position reports in NBR, whose full distances also tell the root, while it
is elected, how far apart its neighbours are (:mod:`kilonet.protocols.localize.phase2_spread`); once
it has one, in DIST, which carries the position too (:func:`distance_report`).

Every robot measures its own ranging noise, as the median spread of the samples it gets from
each neighbour (:meth:`Neighbours.noise_mm`), and scales its tolerances by it (the duplicate
test here, the fix checks of :mod:`kilonet.protocols.localize.phase2_spread`), so the protocol needs
no calibration constant for it.

IDs are drawn at random; :mod:`kilonet.protocols.localize.phase1_election` redraws one heard from
another robot. Two neighbours of one robot may still share an ID: when a sample from an ID lies more
than ``duplicate_sigmas`` noise deviations from that ID's mean, the record is marked
ambiguous and ignored from then on (:meth:`Neighbours.heard`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from kilonet.message import Layout, Message
from kilonet.params import param
from kilonet.protocols.common import neighbours as common_neighbours
from kilonet.protocols.common.neighbours import NeighbourTable
from kilonet.protocols.common.refinement import (
    DIST,
    DISTANCE_STEP_MM,
    agreed_range_mm,
    distance_code,
    unwrap_distance,
)

__all__ = [
    "COMPLETE",
    "COORDINATE_PERIOD_MM",
    "DONE",
    "LOCALIZED",
    "MAX_COORDINATE_MM",
    "MAX_HOPS",
    "NBR",
    "NO_ID",
    "SETTLED",
    "UNKNOWN_HOPS",
    "LocalizeParams",
    "Neighbour",
    "Neighbours",
    "absolute_position",
    "children_complete",
    "choose_parent",
    "distance_report",
    "toward_root",
    "unwrap_coordinate",
    "wrapped_position",
]

#: No robot: an empty ID field (IDs are drawn from 0 .. 0xFFFE).
NO_ID = 0xFFFF
#: Hop counts saturate here (ELECT's hops byte keeps its top bit for the echo).
MAX_HOPS = 126
#: A neighbour's hop count as a robot records it before it has heard one that counts: never
#: announced, or announced for another election key (:func:`toward_root`).
UNKNOWN_HOPS = 255
#: Coordinates travel as int16 tenths of a millimetre *modulo* this period, mm (2¹⁶ tenths):
#: every message's x and y fields wrap, and a receiver unwraps them near a position it knows
#: (:func:`unwrap_coordinate`). POS and CAND also carry the winding numbers, so a robot that
#: knows no position yet learns its anchors' positions whole (:func:`absolute_position`).
COORDINATE_PERIOD_MM = 6553.6
_PERIOD_TENTHS = 65536
_HALF_PERIOD_TENTHS = 32768
#: Winding numbers are signed 4-bit values, -8 .. 7, one per axis in one byte.
_MAX_WINDING = 7
#: Largest coordinate a robot can hold, mm: 7 whole periods and the int16 field's 3,276.7 mm
#: (49.2 m from the root; a frame farther than that refuses the position, ``out_of_frame``).
MAX_COORDINATE_MM = _MAX_WINDING * COORDINATE_PERIOD_MM + 3276.7

# State flags of POS and ROOT messages (kilonet.protocols.localize.phase3_termination sets the last
# three).
#: The sender has a position in the frame.
LOCALIZED = 1
#: The sender's position has stopped moving (or, unlocalized, it has given up).
SETTLED = 2
#: The sender and every robot below it in the hop structure are settled.
COMPLETE = 4
#: The swarm is done: stop refining.
DONE = 8

NBR = Layout(
    "nbr",
    type=85,
    fields=[("sender", "H"), ("neighbour", "H"), ("distance_mm", "H", 0.01)],
)


@dataclass(frozen=True)
class LocalizeParams:
    """Parameters of the ``localize`` protocol (section ``localize``); times on the robot's
    own clock."""

    section_name = "localize"
    round_s: float = param(0.2, lo=0.01, hi=10.0, doc="a robot updates its state this often")
    sigma_mm: float = param(
        1.0,
        lo=0.01,
        hi=100.0,
        doc="ranging noise per reception assumed until a robot has measured its own",
    )
    noise_samples: int = param(
        5, lo=2, hi=10_000, doc="receptions from a neighbour before its spread counts"
    )
    link_error_mm: float = param(
        2.0,
        lo=0.0,
        hi=100.0,
        doc="per-link ranging error robots add to the noise they measure (real robots: the "
        "emitter's strength biases each link, which repeated readings cannot show)",
    )
    neighbour_max_mm: float = param(
        90.0,
        lo=33.0,
        hi=255.0,
        doc="a reception with a larger distance estimate is ignored: its sender is no neighbour "
        "(kilolib's tables end at 98 mm; near their end a strong emitter reads up to 10 mm near)",
    )
    duplicate_after: int = param(
        10, lo=3, hi=10_000, doc="receptions from an ID before the duplicate test applies"
    )
    dist_every: int = param(
        3, lo=2, hi=100, doc="one transmit opportunity in this many carries a DIST report"
    )
    duplicate_sigmas: float = param(
        6.0, lo=2.0, hi=1000.0, doc="a sample this many sigmas off its ID's mean: two robots"
    )
    stale_s: float = param(3.0, lo=0.2, hi=600.0, doc="a neighbour silent this long is ignored")
    child_stale_s: float = param(
        10.0,
        lo=0.2,
        hi=600.0,
        doc="a child not complete holds up its parent's settled wave until silent this long, s",
    )
    listen_s: float = param(
        1.0, lo=0.0, hi=600.0, doc="election key follows the neighbour count until then"
    )
    elect_timeout_s: float = param(
        60.0, lo=1.0, hi=3600.0, doc="the best-key robot starts without the echo after this"
    )
    bootstrap_timeout_s: float = param(
        4.0, lo=0.2, hi=600.0, doc="the root picks other frame robots if these stay silent"
    )
    min_height_mm: float = param(
        10.0,
        lo=0.1,
        hi=200.0,
        doc="thinnest triangle allowed: frame start, fix anchors, candidates",
    )
    max_residual_sigmas: float = param(
        4.0, lo=0.1, hi=1000.0, doc="reject fixes whose residual RMS exceeds this many sigmas"
    )
    max_candidate_neighbours: int = param(
        0,
        lo=0,
        hi=6,
        doc="neighbours' candidate pairs combined in one fix at most (rule 3; 0: off, since "
        "kilolib's per-link errors make it pick mirror images that fold the frame)",
    )
    overlap_mm: float = param(
        28.0, lo=0.0, hi=200.0, doc="a candidate nearer than this to a located robot is impossible"
    )
    heard_mm: float = param(
        55.0,
        lo=0.0,
        hi=1000.0,
        doc="a candidate nearer than this to a settled robot it does not hear is impossible "
        "(0: off)",
    )
    fresh_anchor_s: float = param(
        1.0,
        lo=0.0,
        hi=60.0,
        doc="rule 1 takes no fix from exactly three anchors while one of them was placed less "
        "than this long ago, s (0: off)",
    )
    retry_s: float = param(
        2.0, lo=0.2, hi=600.0, doc="an unlocalized robot retries an unchanged fix this often"
    )
    island_quiet_s: float = param(
        1.0, lo=0.2, hi=3600.0, doc="an island member solves once its reports are quiet this long"
    )
    island_max_reports: int = param(
        64,
        lo=0,
        hi=100_000,
        doc="island reports a member stores; a larger island is not solved (0: no islands)",
    )
    huber_mm: float = param(
        3.0, lo=0.01, hi=100.0, doc="refinement down-weights residuals beyond this"
    )
    max_step_mm: float = param(5.0, lo=0.01, hi=100.0, doc="largest refinement step per round")
    momentum: float = param(
        0.5, lo=0.0, hi=0.99, doc="share of its previous step a refinement step adds"
    )
    settle_mm: float = param(
        0.5, lo=0.0, hi=100.0, doc="settled: moved less than this over settle_rounds rounds"
    )
    settle_rounds: int = param(10, lo=1, hi=10_000, doc="rounds the settle test looks back")
    unsettle_mm: float = param(
        1.5,
        lo=0.0,
        hi=100.0,
        doc="a settled robot stays settled until it is this far from where it settled, mm "
        "(0: only while the settle test holds)",
    )
    settle_timeout_s: float = param(
        120.0, lo=1.0, hi=3600.0, doc="a localized robot counts as settled after this anyway"
    )
    give_up_s: float = param(
        5.0, lo=0.2, hi=3600.0, doc="an unlocalized robot gives up after no news for this long"
    )
    done_confirm_rounds: int = param(
        3, lo=1, hi=1000, doc="rounds the root must stay complete before it floods done"
    )
    done_repeats: int = param(3, lo=1, hi=100, doc="messages a done robot sends before silence")
    parent_repeats: int = param(
        3, lo=1, hi=100, doc="ELECT messages a robot sends after its parent changes (phase 2-3)"
    )
    parent_every: int = param(
        10, lo=2, hi=1000, doc="after the election, one opportunity in this many sends the parent"
    )
    run_timeout_s: float = param(
        600.0, lo=1.0, hi=86_400.0, doc="a robot declares itself done after this anyway"
    )


class Neighbour(common_neighbours.Neighbour):
    """What a robot knows about one neighbour ID: the distance samples of the common record
    (:class:`kilonet.protocols.common.neighbours.Neighbour`: ``uid``, ``distance_sum_mm``,
    ``distance_sq_sum_mm2``, ``samples``, ``heard_round``, ``ambiguous``), and what
    ``localize`` learns besides.

    Attributes
    ----------
    reported_mm : float or None
        Its own mean distance to this robot, from its DIST reports (mm).
    sent_mm : float or None
        This robot's mean distance to it when this robot last reported it (None: never), mm.
    sent_round : int
        This robot's round at that report (-1: never).
    x_mm, y_mm : float or None
        Its position as last announced (None: it has none).
    hops : int
        Its hop count to the root as last announced (255: unknown).
    parent : int
        The neighbour it reports to in the convergecasts, as its last ELECT announced
        (``NO_ID``: none heard).
    flags : int
        Its state flags as last announced (:data:`LOCALIZED`, ...).
    near : set of int
        The neighbours it has reported distances to in NBR messages (it is unplaced then).
    """

    __slots__ = (
        "candidates",
        "candidates_from_line",
        "echo",
        "flags",
        "hops",
        "key",
        "near",
        "parent",
        "placed_tick",
        "reported_mm",
        "sent_mm",
        "sent_round",
        "x_mm",
        "y_mm",
    )

    def __init__(self, uid: int) -> None:
        super().__init__(uid)
        self.reported_mm: float | None = None
        self.sent_mm: float | None = None
        self.sent_round = -1
        self.x_mm: float | None = None
        self.y_mm: float | None = None
        self.placed_tick: float | None = None  # its clock when this robot first heard a position
        self.hops = UNKNOWN_HOPS
        self.parent = NO_ID
        self.flags = 0
        self.key: int | None = None  # election key (kilonet.protocols.localize.phase1_election)
        self.echo = False
        # Two candidate positions (kilonet.protocols.localize.phase2_spread): (version, [p0, p1]) or
        # None, and whether they come from three or more anchors on one line (CAND's FROM_LINE).
        self.candidates: tuple[int, list] | None = None
        self.candidates_from_line = False
        self.near: set[int] = set()  # the IDs this neighbour's NBR reports were about

    @property
    def range_mm(self) -> float:
        """The distance both ends fit
        (:func:`~kilonet.protocols.common.refinement.agreed_range_mm`), mm."""
        return agreed_range_mm(self.distance_sum_mm / self.samples, self.sent_mm, self.reported_mm)

    @property
    def position(self) -> tuple[float, float] | None:
        """Its announced position, or None."""
        return None if self.x_mm is None else (self.x_mm, self.y_mm)


class Neighbours(NeighbourTable[Neighbour]):
    """A robot's neighbour records by ID
    (:class:`~kilonet.protocols.common.neighbours.NeighbourTable`, its duplicate test and ageing
    on), each a ``localize`` :class:`Neighbour`; the robot sets ``duplicate_mm`` from the noise it
    measures."""

    record_type = Neighbour

    def report(self, n: Neighbour, code: int) -> None:
        """Store ``n``'s DIST report of its distance to this robot (its code)."""
        n.reported_mm = unwrap_distance(code, n.distance_sum_mm / n.samples)


def distance_report(uid: int, position: tuple[float, float] | None, n: Neighbour) -> Message:
    """This robot's report of its mean distance to ``n``: NBR without a position, else DIST.
    Stamps ``n.sent_mm`` with the value as ``n`` will decode it (``n.sent_round`` is the
    caller's).

    Examples
    --------
    >>> n = Neighbour(9)
    >>> n.distance_sum_mm, n.samples = 123.4, 2
    >>> NBR.unpack(distance_report(5, None, n))
    Nbr(sender=5, neighbour=9, distance_mm=61.7)
    >>> m = DIST.unpack(distance_report(5, (10.0, -2.5), n))
    >>> m.x_mm, m.y_mm, m.neighbour, round(unwrap_distance(m.distance, near_mm=61.0), 6)
    (10.0, -2.5, 9, 61.7)
    """
    if position is None:
        n.sent_mm = round(n.mean_mm, 2)
        return NBR.pack(sender=uid, neighbour=n.uid, distance_mm=n.mean_mm)
    n.sent_mm = round(n.mean_mm / DISTANCE_STEP_MM) * DISTANCE_STEP_MM
    x_mm, y_mm, _ = wrapped_position(*position)
    return DIST.pack(
        sender=uid,
        x_mm=x_mm,
        y_mm=y_mm,
        neighbour=n.uid,
        distance=distance_code(n.mean_mm),
    )


def _wrap(v_mm: float) -> tuple[float, int]:
    tenths = round(v_mm / 0.1)  # as Layout rounds a 0.1 mm field
    winding = (tenths + _HALF_PERIOD_TENTHS) // _PERIOD_TENTHS
    return (tenths - winding * _PERIOD_TENTHS) / 10.0, winding


def wrapped_position(x_mm: float, y_mm: float) -> tuple[float, float, int]:
    """A position as messages carry it: x and y modulo :data:`COORDINATE_PERIOD_MM`, each in
    [-3276.8, 3276.7] mm (0.1 mm steps, an int16 field), and the byte of both winding
    numbers (x in the low nibble, y in the high one, signed 4-bit). Coordinates beyond
    :data:`MAX_COORDINATE_MM` are the caller's to refuse; their windings wrap.

    Examples
    --------
    >>> wrapped_position(12.34, -5.0)
    (12.3, -5.0, 0)
    >>> wrapped_position(3297.6, -4000.0)  # the 5 m corridor's overflow, and its mirror
    (-3256.0, 2553.6, 241)
    >>> [round(v, 6) for v in absolute_position(-3256.0, 2553.6, 241)]
    [3297.6, -4000.0]
    """
    wx, kx = _wrap(x_mm)
    wy, ky = _wrap(y_mm)
    return wx, wy, (kx & 15) | (ky & 15) << 4


def absolute_position(x_mm: float, y_mm: float, windings: int) -> tuple[float, float]:
    """The position a message's wrapped ``x_mm``, ``y_mm`` and winding byte stand for, mm
    (the inverse of :func:`wrapped_position`, to 0.1 mm; with no winding, the coordinates
    as they came)."""
    kx, ky = windings & 15, windings >> 4
    kx -= 16 if kx > _MAX_WINDING else 0
    ky -= 16 if ky > _MAX_WINDING else 0
    return x_mm + kx * COORDINATE_PERIOD_MM, y_mm + ky * COORDINATE_PERIOD_MM


def unwrap_coordinate(wrapped_mm: float, near_mm: float) -> float:
    """The coordinate equal to ``wrapped_mm`` modulo :data:`COORDINATE_PERIOD_MM` that lies
    nearest ``near_mm`` (a position the receiver knows within 3.2 m of the sender: its own, or
    the sender's last), mm. Messages without winding numbers (DIST, ISLAND_LINK) are read so.

    Examples
    --------
    >>> round(unwrap_coordinate(-3256.0, 3200.0), 6), unwrap_coordinate(-3256.0, -3000.0)
    (3297.6, -3256.0)
    >>> round(unwrap_coordinate(100.0, 13200.0), 6)
    13207.2
    """
    return wrapped_mm + round((near_mm - wrapped_mm) / COORDINATE_PERIOD_MM) * COORDINATE_PERIOD_MM


def choose_parent(current: int, hops: int, neighbours: Iterable[Neighbour]) -> int:
    """The neighbour a robot ``hops`` from the root reports to in the convergecasts (the
    election's echo, the settled wave): of the ``neighbours`` one hop nearer the root, the one
    heard most often — the strongest link, so the two ends hear each other soonest. The
    ``current`` parent stays while it is one hop nearer and heard at least half as often as
    the best, so two links of about the same strength do not take turns. ``NO_ID`` for the
    root, or with no neighbour one hop nearer.

    Examples
    --------
    >>> a, b, c = Neighbour(1), Neighbour(2), Neighbour(3)
    >>> (a.hops, a.samples), (b.hops, b.samples), (c.hops, c.samples) = (1, 8), (1, 12), (2, 30)
    >>> choose_parent(NO_ID, 2, [a, b, c]), choose_parent(1, 2, [a, b, c])
    (2, 1)
    >>> b.samples = 17  # more than twice a's receptions: the stronger link takes over
    >>> choose_parent(1, 2, [a, b, c]), choose_parent(2, 0, [a, b, c]) == NO_ID
    (2, True)
    """
    if hops == 0:
        return NO_ID
    nearer = hops - 1
    best = kept = None
    for n in neighbours:
        if n.hops == nearer:
            if best is None or n.samples > best.samples:
                best = n
            if n.uid == current:
                kept = n
    if best is None:
        return NO_ID
    if kept is not None and 2 * kept.samples >= best.samples:
        return current
    return best.uid


def toward_root(hops: int, parent: int, neighbours: Iterable[Neighbour]) -> tuple[int, int]:
    """A robot's hop count to the root and its parent after a round of phases 2-3, from what
    its ``neighbours`` (those heard recently) last announced in the frame's messages. Only a
    neighbour that hears this robot counts — one that has reported its distance to it
    (``reported_mm``, from NBR or DIST). The count only falls, to one more than the least
    such a neighbour announces; the parent is :func:`choose_parent`'s choice among them, or
    the current one while none of them is one hop nearer.

    The convergecasts climb the parents, so they wait for every robot only if following
    parents from any robot reaches the root, each parent counting its child. Two rules make
    sure of it:

    * *Every parent is nearer the root than its child.* Counts never rise, so a robot's
      record of a neighbour's count is never below that neighbour's count now, and a
      neighbour taken for a parent at ``hops - 1`` is at most that far: parents form no
      cycle. When the count was recomputed every round it rose whenever a nearer neighbour
      went unheard for ``stale_s``, robots took each other for parents from records older
      than the rise, and a cycle and every robot below it were waited for by no robot on
      the root's side.
    * *A parent hears its child.* Near ``neighbour_max_mm`` one end of a link often ranges
      the other beyond it and ignores it
      (:func:`~kilonet.protocols.common.ranging_limit.trusted_range`), and a parent that never hears
      its child cannot count it.

    The root (0 hops) has no parent.

    Examples
    --------
    A robot 5 hops out whose parent (4 hops) has fallen silent keeps both its count and its
    parent, though a sibling (5 hops) would make it 6 — and the sibling may be its own child:

    >>> parent, sibling = Neighbour(1), Neighbour(2)
    >>> (parent.hops, parent.samples), (sibling.hops, sibling.samples) = (4, 10), (5, 40)
    >>> parent.reported_mm = sibling.reported_mm = 60.0  # both hear it
    >>> toward_root(5, 1, [sibling]), toward_root(5, 1, [parent, sibling])
    ((5, 1), (5, 1))

    A neighbour nearer the root lowers the count and becomes the parent, if it hears this
    robot; the root stays put:

    >>> sibling.hops = 3
    >>> toward_root(5, 1, [parent, sibling]), toward_root(0, NO_ID, [parent, sibling])
    ((4, 2), (0, 65535))
    >>> sibling.reported_mm = None  # it has never reported hearing this robot
    >>> toward_root(5, 1, [parent, sibling])
    (5, 1)
    """
    if hops == 0:
        return 0, NO_ID
    hearing = [n for n in neighbours if n.reported_mm is not None]
    hops = min(hops, MAX_HOPS, 1 + min((n.hops for n in hearing), default=MAX_HOPS))
    nearer = choose_parent(parent, hops, hearing)
    return hops, parent if nearer == NO_ID else nearer


def children_complete(
    uid: int, neighbours: Iterable[Neighbour], complete: Callable[[Neighbour], object]
) -> bool:
    """Whether every neighbour that names robot ``uid`` its parent (:func:`choose_parent`) is
    ``complete``: the step of a convergecast over the tree of parents, which the election's
    echo and the termination's settled wave both climb. Only its children hold a robot up, not
    every neighbour one hop farther out: a robot at the edge of two ranges would otherwise
    wait for the weakest of many links at every hop.

    Examples
    --------
    >>> a, b = Neighbour(1), Neighbour(2)
    >>> a.parent, b.parent = 7, 3
    >>> children_complete(3, [a, b], lambda n: n.echo), children_complete(9, [a, b], lambda n: 0)
    (False, True)
    >>> b.echo = True
    >>> children_complete(3, [a, b], lambda n: n.echo)
    True
    """
    return all(n.parent != uid or complete(n) for n in neighbours)
