"""Phase 5: merging groups (thesis §4.5, §5.3.2 "Phase 5").

A robot X located in two frames I and K looks among its neighbours for two more robots Y, Z
located in both frames (from their phase-4 announcements) and close enough to each other to see
each other (their distance computed in frame I is within the longest distance X has measured
itself); of those it keeps the pair whose triangle XYZ has the largest area, so the rotation
between the frames is well conditioned (none thinner than
``gcs.min_group_width_mm``). As in the thesis's implementation, the members do not
confirm the group to each other: the data needed was exchanged in phase 4. X registers the group
with both seeds; a seed records, per partner frame, the robots it can ask in phase 6.

Message (type 50 REGISTER, 7 bytes)::

    sender:uint16  seed:uint16  partner:uint16  partner_salt:uint8

Frames are named by frame keys (seed ID and salt,
:meth:`kilonet.protocols.gcs.program.GcsRobot.frame_key`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import TypeVar

from kilonet.message import Message
from kilonet.protocols.gcs.base import GcsParams, GcsStage, Phase, gcs_layout
from kilonet.protocols.gcs.frame_keys import FrameKey
from kilonet.protocols.gcs.phase4_localization import announce_position, receive_position

__all__ = ["REGISTER", "MergingGroups", "find_groups"]

F = TypeVar("F")  # what names a frame

REGISTER = gcs_layout(
    "register", type=50, fields=[("seed", "H"), ("partner", "H"), ("partner_salt", "B")]
)


def _area(a: tuple[float, float], b: tuple[float, float], c: tuple[float, float]) -> float:
    return abs((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])) / 2


def find_groups(
    own: Mapping[F, tuple[float, float]],
    announced: Mapping[F, Mapping[int, tuple[float, float]]],
    neighbours: set[int],
    reach_mm: float,
    min_width_mm: float = 0.0,
) -> dict[tuple[F, F], tuple[int, int]]:
    """Merging groups of a robot: ``{(I, K): (Y, Z)}`` for each pair of its frames I < K.

    Parameters
    ----------
    own : mapping
        The robot's positions by frame (a :class:`~kilonet.protocols.gcs.frame_keys.FrameKey`, or
        any ordered name of a frame: the prediction uses seed indices), mm.
    announced : mapping
        Neighbours' positions by frame, then neighbour ID, mm.
    neighbours : set
        IDs the robot hears.
    reach_mm : float
        Y and Z count as seeing each other when their distance in frame I is at most this.
    min_width_mm : float
        Smallest accepted width of triangle XYZ (twice its area over its longest side, mm):
        the rotation between the frames about a thin triangle's long axis is set by noise, and
        a flat enough triangle even lets a mirror flip fit.

    Examples
    --------
    >>> own = {1: (0.0, 0.0), 2: (10.0, 0.0)}
    >>> ann = {1: {5: (40.0, 0.0), 6: (0.0, 40.0)}, 2: {5: (50.0, 0.0), 6: (10.0, 40.0)}}
    >>> find_groups(own, ann, {5, 6}, 85.0, min_width_mm=10.0)
    {(1, 2): (5, 6)}
    >>> find_groups(own, ann, {5, 6}, 85.0, min_width_mm=40.0)
    {}
    """
    groups = {}
    for i, k in itertools.combinations(sorted(own), 2):
        shared = sorted(
            uid for uid in neighbours if uid in announced.get(i, {}) and uid in announced.get(k, {})
        )
        best, best_width = None, min_width_mm
        for y, z in itertools.combinations(shared, 2):
            px, py, pz = own[i], announced[i][y], announced[i][z]
            if math.dist(py, pz) > reach_mm:
                continue
            longest = max(math.dist(px, py), math.dist(px, pz), math.dist(py, pz))
            width = 2 * _area(px, py, pz) / longest if longest > 0 else 0.0
            if width > best_width:
                best, best_width = (y, z), width
        if best is not None:
            groups[(i, k)] = best
    return groups


class MergingGroups(Phase):
    """Phase 5 on one robot."""

    name = GcsStage.GROUPS

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's window, s: ``gcs.groups_s``."""
        return p.groups_s

    def start(self) -> None:
        r = self.robot
        reach = max((r.table.distance(uid) for uid in r.table.ids()), default=0.0)
        self.groups = find_groups(
            r.estimate.frames,
            r.announced,
            set(r.table.ids()),
            reach,
            self.params.min_group_width_mm,
        )
        r.groups = self.groups
        self.registrations = [(i, k) for i, k in self.groups] + [(k, i) for i, k in self.groups]
        self.turn = 0
        for seed, partner in self.registrations:
            if seed == r.own_key:
                r.partners.setdefault(partner, set()).add(r.uid)
        if self.groups:
            r.log("groups", count=len(self.groups))

    def message_tx(self) -> Message | None:
        r = self.robot
        self.turn += 1
        if self.registrations and self.turn % 2 == 0:
            seed, partner = self.registrations[(self.turn // 2) % len(self.registrations)]
            return REGISTER.pack(
                sender=r.uid, seed=seed.uid, partner=partner.uid, partner_salt=partner.salt
            )
        return announce_position(r)

    def message_rx(self, message: Message, distance_mm: int) -> None:
        r = self.robot
        receive_position(r, message)
        if REGISTER.matches(message):
            m = REGISTER.unpack(message)
            if m.seed == r.uid:
                partner = FrameKey.from_wire(m.partner, m.partner_salt)
                r.partners.setdefault(partner, set()).add(m.sender)
