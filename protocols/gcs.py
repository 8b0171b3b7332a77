"""Rubenstein's global coordinate system, as one Kilobot program running six phases.

The phases (one module each) run in windows on the robot's own clock, in order:

1. :mod:`protocols.unique_ids` — locally unique IDs;
2. :mod:`protocols.seed_election` — top and bottom seed elections and the seed check;
3. :mod:`protocols.local_frames` — each seed's frame from two references;
4. :mod:`protocols.localization` — trilateration into the frames of seeds in view;
5. :mod:`protocols.merging_groups` — groups of three robots located in the same two frames;
6. :mod:`protocols.frame_merging` — rounds of half-way transforms until partners agree.

Alongside merging, :mod:`protocols.split_detection` checks the merged frame against measured
distances, and :mod:`protocols.recovery` answers a split that persists with a recovery epoch:
edge seeds (phase ``edges``) and phases 3-6 again, at most ``gcs.recoveries`` times.

``gcs.until`` stops the program after a phase. The robot's state that phases share lives on
:class:`GcsRobot` (its ID, neighbour table, seeds in view, local positions, transforms); phases
hold their own working state. LED: phase 1 white, 2 blue (seeds red), 3 references yellow,
located robots green, merged robots cyan.
"""

from __future__ import annotations

import struct

from kilonet.message import Message
from kilonet.robot import Kilobot
from protocols.frame_merging import FrameMerging
from protocols.gcs_base import PHASES, GcsParams, Phase
from protocols.local_frames import LocalFrames
from protocols.localization import Localization
from protocols.merging_groups import MergingGroups
from protocols.neighbours import NeighbourTable
from protocols.recovery import RECOVER, EdgeSeeds, RecoveryFlood
from protocols.seed_election import SeedElection
from protocols.split_detection import POS, SplitCheck
from protocols.unique_ids import UniqueIds

__all__ = ["GcsRobot", "phase_windows_s"]

_PHASE_CLASSES: tuple[type[Phase], ...] = (
    UniqueIds,
    SeedElection,
    LocalFrames,
    Localization,
    MergingGroups,
    FrameMerging,
)
#: Every message's first field, the sender's ID (uint16).
_SENDER = struct.Struct("<H").unpack_from
#: What a recovery epoch runs: edge seeds, then phases 3-6 again.
_RECOVERY_CLASSES: tuple[type[Phase], ...] = (
    EdgeSeeds,
    LocalFrames,
    Localization,
    MergingGroups,
    FrameMerging,
)


def phase_windows_s(p: GcsParams) -> list[tuple[str, float, float]]:
    """``(phase, start_s, end_s)`` of each phase up to ``p.until``; merging has no end
    (``inf``): it ends when the seeds agree.

    Examples
    --------
    >>> [name for name, _, _ in phase_windows_s(GcsParams(until="frames"))]
    ['ids', 'seeds', 'frames']
    """
    lengths = {
        "ids": p.ids_s,
        "seeds": SeedElection.duration_s(p),
        "frames": p.frames_s,
        "localization": p.localization_s,
        "groups": p.groups_s,
        "merge": float("inf"),
    }
    out, t = [], 0.0
    for name in PHASES[: PHASES.index(p.until) + 1]:
        out.append((name, t, t + lengths[name]))
        t += lengths[name]
    return out


