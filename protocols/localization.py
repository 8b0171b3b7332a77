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

A frame is named by its seed's ID and phase-1 salt (:meth:`protocols.gcs.GcsRobot.frame_key`).
"""

from __future__ import annotations

import numpy as np

from kilonet.geometry import multilaterate
from kilonet.message import Layout, Message
from protocols.gcs_base import Phase
from protocols.local_frames import announce_reference, receive_reference

__all__ = ["POS", "Localization", "announce_position", "receive_position"]

POS = Layout(
    "pos",
    type=40,
    fields=[
        ("sender", "H"),
        ("seed", "H"),
        ("seed_salt", "B"),
        ("x_mm", "h", 0.1),
        ("y_mm", "h", 0.1),
    ],
)


def announce_position(robot) -> Message | None:
    """The robot's next POS message (its frames in turn), or ``None`` if it is located nowhere."""
    if not robot.frames:
        return None
    keys = sorted(robot.frames)
    robot.pos_turn = (robot.pos_turn + 1) % len(keys)
    key = keys[robot.pos_turn]
    x, y = robot.frames[key]
    return POS.pack(sender=robot.uid, seed=key >> 8, seed_salt=key & 0xFF, x_mm=x, y_mm=y)


def receive_position(robot, message: Message) -> int | None:
    """Store a neighbour's announced position; return the key of the frame it is in."""
    if not POS.matches(message):
        return None
    m = POS.unpack(message)
    key = (m.seed << 8) | m.seed_salt
    robot.announced.setdefault(key, {})[m.sender] = (m.x_mm, m.y_mm)
    return key


class Localization(Phase):
    """Phase 4 on one robot."""

    name = "localization"

    def start(self) -> None:
        self.tried_with: dict[int, int] = {}  # seed -> anchors used at the last attempt
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
        if key is None or key in r.frames:
            return
        seed = key >> 8
        if seed == r.uid or seed not in r.table or r.frame_key(seed) != key:
            return  # this robot does not see that frame's seed
        anchors = [(0.0, 0.0)]
        ranges = [r.table.distance(seed)]
        for uid, xy in r.announced[key].items():
            if uid in r.table and uid != seed:
                anchors.append(xy)
                ranges.append(r.table.distance(uid))
        if len(anchors) < 3 or len(anchors) <= self.tried_with.get(key, 0):
            return
        self.tried_with[key] = len(anchors)
        fix = multilaterate(
            np.array(anchors),
            np.array(ranges),
            sigma_mm=self.params.sigma_mm,
            max_rmse_mm=self.params.max_rmse_mm,
        )
        if fix.ok:
            r.frames[key] = (fix.x_mm, fix.y_mm)
            r.log("located", seed=seed, x_mm=fix.x_mm, y_mm=fix.y_mm, anchors=len(anchors))
        else:
            self.rejections += 1
            r.log("fix_rejected", seed=seed, reason=fix.reason, anchors=len(anchors))
