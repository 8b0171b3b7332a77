"""Shared parts of the global-coordinate-system program: its parameters, the layout of its
messages, and the phase interface each phase module implements.

Phases follow one another on every robot's clock (``kilo_ticks``), as the thesis's counters do:
the overhead controller starts all robots together, so fixed windows keep the swarm in step
without any message. Inside its window each phase runs its own message protocol, and a robot
that has nothing to say stays silent (which keeps the channel free for those that do).

The phases, in order, are one list, :data:`SEQUENCE`: each one's stage name and the class that
runs it. :class:`GcsStage`, :data:`PHASES` (``gcs.until``'s choices) and
:data:`kilonet.protocols.gcs.program.PHASE_SEQUENCE` all derive from it. A phase's window has its
parameter in :class:`GcsParams`, here too.

Every message starts with the sender's 16-bit ID field (values drawn from ``id_bits`` bits), so
each reception also refines the distance table (:mod:`kilonet.protocols.common.neighbours`): layouts
are built with :func:`gcs_layout`, which puts that field first, and :func:`sender_of` reads it from
any of them.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from kilonet.message import Layout, Message
from kilonet.params import param
from kilonet.protocols.common.layouts import ProtocolLayouts
from kilonet.protocols.common.phases import Phase as BasePhase
from kilonet.protocols.common.phases import Stage

if TYPE_CHECKING:
    from collections.abc import Callable

    from kilonet.protocols.gcs.program import GcsRobot

__all__ = [
    "LAYOUTS",
    "PHASES",
    "SENDER",
    "SEQUENCE",
    "GcsParams",
    "GcsStage",
    "Phase",
    "gcs_layout",
    "sender_of",
]


#: The protocol's phases in the order they run: the thesis's six, then kilonet's refinement
#: (phase 7). Each is its stage's name and the class that runs it (``module:Class`` in this
#: package, imported when a robot program is built, so that listing the parameters imports no
#: phase). To add a phase, add its line here and its window's parameter to :class:`GcsParams`.
SEQUENCE: tuple[tuple[str, str], ...] = (
    ("ids", "phase1_unique_ids:UniqueIds"),
    ("seeds", "phase2_seed_election:SeedElection"),
    ("frames", "phase3_local_frames:LocalFrames"),
    ("localization", "phase4_localization:Localization"),
    ("groups", "phase5_merging_groups:MergingGroups"),
    ("merge", "phase6_merging:FrameMerging"),
    ("refine", "phase7_refinement:GlobalRefinement"),
)

#: The protocol's stages, one per phase of :data:`SEQUENCE`, in its order (``GcsStage.IDS`` is
#: ``"ids"``): what each phase class names as its own (``name``).
GcsStage = Stage("GcsStage", [(name.upper(), name) for name, _ in SEQUENCE], module=__name__)

#: Phase names in order; ``gcs.until`` names the last one to run. The refinement runs only
#: when ``gcs.refine`` is on or ``gcs.until`` names it
#: (:func:`kilonet.protocols.gcs.program.phase_sequence`).
PHASES = GcsStage.names()


@dataclass(frozen=True)
class GcsParams:
    """Parameters of the global-coordinate-system protocol (section ``gcs``)."""

    section_name = "gcs"
    until: Literal[PHASES] = param("merge", doc="last phase to run")
    id_bits: int = param(8, lo=2, hi=15, doc="random IDs are drawn from this many bits")
    neighbour_max_mm: float = param(
        85.0,
        lo=33.0,
        hi=255.0,
        doc="a reception with a larger distance estimate is ignored: its sender is no neighbour "
        "(the thesis's range; estimates saturate beyond kilolib's tables)",
    )
    # Windows: lossless runs with a margin; a lossy channel needs longer ones (block gcs-windows
    # of docs/results/gcs.md: how much of each window the robots use).
    ids_s: float = param(8.0, lo=0.5, hi=600.0, doc="phase 1 window")
    duplicate_distance_mm: float = param(
        12.0, lo=1.0, hi=200.0, doc="one ID heard at distances this far apart is two robots"
    )
    elect_s: float = param(3.0, lo=0.5, hi=600.0, doc="top and each bottom election window")
    check_s: float = param(2.0, lo=0.5, hi=600.0, doc="seed check window after each election")
    reelections: int = param(5, lo=0, hi=50, doc="bottom re-elections at most")
    frames_s: float = param(30.0, lo=1.0, hi=3600.0, doc="phase 3 window")
    ask_timeout_s: float = param(2.0, lo=0.2, hi=60.0, doc="seed skips a silent neighbour")
    busy_reset_s: float = param(3.0, lo=0.2, hi=60.0, doc="a busy neighbour resets itself")
    ask_attempts: int = param(2, lo=1, hi=20, doc="times a seed tries each neighbour")
    reference_rule: Literal["max_angle", "best_conditioned"] = param(
        "max_angle", doc="how a seed picks its two references"
    )
    localization_s: float = param(15.0, lo=1.0, hi=3600.0, doc="phase 4 window")
    max_rmse_mm: float = param(4.0, lo=0.1, hi=100.0, doc="reject fixes with larger residuals")
    sigma_mm: float = param(
        2.5,
        lo=0.01,
        hi=100.0,
        doc="ranging error the robots assume when judging a fix (real robots: a few mm per "
        "link that averaging cannot remove)",
    )
    groups_s: float = param(3.0, lo=0.5, hi=3600.0, doc="phase 5 window")
    min_group_width_mm: float = param(
        15.0, lo=0.0, hi=200.0, doc="thinnest merging-group triangle accepted"
    )
    merge_round_s: float = param(4.0, lo=0.5, hi=600.0, doc="time-out of one merging round")
    merge_max_rounds: int = param(400, lo=1, hi=100_000, doc="rounds a seed runs at most")
    merge_tolerance_mm: float = param(
        4.0, lo=0.01, hi=100.0, doc="a seed agrees with its parent within this (map motion)"
    )
    merge_stable_rounds: int = param(4, lo=1, hi=1000, doc="agreeing rounds before done")
    merge_silent_rounds: int = param(
        3,
        lo=1,
        hi=1000,
        doc="unanswered rounds after which a partner never heard from stops holding up done",
    )
    merge_member: Literal["random", "fixed"] = param(
        "random",
        doc="member asked about a partner: a new one each round, or one kept while it answers",
    )
    merge_whole_step_mm: float = param(
        16.0,
        lo=0.0,
        hi=1000.0,
        doc="a seed steps the whole way toward a parent that disagrees by more (128+: never)",
    )
    # A done seed keeps stepping toward its parent either way; the rule decides only when it
    # drops its done mark (docs/gcs.md, "Done, resumed, given up").
    merge_resume: Literal["far", "drift"] = param(
        "far",
        doc="a done seed resumes on a better rank or two parent answers in a row beyond "
        "merge_whole_step_mm (far), or also on one beyond it or two beyond "
        "merge_tolerance_mm (drift)",
    )
    check_tolerance_mm: float = param(
        8.0, lo=0.1, hi=1000.0, doc="measured and computed neighbour distances agree within this"
    )
    # Long enough for the flooding root to cross a region that settled on a local root first
    # (their boundary looks like a split until it has).
    split_confirm_s: float = param(
        40.0, lo=0.5, hi=3600.0, doc="a split boundary must persist this long to act on it"
    )
    # The fold rule (kilonet.protocols.gcs.fold_rule): on, so that no final frame holds a robot
    # its neighbours disagree with beyond the ranging error. The confirm time: several POS from
    # each neighbour (about one a second each), longer than the 5 s after which a silent
    # neighbour's flag lapses, so a disagreement seen while merging still moves the frame is
    # not acted on.
    fold: bool = param(
        True, doc="a robot its same-frame neighbours disagree with is re-placed or leaves the frame"
    )
    fold_confirm_s: float = param(
        10.0, lo=0.5, hi=3600.0, doc="the fold rule acts on a disagreement that lasts this long"
    )
    recoveries: int = param(2, lo=0, hi=20, doc="recovery epochs (edge seeds, phases 3-6) at most")
    recover_flood_s: float = param(
        20.0, lo=1.0, hi=600.0, doc="a recovery epoch starts this long after it is requested"
    )
    # Phase 7 (kilonet.protocols.gcs.phase7_refinement): off in the thesis's pipeline.
    refine: bool = param(False, doc="refine the merged estimates after merging (phase 7)")
    refine_after_s: float = param(
        5.0, lo=0.0, hi=3600.0, doc="a robot refines once its estimate has been settled this long"
    )
    refine_round_s: float = param(0.2, lo=0.01, hi=10.0, doc="a refining robot steps this often")
    refine_momentum: float = param(
        0.5, lo=0.0, hi=0.99, doc="share of its previous step a refinement step adds"
    )
    refine_settle_mm: float = param(
        0.1, lo=0.0, hi=100.0, doc="settled: moved less than this over refine_settle_rounds"
    )
    refine_settle_rounds: int = param(
        10, lo=1, hi=10_000, doc="rounds the refinement's settle test looks back"
    )
    refine_timeout_s: float = param(
        120.0, lo=1.0, hi=86_400.0, doc="a refining robot stops after this anyway"
    )


#: Every message layout of the protocol, by type byte: :func:`gcs_layout` registers each, so a
#: type byte used twice fails at import (:mod:`kilonet.protocols.common.layouts`).
LAYOUTS = ProtocolLayouts("gcs")

#: The field every message of the protocol starts with: the sender's ID (uint16).
_SENDER_FIELD = ("sender", "H")
#: That field's wire form, for reading it from any message (:func:`sender_of`).
SENDER = struct.Struct("<" + _SENDER_FIELD[1])


def gcs_layout(
    name: str,
    *,
    type: int,
    fields: list[tuple[str, str] | tuple[str, str, float]],
    register: ProtocolLayouts | None = LAYOUTS,
) -> Layout:
    """A message layout of the protocol: the sender's ID (``sender``, uint16) and then
    ``fields`` (as :class:`kilonet.message.Layout` takes them), registered in ``register``
    (the protocol's :data:`LAYOUTS`; ``None``: not registered).

    Raises
    ------
    kilonet.message.PayloadError
        If the sender and ``fields`` take more than the 9-byte payload.
    kilonet.protocols.common.layouts.LayoutClash
        If another layout of the protocol uses type byte ``type``.

    Examples
    --------
    >>> HELLO = gcs_layout("hello", type=99, fields=[("hops", "B")], register=None)
    >>> message = HELLO.pack(sender=513, hops=2)
    >>> len(message.data), sender_of(message)
    (3, 513)
    """
    layout = Layout(name, type=type, fields=[_SENDER_FIELD, *fields])
    return layout if register is None else register.add(layout)


def sender_of(message: Message) -> int:
    """The sender's ID of any message built by a :func:`gcs_layout` layout (the receptions'
    hot path calls ``SENDER.unpack_from(message.data)`` itself, saving a Python call)."""
    return SENDER.unpack_from(message.data)[0]


class Phase(BasePhase):
    """One phase of the protocol on one robot (:class:`kilonet.protocols.common.phases.Phase`).

    A subclass sets ``name`` (a :class:`GcsStage`, or recovery's
    :class:`~kilonet.protocols.gcs.recovery.RecoveryStage`), ``open_ended = True`` if its window
    never closes (it ends by itself), defines :meth:`window_s` and overrides the callbacks it uses;
    :class:`kilonet.protocols.gcs.program.GcsRobot` creates it, with the tick its window closes
    (``until``), when the phase before hands on to it (:meth:`following`), and its driver calls
    :meth:`start`, then the callbacks, then :meth:`finish`.
    """

    __slots__ = ("__dict__", "params", "robot", "until")  # see GcsRobot.__slots__

    def __init__(self, robot: GcsRobot) -> None:
        self.robot = robot
        self.params: GcsParams = robot.params
        self.until = math.inf  # the robot's plan sets its window (GcsRobot.next_phase)

    #: ``window_s(p: GcsParams) -> float``, a static method every phase defines: the length of
    #: its window for parameters ``p``, s (``inf``: it never closes; an open-ended phase's
    #: window, if finite, is a time-out).
    window_s: Callable[[GcsParams], float]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if not callable(getattr(cls, "window_s", None)):
            raise TypeError(f"phase {cls.__name__} must define window_s(params) -> float")

    def following(self) -> Phase | None:
        """The next phase of the robot's plan, with its window
        (:meth:`~kilonet.protocols.gcs.program.GcsRobot.next_phase`)."""
        return self.robot.next_phase()