class GcsRobot(Kilobot):
    """The global-coordinate-system program of one robot.

    Parameters
    ----------
    params : GcsParams
        The protocol's parameters (time-outs, rules, tolerances).
    """

    # Its state, the phases' shared state included, in slots: with more than 30 attributes an
    # instance dict is no longer CPython's compact shared-key kind, and every delivery and loop
    # reads several attributes, robot after robot. Slots here and in FrameMerging cut the CPU
    # time by 8 % at 300 robots and 2 % at 1,000, with identical results.
    __slots__ = (
        "_due_tick",
        "_frames_cache",
        "_loops",
        "_phase_index",
        "_polled",
        "_position_cache",
        "_windows",
        "announced",
        "check",
        "edge_seed",
        "epoch",
        "frames",
        "groups",
        "is_seed",
        "merge_done",
        "merge_state",
        "params",
        "partners",
        "phase",
        "pos_turn",
        "ranks",
        "recovery",
        "ref_turn",
        "references",
        "role",
        "salt",
        "salts",
        "seeds",
        "table",
        "transforms",
        "uid",
    )

    def __init__(self, params: GcsParams) -> None:
        self.params = params

    def setup(self) -> None:
        self._polled = self.polled  # fixed for a run; loop() asks many times a second
        self.table = NeighbourTable()
        self.uid = -1
        self.salt = 0
        self.salts: dict[int, int] = {}  # neighbours' salts from phase 1
        self.seeds: set[int] = set()
        self.is_seed = False
        self.role = "robot"
        # Local positions of this robot, by frame key (see frame_key), mm.
        self.frames: dict[int, tuple[float, float]] = {}
        # A seed's references: (ID, x, y) in its frame, announced in turn.
        self.references: list[tuple[int, float, float]] = []
        self.ref_turn = 0
        self.pos_turn = 0
        # Phase 5: this robot's groups {(I, K): (Y, Z)}; a seed's partners {K: {members}}.
        self.groups: dict[tuple[int, int], tuple[int, int]] = {}
        self.partners: dict[int, set[int]] = {}
        # Phase 6: transforms heard, by frame key (protocols.frame_merging.Transform).
        self.transforms: dict = {}
        self.ranks: dict[int, int] = {}  # merge rank of each seed heard (frame_merging)
        # Bumped by frame_merging whenever the transform or rank of a frame this robot is
        # located in is set anew: the global estimate (asked on every POS heard) is recomputed
        # only when this or the frames change.
        self.merge_state = 0
        self._frames_cache: tuple[tuple[int, int], tuple[int | None, list[int]]] = (
            (-1, -1),
            (None, []),
        )
        self._position_cache: tuple[tuple[int, int], tuple[float, float] | None] = ((-1, -1), None)
        self.merge_done = False
        # Checking and recovering (split_detection, recovery): the check runs while merging.
        self.check: SplitCheck | None = None
        self.recovery = RecoveryFlood(self)
        self.epoch = 0  # recovery epochs started so far
        self.edge_seed = False
        # Positions neighbours announced, by frame key then neighbour ID, mm.
        self.announced: dict[int, dict[int, tuple[float, float]]] = {}
        tps = self.ticks_per_s
        self._windows = [
            (cls, round(start * tps), end * tps)
            for cls, (_, start, end) in zip(
                _PHASE_CLASSES, phase_windows_s(self.params), strict=False
            )
        ]
        self._phase_index = -1
        self._loops = 0
        self.phase: Phase | None = None
        self._due_tick: float = 0
        self._advance()

    def _advance(self) -> None:
        ticks = self.kilo_ticks
        if ticks < self._due_tick:  # called on every loop and transmit opportunity
            return
        while (
            self._phase_index + 1 < len(self._windows)
            and ticks >= self._windows[self._phase_index + 1][1]
        ):
            if self.phase is not None:
                self.phase.finish()
            self._phase_index += 1
            cls = self._windows[self._phase_index][0]
            self.phase = cls(self)
            self.log("phase", name=cls.name)
            self.phase.start()
            self._show()
        if self.phase is not None and ticks >= self._windows[self._phase_index][2]:
            self.phase.finish()
            self.phase = None  # past the last phase asked for: the robot falls silent
        self._due_tick = self._next_window_change()

    def _next_window_change(self) -> float:
        """The tick at which the next phase starts or the running one ends."""
        i, windows = self._phase_index, self._windows
        start = windows[i + 1][1] if i + 1 < len(windows) else float("inf")
        end = windows[i][2] if self.phase is not None else float("inf")
        return min(start, end)

    def schedule_recovery(self, epoch: int, start_tick: int) -> None:
        """Run recovery epoch ``epoch`` from ``start_tick``: the running phase (merging) ends
        there and edge seeds, frames, localization, groups and merging follow in windows of
        the usual lengths (see :mod:`protocols.recovery`)."""
        self.epoch = epoch
        p = self.params
        lengths = (p.elect_s, p.frames_s, p.localization_s, p.groups_s, float("inf"))
        cls, start, _ = self._windows[self._phase_index]
        windows = [*self._windows[: self._phase_index], (cls, start, start_tick)]
        t = start_tick
        for cls, length in zip(_RECOVERY_CLASSES, lengths, strict=True):
            end = t + length * self.ticks_per_s
            windows.append((cls, round(t), end))
            t = end
        self._windows = windows
        self._due_tick = self._next_window_change()

    def _show(self) -> None:
        """LED by phase and role, as listed in the module docstring."""
        name = self.phase_name
        if self.is_seed:
            self.set_color(3, 0, 0)
        elif name in ("", "ids"):
            self.set_color(1, 1, 1)
        elif name == "seeds":
            self.set_color(0, 0, 2)
        elif self.merge_done or (name == "merge" and self.global_root is not None):
            self.set_color(0, 3, 3)
        elif self.frames:
            self.set_color(0, 3, 0)
        elif self.role == "reference":
            self.set_color(3, 3, 0)
        else:
            self.set_color(0, 0, 1)

    @property
    def phase_name(self) -> str:
        """Name of the running phase ('' once done)."""
        return self.phase.name if self.phase is not None else ""

    def loop(self) -> None:
        self._advance()
        if self._polled:
            while (received := self.get_message()) is not None:
                self.message_rx(*received)
        phase = self.phase
        if phase is not None:
            phase.loop()
            check = self.check
            merging = phase.name == "merge"
            if merging and check and not self.recovery.pending and check.wants_recovery():
                self.recovery.request()
            self._loops += 1
            if self._loops % 16 == 0:  # refresh the LED now and then, not every loop
                self._show()

    def frame_key(self, seed_uid: int) -> int:
        """The key of the frame of seed ``seed_uid``, a neighbour or this robot: its ID and its
        phase-1 salt. IDs are unique only among a robot's neighbours, so two seeds three hops
        apart may share one; with the salt, two frames are confused only if both match."""
        salt = self.salt if seed_uid == self.uid else self.salts.get(seed_uid, 0)
        return (seed_uid << 8) | salt

    def global_position(self) -> tuple[float, float] | None:
        """This robot's estimate in the merged frame, mm (None before it has one).

        Among the frames it is located in whose transform it holds, it keeps those of the
        smallest root (frames of another root have not been merged with them) and averages
        ``R_S (x, y, 0) + v_S`` over them; 2-D coordinates are those of the common plane laid
        flat by :func:`kilonet.alignment.level` (see :mod:`protocols.frame_merging`).
        """
        state = self.estimate_state
        if state == self._position_cache[0]:
            return self._position_cache[1]
        root, known = self.global_frames()
        if root is None:
            self._position_cache = (state, None)
            return None
        points = [self.transforms[k].apply_point(*self.frames[k]) for k in known]
        # Merged frames share one plane, tilted in general, but not one rotation (a frame that
        # was a mirror image faces the other way). Turning the plane's normal, taken on a fixed
        # side, onto +z depends on the plane alone, so every robot reads the same 2-D axes.
        row_x, row_y, _ = self.transforms[known[0]].flat.tolist()
        mean = [sum(c) / len(points) for c in zip(*points, strict=True)]
        position = (
            row_x[0] * mean[0] + row_x[1] * mean[1] + row_x[2] * mean[2],
            row_y[0] * mean[0] + row_y[1] * mean[1] + row_y[2] * mean[2],
        )
        self._position_cache = (state, position)
        return position

    @property
    def estimate_state(self) -> tuple[int, int]:
        """What the global estimate depends on, as a cache key: frames are only ever added,
        and ``merge_state`` moves with every transform or rank of a frame this robot is in."""
        return self.merge_state, len(self.frames)

    def global_frames(self) -> tuple[int | None, list[int]]:
        """The root of the merged frame this robot's estimate is in and the frames (keys, in
        order) that estimate uses: those it is located in whose transform and rank it holds,
        of the smallest root. ``(None, [])`` without an estimate."""
        state = self.estimate_state
        if state == self._frames_cache[0]:
            return self._frames_cache[1]
        self._frames_cache = (state, self._global_frames())
        return self._frames_cache[1]

    def _global_frames(self) -> tuple[int | None, list[int]]:
        known = [k for k in sorted(self.frames) if k in self.transforms and k in self.ranks]
        if not known:
            return None, []
        root = min(self.ranks[k] >> 8 for k in known)
        return root, [k for k in known if self.ranks[k] >> 8 == root]

    @property
    def global_root(self) -> int | None:
        """Root of the merged frame this robot's estimate is in (None without an estimate)."""
        return self.global_frames()[0]

    def message_tx(self) -> Message | None:
        self._advance()
        flood = self.recovery.message_tx()
        if flood is not None:
            return flood
        if self.phase is None:
            return None
        # While merging, the check takes its turn first (one opportunity in a few, once
        # settled): seeds always have something of their own to send.
        message = None
        if self.check is not None and self.phase_name == "merge":
            message = self.check.message_tx()
        return message if message is not None else self.phase.message_tx()

    def message_rx(self, message: Message, distance_mm: int) -> None:
        phase = self.phase
        if phase is None:
            return
        # Recovery floods and POS are rare: dispatch on the type byte, not a call per message.
        kind = message.type
        if kind == RECOVER.type:
            self.recovery.message_rx(message)
        phase.message_rx(message, distance_mm)
        if kind == POS.type and self.check is not None and phase.name == "merge":
            self.check.message_rx(message)
        (sender,) = _SENDER(message.data)
        if sender != self.uid:
            self.table.heard(sender, distance_mm)
