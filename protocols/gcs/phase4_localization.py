"""Phase 4: localization in the frames of seeds in view (thesis §4.4, §5.3.2 "Phase 4").

Located robots announce, asynchronously and in turn, each position they hold:
``POS(sender, seed, x, y)``. A robot that sees seed S (S is in its neighbour table) and has heard
at least two neighbours located in S's frame multilaterates itself in that frame, with the seed
at the origin as a further anchor and its mean measured distances as ranges (least squares when
it has more than three anchors). A fix whose residuals are too large (``gcs.max_rmse_mm``), whose
anchors are near-collinear, or that its mirror image fits as well is rejected and counted
(``fix_rejected`` events); the robot tries again when it hears a new anchor. Seeds keep
announcing their references (phase 3's REF) so late references still learn their place.

A robot can hold positions in several frames; it announces them all, in turn.

Message (type 40 POS)::

    sender:uint16  seed:uint16  seed_salt:uint8  x:int16  y:int16   (0.1 mm)   9 bytes

A frame is named by its seed's ID and phase-1 salt
(:meth:`kilonet.protocols.gcs.program.GcsRobot.frame_key`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from kilonet.message import Message
from kilonet.protocols.common.geometry import multilaterate
from kilonet.protocols.common.neighbours import NeighbourTable
from kilonet.protocols.gcs.base import GcsParams, GcsStage, Phase, gcs_layout
from kilonet.protocols.gcs.frame_keys import FrameKey
from kilonet.protocols.gcs.phase3_local_frames import announce_reference, receive_reference

__all__ = [
    "POS",
    "Localization",
    "announce_position",
    "fix_anchors",
    "receive_position",
    "worth_a_fix",
]

POS = gcs_layout(
    "pos",
    type=40,
    fields=[("seed", "H"), ("seed_salt", "B"), ("x_mm", "h", 0.1), ("y_mm", "h", 0.1)],
)


def announce_position(robot) -> Message | None:
    """The robot's next POS message (its frames in turn), or ``None`` if it is located nowhere."""
    frames = robot.estimate.frames
    if not frames:
        return None
    keys = sorted(frames)
    robot.pos_turn = (robot.pos_turn + 1) % len(keys)
    key = keys[robot.pos_turn]
    x, y = frames[key]
    return POS.pack(sender=robot.uid, seed=key.uid, seed_salt=key.salt, x_mm=x, y_mm=y)


def receive_position(robot, message: Message) -> FrameKey | None:
    """Store a neighbour's announced position; return the key of the frame it is in."""
    if not POS.matches(message):
        return None
    m = POS.unpack(message)
    key = FrameKey.from_wire(m.seed, m.seed_salt)
    robot.announced.setdefault(key, {})[m.sender] = (m.x_mm, m.y_mm)
    return key


def fix_anchors(
    seed: int, located: Mapping[int, tuple[float, float]], table: NeighbourTable
) -> tuple[list[tuple[float, float]], list[float]]:
    """The anchors (mm, in the seed's frame) and ranges (mm) of a fix in seed ``seed``'s
    frame: the seed at the origin, then every neighbour in ``table`` that announced a position
    in that frame (``located``, by ID, in the order heard), each at its mean measured distance.

    Examples
    --------
    >>> t = NeighbourTable(); _ = [t.heard(uid, d) for uid, d in ((1, 40), (2, 42), (3, 39))]
    >>> fix_anchors(1, {2: (40.0, 0.0), 3: (20.0, 35.0), 9: (0.0, 80.0)}, t)
    ([(0.0, 0.0), (40.0, 0.0), (20.0, 35.0)], [40.0, 42.0, 39.0])
    """
    anchors = [(0.0, 0.0)]
    ranges = [table.distance(seed)]
    for uid, xy in located.items():
        if uid in table and uid != seed:
            anchors.append(xy)
            ranges.append(table.distance(uid))
    return anchors, ranges


def worth_a_fix(anchors: int, tried_with: int) -> bool:
    """A fix needs three anchors (the seed and two located neighbours), and is tried again
    only with more anchors than the last attempt in the same frame had."""
    return anchors >= 3 and anchors > tried_with


class Localization(Phase):
    """Phase 4 on one robot."""

    name = GcsStage.LOCALIZATION

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's window, s: ``gcs.localization_s``."""
        return p.localization_s

    def start(self) -> None:
        self.tried_with: dict[FrameKey, int] = {}  # frame -> anchors used at the last attempt
        self.rejections = 0
        self.turn = 0

    def message_tx(self) -> Message | None:
        r = self.robot
        self.turn += 1
        if r.references and self.turn % 3 == 0:
            return announce_reference(r)
        return announce_position(r)

    def message_rx(self, message: Message, distance_mm: int) -> None:
        r = self.robot
        receive_reference(r, message)
        key = receive_position(r, message)
        if key is None or key in r.estimate.frames:
            return
        seed = key.uid
        if seed == r.uid or seed not in r.table or r.frame_key(seed) != key:
            return  # this robot does not see that frame's seed
        anchors, ranges = fix_anchors(seed, r.announced[key], r.table)
        if not worth_a_fix(len(anchors), self.tried_with.get(key, 0)):
            return
        self.tried_with[key] = len(anchors)
        fix = multilaterate(
            np.array(anchors),
            np.array(ranges),
            sigma_mm=self.params.sigma_mm,
            max_rmse_mm=self.params.max_rmse_mm,
        )
        if fix.ok:
            r.estimate.locate(key, (fix.x_mm, fix.y_mm))
            r.log("located", seed=seed, x_mm=fix.x_mm, y_mm=fix.y_mm, anchors=len(anchors))
        else:
            self.rejections += 1
            r.log("fix_rejected", seed=seed, reason=fix.reason, anchors=len(anchors))
