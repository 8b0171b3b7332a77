"""Rubenstein's global coordinate system, as one Kilobot program running six phases.

The phases (one module each) run in windows on the robot's own clock, in order:

1. :mod:`kilonet.protocols.gcs.phase1_unique_ids` — locally unique IDs;
2. :mod:`kilonet.protocols.gcs.phase2_seed_election` — top and bottom seed elections and the seed
check; 3. :mod:`kilonet.protocols.gcs.phase3_local_frames` — each seed's frame from two references;
4. :mod:`kilonet.protocols.gcs.phase4_localization` — trilateration into the frames of seeds in
view; 5. :mod:`kilonet.protocols.gcs.phase5_merging_groups` — groups of three robots located in the
   same two frames;
6. :mod:`kilonet.protocols.gcs.phase6_merging` — rounds of half-way transforms until partners agree;
7. :mod:`kilonet.protocols.gcs.phase7_refinement` — with ``gcs.refine = true`` only (not the
   thesis's): the merged estimates refined from neighbours' global positions and measured distances.
   Merging's window never closes, so a robot leaves it when merging reports itself finished for it
   (:meth:`~kilonet.protocols.gcs.base.Phase.finished`).

Alongside merging, :mod:`kilonet.protocols.gcs.split_detection` checks the merged frame against
measured distances, and :mod:`kilonet.protocols.gcs.recovery` answers a split that persists with a
recovery epoch: edge seeds (phase ``edges``) and phases 3-6 again (and 7, when it runs), at most
``gcs.recoveries`` times.

``gcs.until`` stops the program after a phase. The robot's state that phases share lives on
:class:`GcsRobot` (its ID, neighbour table, seeds in view, groups and partners, and its
:class:`~kilonet.protocols.gcs.global_estimate.GlobalEstimate`: local positions, transforms, ranks);
phases hold their own working state. LED (:func:`led_colour`): phase 1 white, 2 blue (seeds red),
3 references yellow, located robots green, merged robots cyan.

The robot holds its phases in a :class:`~kilonet.protocols.common.phases.PhaseDriver`: the
running phase, the receive handlers by message type byte (RECOVER in every phase, merging's POS
for the split check) and every transition. The windows still to come are the robot's plan; a
phase hands on to the next one with its window (:meth:`GcsRobot.next_phase`) when its own closes,
or, for a window that never closes, when the phase reports itself
:meth:`~kilonet.protocols.gcs.base.Phase.finished` (asked from ``loop()``). A recovery epoch
plans anew and moves the running phase's close.

To add a phase (two files): write its module, a :class:`~kilonet.protocols.gcs.base.Phase`
subclass naming its stage (``name = GcsStage.X``), with a ``window_s`` that reads its window's
parameter and the callbacks it needs; then, in :mod:`kilonet.protocols.gcs.base`, add its line
(stage name and ``module:Class``) to :data:`~kilonet.protocols.gcs.base.SEQUENCE` at its place,
which makes its stage, its ``gcs.until`` choice and its place in :data:`PHASE_SEQUENCE`, and its
window's parameter to :class:`~kilonet.protocols.gcs.base.GcsParams`. A recovery epoch runs it
again only if :data:`RECOVERY_SEQUENCE` lists it too. A phase after one whose window never closes
starts when that phase's :meth:`~kilonet.protocols.gcs.base.Phase.finished` says so.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Mapping
from dataclasses import dataclass

from kilonet.message import Message
from kilonet.protocols.common.neighbours import NeighbourTable
from kilonet.protocols.common.phases import PhaseDriver
from kilonet.protocols.common.ranging_limit import trusted_range
from kilonet.protocols.gcs.base import SENDER, SEQUENCE, GcsParams, GcsStage, Phase
from kilonet.protocols.gcs.frame_keys import FrameKey, Root
from kilonet.protocols.gcs.global_estimate import GlobalEstimate
from kilonet.protocols.gcs.phase3_local_frames import LocalFrames
from kilonet.protocols.gcs.phase4_localization import Localization
from kilonet.protocols.gcs.phase5_merging_groups import MergingGroups
from kilonet.protocols.gcs.phase6_merging import FrameMerging
from kilonet.protocols.gcs.phase7_refinement import GlobalRefinement
from kilonet.protocols.gcs.recovery import RECOVER, EdgeSeeds, RecoveryFlood
from kilonet.protocols.gcs.split_detection import SplitCheck
from kilonet.robot import Kilobot

__all__ = [
    "OPEN_ENDED",
    "PHASE_SEQUENCE",
    "RECOVERY_SEQUENCE",
    "GcsRobot",
    "RobotOutcome",
    "led_colour",
    "phase_sequence",
    "phase_windows_s",
]


def _phase_class(name: str, path: str) -> type[Phase]:
    """The class ``path`` (``module:Class`` in this package) that runs phase ``name``, as
    :data:`kilonet.protocols.gcs.base.SEQUENCE` names them.

    Raises
    ------
    TypeError
        If it is no phase, or runs another stage than ``name``.
    """
    module, _, attribute = path.partition(":")
    cls = getattr(importlib.import_module(f"{__package__}.{module}"), attribute)
    if not (isinstance(cls, type) and issubclass(cls, Phase)) or cls.name != name:
        raise TypeError(f"gcs SEQUENCE: {path} is no phase of stage {name!r}")
    return cls


#: The phases in the order they run: the classes of :data:`kilonet.protocols.gcs.base.SEQUENCE`.
PHASE_SEQUENCE: tuple[type[Phase], ...] = tuple(_phase_class(*entry) for entry in SEQUENCE)
#: gcs_base.sender_of without its Python call: every reception reads the sender, so the call
#: would sit on the path of every reception (docs/gcs.md, "Speed").
_read_sender = SENDER.unpack_from
#: What a recovery epoch runs: edge seeds, then phases 3-6 again (and the refinement after them
#: when the run refines, :func:`phase_sequence`).
RECOVERY_SEQUENCE: tuple[type[Phase], ...] = (
    EdgeSeeds,
    LocalFrames,
    Localization,
    MergingGroups,
    FrameMerging,
)
#: The phases that end by themselves (``open_ended``), not when their window closes.
OPEN_ENDED = frozenset(cls.name for cls in (*PHASE_SEQUENCE, *RECOVERY_SEQUENCE) if cls.open_ended)


def phase_sequence(p: GcsParams) -> tuple[type[Phase], ...]:
    """The phases a run with parameters ``p`` runs: up to ``p.until``, the refinement only when
    ``p.refine`` is on (and ``p.until`` is merge) or ``p.until`` names it.

    Examples
    --------
    >>> [str(cls.name) for cls in phase_sequence(GcsParams(until="frames", refine=True))]
    ['ids', 'seeds', 'frames']
    >>> [str(cls.name) for cls in phase_sequence(GcsParams(refine=True))][-2:]
    ['merge', 'refine']
    >>> phase_sequence(GcsParams())[-1].name, phase_sequence(GcsParams(until="refine"))[-1].name
    (<GcsStage.MERGE: 'merge'>, <GcsStage.REFINE: 'refine'>)
    """
    last = GcsStage.REFINE if p.refine and p.until == GcsStage.MERGE else p.until
    return PHASE_SEQUENCE[: [cls.name for cls in PHASE_SEQUENCE].index(last) + 1]


def phase_windows_s(p: GcsParams) -> list[tuple[str, float, float]]:
    """``(phase, start_s, end_s)`` of each phase of :func:`phase_sequence`; merging has no end
    (``inf``): it ends when the seeds agree, and the refinement after it starts when merging
    is over for a robot (``inf`` here too).

    Examples
    --------
    >>> [str(name) for name, _, _ in phase_windows_s(GcsParams(until="frames"))]
    ['ids', 'seeds', 'frames']
    """
    out, t = [], 0.0
    for cls in phase_sequence(p):
        length = cls.window_s(p)
        out.append((cls.name, t, t + length))
        t += length
    return out


def _start_tick(ticks: float) -> float:
    """A window's first tick: whole ticks, or ``inf`` after a window that never closes."""
    return ticks if math.isinf(ticks) else round(ticks)


def led_colour(
    phase: str, *, seed: bool, merged: bool, located: bool, reference: bool
) -> tuple[int, int, int]:
    """The LED (kilolib levels 0-3) of a robot in phase ``phase`` ('' before the first and
    after the last): seeds red; phase 1 white; phase 2 blue; merged robots (done merging, or
    holding a global estimate while merging) cyan; located robots green; references yellow;
    others dim blue.

    Examples
    --------
    >>> led_colour("frames", seed=False, merged=False, located=False, reference=True)
    (3, 3, 0)
    """
    if seed:
        return (3, 0, 0)
    if phase in ("", GcsStage.IDS):
        return (1, 1, 1)
    if phase == GcsStage.SEEDS:
        return (0, 0, 2)
    if merged:
        return (0, 3, 3)
    if located:
        return (0, 3, 0)
    if reference:
        return (3, 3, 0)
    return (0, 0, 1)


@dataclass(frozen=True, slots=True)
class RobotOutcome:
    """What one robot ended a run with, read once from :meth:`GcsRobot.outcome`.

    Parameters
    ----------
    uid : int
        Its ID (phase 1).
    role : str
        ``"seed"``, ``"reference"`` or ``"robot"``.
    is_seed, edge_seed : bool
        Elected or edge seed (an edge seed is a seed too).
    own_key : FrameKey
        The key its own frame has (or would have, as a non-seed).
    has_frame : bool
        A seed that built its frame (chose its references).
    local_positions : Mapping[FrameKey, tuple[float, float]]
        Its position in each local frame it is located in, mm.
    groups : tuple of (FrameKey, FrameKey)
        The frame pairs of its merging groups.
    isolated_seed : bool
        A seed no merging group was registered with.
    position : tuple[float, float] or None
        Its global estimate, mm: the refined one once it has refined (phase 7), else the
        merged one.
    merged_position : tuple[float, float] or None
        Its global estimate as merging left it, mm, with the fold rule's repair or split
        (:mod:`kilonet.protocols.gcs.split_detection`).
    refined : bool
        It refined its estimate (phase 7).
    root : Root or None
        The root of the merged frame its estimate (``position``) is in.
    merged_root : Root or None
        The root of the frame ``merged_position`` is in (the refinement may join another).
    split_boundary, inconsistent : bool
        What its split check flagged at the end (:mod:`kilonet.protocols.gcs.split_detection`).
    fold : str or None
        What the fold rule made of its merged estimate, where that still holds: ``"repaired"``
        or ``"split"`` (``None``: nothing, or the refinement's estimate replaced it).
    merge_done : bool
        A seed done merging.
    merge_rounds : int
        Rounds a seed ran in its latest merging phase (0 for others, or outside merging).
    epoch : int
        Recovery epochs it started.
    """

    uid: int
    role: str
    is_seed: bool
    edge_seed: bool
    own_key: FrameKey
    has_frame: bool
    local_positions: Mapping[FrameKey, tuple[float, float]]
    groups: tuple[tuple[FrameKey, FrameKey], ...]
    isolated_seed: bool
    position: tuple[float, float] | None
    merged_position: tuple[float, float] | None
    refined: bool
    root: Root | None
    merged_root: Root | None
    split_boundary: bool
    inconsistent: bool
    fold: str | None
    merge_done: bool
    merge_rounds: int
    epoch: int


class GcsRobot(Kilobot):
    """The global-coordinate-system program of one robot.

    Parameters
    ----------
    params : GcsParams
        The protocol's parameters (time-outs, rules, tolerances).
    """

    LED_KEY = (
        ((1, 1, 1), "phase 1: drawing IDs"),
        ((0, 0, 2), "phase 2: electing seeds"),
        ((3, 0, 0), "seed"),
        ((3, 3, 0), "reference of a seed's frame"),
        ((0, 0, 1), "not located yet"),
        ((0, 3, 0), "located in a local frame"),
        ((0, 3, 3), "global estimate (merged)"),
    )  # led_colour's rules

    # Its state, the phases' shared state included, in slots, as FrameMerging's and
    # SeedRounds': past 30 attributes an instance dict is no longer CPython's compact
    # shared-key kind, and every delivery and loop reads several attributes, robot after robot
    # (docs/gcs.md, "Speed").
    __slots__ = (
        "_loops",
        "_may_finish",
        "_neighbour_keys",
        "_plan",
        "_polled",
        "announced",
        "check",
        "driver",
        "edge_seed",
        "epoch",
        "estimate",
        "groups",
        "is_seed",
        "merge_done",
        "merging",
        "own_key",
        "params",
        "partners",
        "pos_turn",
        "recovery",
        "ref_turn",
        "references",
        "refined",
        "refined_root",
        "role",
        "salt",
        "seeds",
        "table",
        "uid",
    )

    def __init__(self, params: GcsParams) -> None:
        self.params = params

    def setup(self) -> None:
        self._polled = self.polled  # fixed for a run; loop() asks many times a second
        self.table = NeighbourTable()
        self.take_id(-1, 0)
        self._neighbour_keys: dict[int, FrameKey] = {}
        self.seeds: set[int] = set()
        self.is_seed = False
        self.role = "robot"
        self.estimate = GlobalEstimate()
        # A seed's references: (ID, x, y) in its frame, announced in turn.
        self.references: list[tuple[int, float, float]] = []
        self.ref_turn = 0
        self.pos_turn = 0
        # Phase 5: this robot's groups {(I, K): (Y, Z)}; a seed's partners {K: {members}}.
        self.groups: dict[tuple[FrameKey, FrameKey], tuple[int, int]] = {}
        self.partners: dict[FrameKey, set[int]] = {}
        self.merge_done = False  # a seed done merging (kilonet.protocols.gcs.phase6_merging)
        self.merging: FrameMerging | None = None  # the latest merging phase (phase 7 keeps it)
        # Checking and recovering (split_detection, recovery): the check runs while merging.
        self.check: SplitCheck | None = None
        self.recovery = RecoveryFlood(self)
        self.epoch = 0  # recovery epochs started so far
        self.edge_seed = False
        # Positions neighbours announced, by frame key then neighbour ID, mm.
        self.announced: dict[FrameKey, dict[int, tuple[float, float]]] = {}
        self.refined: tuple[float, float] | None = None  # phase 7's estimate, mm
        self.refined_root: Root | None = None  # and the frame it is in
        tps = self.ticks_per_s
        # The windows still to come, in ticks: (phase, first tick, tick the window closes).
        self._plan = [
            (cls, _start_tick(start * tps), end * tps)
            for cls, (_, start, end) in zip(
                phase_sequence(self.params), phase_windows_s(self.params), strict=True
            )
        ]
        self._may_finish = False
        self._loops = 0
        # RECOVER is heard in every phase; merging adds the split check's POS (its handlers).
        self.driver = PhaseDriver({RECOVER.type: self.recovery.message_rx}, entered=self._entered)
        self.driver.enter(self.next_phase())
        self._show()
        self._advance()

    # -- identity and frame keys ---------------------------------------------------------------
    def take_id(self, uid: int, salt: int) -> None:
        """This robot's ID and salt are now ``uid`` and ``salt`` (phase 1)."""
        self.uid, self.salt = uid, salt
        self.own_key = FrameKey(uid, salt)

    def learn_salts(self, salts: Mapping[int, int]) -> None:
        """The salts neighbours announced in phase 1, by ID: they name those neighbours'
        frames from now on (:meth:`frame_key`)."""
        self._neighbour_keys = {uid: FrameKey(uid, salt) for uid, salt in salts.items()}

    def frame_key(self, seed_uid: int) -> FrameKey:
        """The key of the frame of seed ``seed_uid``, a neighbour or this robot: its ID and its
        phase-1 salt (salt 0 for a robot not heard in phase 1)."""
        if seed_uid == self.uid:
            return self.own_key
        key = self._neighbour_keys.get(seed_uid)
        return FrameKey.from_wire(seed_uid, 0) if key is None else key

    # -- phases --------------------------------------------------------------------------------
    @property
    def phase(self) -> Phase | None:
        """The running phase (``None`` after the last phase asked for: the robot is silent)."""
        return self.driver.phase

    def next_phase(self) -> Phase | None:
        """The next phase of the plan (``None`` past the last), made with the tick its window
        closes (:attr:`~kilonet.protocols.common.phases.Phase.until`): when the phase after it
        starts, or its own end if it is the last. When the running phase reports itself
        finished before its window closes, the next window opens now, for its usual length;
        the windows after it keep their starts. The phases' :meth:`Phase.following`."""
        ticks, plan = self.kilo_ticks, self._plan
        if not plan:
            return None
        cls, _, end = plan.pop(0)
        if ticks < self.driver.until and self.driver.phase is not None:
            end = ticks + cls.window_s(self.params) * self.ticks_per_s
        phase = cls(self)
        phase.until = plan[0][1] if plan else end
        return phase

    def _entered(self, phase: Phase) -> None:
        """The driver enters ``phase``: it goes to the trace, and a window that never closes,
        with a phase after it, ends when the phase reports itself finished (asked in
        :meth:`loop`)."""
        self.log("phase", name=phase.name)
        self._may_finish = bool(self._plan) and self.driver.until == math.inf

    def _advance(self) -> None:
        """Move on from a phase whose window has closed (asked on every loop and transmit
        opportunity)."""
        driver, ticks = self.driver, self.kilo_ticks
        if ticks >= driver.until and driver.advance(ticks, ask=False) and driver.phase is not None:
            self._show()

    def schedule_recovery(self, epoch: int, start_tick: int) -> None:
        """Run recovery epoch ``epoch`` from ``start_tick``: the running phase (merging, or the
        refinement) ends there and :data:`RECOVERY_SEQUENCE` follows in windows of the usual
        lengths, the refinement after it when the run refines (see
        :mod:`kilonet.protocols.gcs.recovery`)."""
        self.epoch = epoch
        self.driver.reschedule(start_tick)
        refines = phase_sequence(self.params)[-1] is GlobalRefinement
        plan, t = [], start_tick
        for cls in (*RECOVERY_SEQUENCE, GlobalRefinement) if refines else RECOVERY_SEQUENCE:
            end = t + cls.window_s(self.params) * self.ticks_per_s
            plan.append((cls, _start_tick(t), end))
            t = end
        self._plan = plan

    def _show(self) -> None:
        name = self.phase_name
        merging = self.phase is not None and self.phase.open_ended
        merged = self.merge_done or (merging and self.estimate.root() is not None)
        self.set_color(
            *led_colour(
                name,
                seed=self.is_seed,
                merged=merged,
                located=bool(self.estimate.frames),
                reference=self.role == "reference",
            )
        )

    @property
    def phase_name(self) -> str:
        """Name of the running phase ('' once done)."""
        return self.driver.stage

    # -- what the run reads ----------------------------------------------------------------------
    def awaiting_recovery(self) -> bool:
        """A recovery epoch is announced, or this robot is merging on a split boundary that one
        may still be started for (``gcs.recoveries`` not used up). Only merging robots check
        for splits: a boundary flagged before the refinement's wave reached a robot stays on
        record, but nothing there requests a recovery for it."""
        check = self.check
        boundary = (
            check is not None
            and check.boundary_since is not None
            and self.phase_name == GcsStage.MERGE
        )
        return self.recovery.pending or (boundary and self.epoch < self.params.recoveries)

    def awaiting_fold(self) -> bool:
        """This robot is merging and the fold rule is about to act on it
        (:meth:`~kilonet.protocols.gcs.split_detection.SplitCheck.awaiting_fold`)."""
        check = self.check
        return check is not None and self.phase_name == GcsStage.MERGE and check.awaiting_fold()

    def _merged(self) -> tuple[tuple[float, float], Root] | None:
        """The global position, mm, and root merging leaves this robot with: its merged
        estimate, or what the fold rule made of it
        (:meth:`~kilonet.protocols.gcs.split_detection.SplitCheck.held`)."""
        if self.check is not None:
            return self.check.held()
        position = self.estimate.position()
        return None if position is None else (position, self.estimate.root())

    @property
    def merge_done_at_s(self) -> float | None:
        """When this seed was done merging, s on its clock (``None`` unless it is done)."""
        seed = self.phase.seed if isinstance(self.phase, FrameMerging) else None
        if seed is None or seed.done_since is None:
            return None
        return seed.done_since / self.ticks_per_s

    def position_estimate(self) -> tuple[float, float, str] | None:
        """The global estimate now and the merged frame it is in (:attr:`Root.label`), for the
        run's estimates table; ``None`` before the robot has one."""
        if self.refined is not None:
            return (*self.refined, self.refined_root.label)
        merged = self._merged()
        return None if merged is None else (*merged[0], merged[1].label)

    def outcome(self) -> RobotOutcome:
        """What this robot holds now, as one value (see :class:`RobotOutcome`)."""
        estimate, check = self.estimate, self.check
        merged, merged_root = self._merged() or (None, None)
        position, root = (
            (merged, merged_root) if self.refined is None else (self.refined, self.refined_root)
        )
        seed = self.phase.seed if isinstance(self.phase, FrameMerging) else None
        return RobotOutcome(
            uid=self.uid,
            role=self.role,
            is_seed=self.is_seed,
            edge_seed=self.edge_seed,
            own_key=self.own_key,
            has_frame=bool(self.references),
            local_positions=dict(estimate.frames),
            groups=tuple(self.groups),
            isolated_seed=self.is_seed and not self.partners,
            position=position,
            merged_position=merged,
            refined=self.refined is not None,
            root=root,
            merged_root=merged_root,
            split_boundary=check is not None and check.on_split_boundary,
            inconsistent=check is not None and bool(check.inconsistent),
            fold=check.fold.action if check and check.fold and self.refined is None else None,
            merge_done=self.merge_done,
            merge_rounds=seed.rounds if seed is not None else 0,
            epoch=self.epoch,
        )

    # -- kilolib callbacks ---------------------------------------------------------------------
    def loop(self) -> None:
        self._advance()
        if self._polled:
            self.drain_messages()
        phase = self.driver.phase
        if phase is not None:
            phase.loop()
            if self._may_finish and self.driver.advance(self.kilo_ticks):
                self._show()
            check = self.check
            merging = phase.name == GcsStage.MERGE
            # Without a boundary wants_recovery() is False: most loops ask nothing more.
            boundary = merging and check and check.boundary_since is not None
            if boundary and not self.recovery.pending and check.wants_recovery():
                self.recovery.request()
            if merging and check and check.outlier_since is not None:
                check.fold_step()
            self._loops += 1
            if self._loops % 16 == 0:  # refresh the LED now and then, not every loop
                self._show()

    def message_tx(self) -> Message | None:
        self._advance()
        flood = self.recovery.message_tx()
        if flood is not None:
            return flood
        phase = self.driver.phase
        if phase is None:
            return None
        # While merging, the check takes its turn first (one opportunity in a few, once
        # settled): seeds always have something of their own to send.
        message = None
        if self.check is not None and phase.name == GcsStage.MERGE:
            message = self.check.message_tx()
        return message if message is not None else phase.message_tx()

    def message_rx(self, message: Message, distance_mm: int) -> None:
        driver = self.driver
        phase = driver.phase
        if phase is None or not trusted_range(distance_mm, self.params.neighbour_max_mm):
            return  # a robot measured beyond the neighbourhood is none of its neighbours
        # Recovery floods and the split check's POS are rare: the driver's table by type byte,
        # not a call per message.
        handler = driver.handler(message.type)
        if handler is not None:
            handler(message)
        phase.message_rx(message, distance_mm)
        (sender,) = _read_sender(message.data)
        if sender != self.uid:
            self.table.heard(sender, distance_mm)
