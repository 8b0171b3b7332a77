"""One robot of the self-assembly: a seed, or a robot that waits in the packed start, then
edge-follows round the group into the shape and joins it (Rubenstein, Cornejo and Nagpal,
Science 345:795, 2014).

Message (kilolib v2, type 20, :data:`ASSEMBLY`)::

    data[0..1]  uid       uint16, the robot's id (ties of the start and yield rules)
    data[2]     gradient  uint8, hops from the seeds (255: not yet known)
    data[3]     stage     uint8, the sender's :class:`AssemblyStage` number
    data[4]     age       uint8, whole seconds the sender has moved (saturates at 255)
    data[5..6]  x         int16, the sender's position estimate, whole mm (if localized)
    data[7..8]  y         int16

A robot knows only what it hears, its distance estimates and its own motion; the rules it
applies are the pure functions of :mod:`kilonet.protocols.self_assembly.rules`. Events logged:
``start`` (it begins to move), ``fix`` (a first position estimate, and again after
:data:`REFIX_S` without an update), ``entered`` (its estimate enters the shape), ``stopped``
(it stops in the shape, with the rule that stopped it and its estimate), ``joined`` (its
estimate settled standing still, :func:`~kilonet.protocols.self_assembly.rules.settled`: from
now on it is a localization anchor) and ``lost`` (a moving robot that heard no stationary robot for
:data:`LOST_AFTER_S` stops where it is).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from kilonet.message import Layout, Message
from kilonet.protocols.common.phases import Stage
from kilonet.protocols.common.ranging_limit import trusted_range
from kilonet.protocols.self_assembly.rules import (
    Heard,
    Shape,
    about_to_leave,
    edge_turn,
    first_fix,
    gradient_from,
    localize_step,
    may_start,
    meets_own_gradient,
    must_yield,
    on_edge,
    settled,
)
from kilonet.robot import Kilobot

__all__ = ["ASSEMBLY", "LOST_AFTER_S", "AssemblyStage", "Neighbour", "SelfAssembly"]

ASSEMBLY = Layout(
    "assembly",
    type=20,
    fields=[
        ("uid", "H"),
        ("gradient", "B"),
        ("stage", "B"),
        ("age", "B"),
        ("x", "h"),
        ("y", "h"),
    ],
)
_TYPE = ASSEMBLY.type
_UNPACK = ASSEMBLY.unpack
UNKNOWN = 255
#: A neighbour not heard for this long (three transmit periods) is forgotten, seconds.
FORGET_S = 1.6
#: A moving robot that heard no stationary robot for this long stops, seconds.
LOST_AFTER_S = 10.0
#: Waiting robots check the start rule this often, seconds, and only after hearing their
#: neighbours this long since they started (the supplement's start-up time).
CHECK_S = 1.0
STARTUP_S = 4.0
#: How far back a moving robot looks at its own estimates to tell where it is heading, and
#: so how far ahead it looks for the shape's edge, seconds.
HEADING_S = 1.0
#: Localization ranges only with estimates at most this far (kilolib's read ever nearer than
#: the truth towards the end of its tables, :mod:`kilonet.protocols.common.ranging_limit`), mm,
#: and only with readings at most :data:`RANGE_FRESH_S` old (a moving robot has moved since).
RANGE_MM = 80.0
RANGE_FRESH_S = 0.6
#: Steps of the localization descent a moving robot takes each time it runs its loop.
LOCALIZE_STEPS = 12
#: A robot updates its estimate only from at least this many localized stationary robots
#: (fewer leave it free to slide along a circle, or to its mirror image).
MIN_ANCHORS = 3
#: A moving robot whose estimate went this long without an update drops it and waits for a
#: new first fix, seconds: it has moved some 20-40 mm since, and the descent from there can
#: settle on the mirror image of its position across a straight edge of the shape.
REFIX_S = 3.0


class AssemblyStage(Stage):
    """What a robot is doing, in the order a robot goes through them."""

    SEED = "seed"
    WAIT = "wait"
    MOVE_OUTSIDE = "move_outside"
    MOVE_INSIDE = "move_inside"
    SETTLE = "settle"
    JOINED = "joined"
    LOST = "lost"


_NUMBER = {stage: stage.number for stage in AssemblyStage}
_MOVING = frozenset({AssemblyStage.MOVE_OUTSIDE.number, AssemblyStage.MOVE_INSIDE.number})
#: The localization anchors: seeds, and robots whose estimate settled in the shape.
_LOCALIZED = frozenset({AssemblyStage.SEED.number, AssemblyStage.JOINED.number})
#: The robots that stand in the shape (anchors, and robots still settling).
_PLACED = _LOCALIZED | {AssemblyStage.SETTLE.number}
_COLORS = {
    AssemblyStage.SEED: (3, 3, 3),
    AssemblyStage.WAIT: (0, 0, 1),
    AssemblyStage.MOVE_OUTSIDE: (3, 0, 0),
    AssemblyStage.MOVE_INSIDE: (3, 3, 0),
    AssemblyStage.SETTLE: (0, 3, 3),
    AssemblyStage.JOINED: (0, 3, 0),
    AssemblyStage.LOST: (3, 0, 3),
}


class Neighbour(NamedTuple):
    """The last message heard from one neighbour: when (seconds of the hearer's clock), the
    distance estimate with it (mm) and what the sender said of itself (its decoded
    :data:`ASSEMBLY` record: ``uid``, ``gradient``, ``stage`` number, ``age``, ``x``, ``y``).

    The record is the one the medium decoded once for every receiver of the transmission, so
    hearing a message costs one small tuple."""

    heard_s: float
    distance_mm: int
    said: Any


_NEIGHBOUR = tuple.__new__


class SelfAssembly(Kilobot):
    """A robot of the self-assembly.

    Parameters
    ----------
    shape : Shape
        The target shape, in the seeds' frame (every robot holds it).
    seed_at_mm : (float, float), optional
        For a seed robot, its position in the seeds' frame (seeds are placed, not localized);
        ``None`` for every other robot.
    seed_gradient : int
        A seed's gradient (0 for the seed at the origin, 1 for the other three).
    """

    LED_KEY = tuple((color, stage.value.replace("_", " ")) for stage, color in _COLORS.items())

    def __init__(
        self,
        shape: Shape,
        *,
        seed_at_mm: tuple[float, float] | None = None,
        seed_gradient: int = 0,
    ) -> None:
        self.shape = shape
        self.seed_at_mm = seed_at_mm
        self.seed_gradient = seed_gradient

    # -- kilolib callbacks -------------------------------------------------------------------
    def setup(self) -> None:
        seed = self.seed_at_mm is not None
        self.stage = AssemblyStage.SEED if seed else AssemblyStage.WAIT
        self.stage_no = _NUMBER[self.stage]
        self.tick_s = 1.0 / self.ticks_per_s
        self.gradient = self.seed_gradient if seed else UNKNOWN
        self.estimate: tuple[float, float] | None = self.seed_at_mm
        self.neighbours: dict[int, Neighbour] = {}
        self.turn = ""
        self.edge_action = ""  # what the last reading of the nearest robot decided
        self.edge_reading: tuple[int, float] | None = None  # (uid, when heard) of that reading
        self.edge_previous_mm: float | None = None  # its distance, mm
        self.moved_since_s = 0.0
        self.last_stationary_s = 0.0
        self.next_check_s = STARTUP_S
        self.track: list[tuple[float, float, float]] = []  # (t, x, y) of recent estimates
        self.located_s = 0.0  # when the estimate was last updated
        self.last_step_mm: float | None = None  # how far the last update moved it
        self.stopped_s = 0.0  # when it stopped in the shape
        self.stop_rule = ""  # the stop rule that stopped it
        self.joined_s: float | None = None  # when it joined the shape (its estimate settled)
        self._message: Message | None = None
        self.set_color(*_COLORS[self.stage])

    def message_tx(self) -> Message | None:
        if self._message is None:
            x, y = self.estimate if self.estimate is not None else (0.0, 0.0)
            age = 0
            if self.stage_no in _MOVING:
                age = min(255, int(self._now_s() - self.moved_since_s))
            self._message = ASSEMBLY.pack(
                uid=self.kilo_uid,
                gradient=min(self.gradient, UNKNOWN),
                stage=self.stage_no,
                age=age,
                x=round(x),
                y=round(y),
            )
        return self._message

    def message_tx_success(self) -> None:
        if self.stage_no in _MOVING:
            self._message = None  # a moving robot's age and estimate change

    def message_rx(self, message: Message, distance_mm: int) -> None:
        # Every robot hears every neighbour about twice a second (some 60 receptions per
        # simulated second per robot in a packed start): the clock is read inline, the record
        # is the one decoded once for all receivers, and the Neighbour is built without the
        # named tuple's Python-level __new__.
        if message.type != _TYPE:
            return
        said = _UNPACK(message)
        self.neighbours[said.uid] = _NEIGHBOUR(
            Neighbour, (self.kilo_ticks * self.tick_s, distance_mm, said)
        )

    def loop(self) -> None:
        stage = self.stage
        if stage is AssemblyStage.SEED or stage is AssemblyStage.LOST:
            return
        now = self._now_s()
        moving = self.stage_no in _MOVING
        if not moving and stage is not AssemblyStage.SETTLE and now < self.next_check_s:
            return
        self.next_check_s = now + CHECK_S
        fresh = self._fresh(now)
        stationary = [(uid, n) for uid, n in fresh.items() if n.said.stage not in _MOVING]
        if stationary:
            self.last_stationary_s = now
        level = gradient_from(
            [n.distance_mm for _, n in stationary], [n.said.gradient for _, n in stationary]
        )
        if level is not None and level != self.gradient:
            self.gradient = min(level, UNKNOWN)
            self._message = None
        if stage is AssemblyStage.WAIT:
            self._wait(fresh, stationary)
        elif moving:
            self._move(now, fresh, stationary)
        elif stage is AssemblyStage.SETTLE:
            self._settle(now, stationary)
        else:  # joined: it keeps refining its estimate against the shape's other robots
            self._localize(now, stationary)

    def since_joined_s(self) -> float | None:
        """Seconds of its own clock since it joined the shape (``None``: it has not)."""
        return None if self.joined_s is None else self._now_s() - self.joined_s

    def position_estimate(self) -> tuple[float, float, str] | None:
        if self.estimate is None:
            return None
        return self.estimate[0], self.estimate[1], "seeds"

    # -- the stages --------------------------------------------------------------------------
    def _wait(self, fresh: dict[int, Neighbour], stationary: list[tuple[int, Neighbour]]) -> None:
        # A robot inside the packed start (most of them) is not on the edge: it need not
        # weigh its neighbours.
        if self.gradient == UNKNOWN or not on_edge(n.distance_mm for _, n in stationary):
            return
        heard = [
            Heard(uid, n.said.gradient, n.said.stage in _MOVING, n.distance_mm)
            for uid, n in fresh.items()
            if n.said.stage not in _PLACED
        ]
        if may_start(True, self.gradient, self.kilo_uid, heard):
            self.moved_since_s = self._now_s()
            self._set_stage(AssemblyStage.MOVE_OUTSIDE)
            self.log("start", gradient=self.gradient)

    def _move(
        self, now: float, fresh: dict[int, Neighbour], stationary: list[tuple[int, Neighbour]]
    ) -> None:
        if now - self.last_stationary_s > LOST_AFTER_S:
            self._halt()
            self._set_stage(AssemblyStage.LOST)
            self.log("lost", after_s=LOST_AFTER_S)
            return
        located = self._localize(now, stationary)
        nearest = min(stationary, key=lambda item: item[1].distance_mm, default=None)
        if located and self._stops(nearest):
            return
        age = int(now - self.moved_since_s)
        ahead = [
            (n.said.age, uid, n.distance_mm) for uid, n in fresh.items() if n.said.stage in _MOVING
        ]
        if nearest is None or must_yield(age, self.kilo_uid, ahead):
            self._drive("")
        else:
            self._drive(self._edge_action(*nearest))

    def _edge_action(self, uid: int, nearest: Neighbour) -> str:
        """The edge-following action for the nearest stationary robot's reading: decided
        afresh only on a new reading (the trend compares it with the reading before); between
        readings the robot keeps the action the last one decided."""
        reading = (uid, nearest.heard_s)
        if reading != self.edge_reading:
            self.edge_action = edge_turn(nearest.distance_mm, self.edge_previous_mm)
            self.edge_reading = reading
            self.edge_previous_mm = float(nearest.distance_mm)
        return self.edge_action

    def _stops(self, nearest: tuple[int, Neighbour] | None) -> bool:
        """Apply the stop rules to a fresh estimate; whether the robot stopped in the shape."""
        if self.stage is AssemblyStage.MOVE_OUTSIDE:
            if self.shape.contains(*self.estimate):
                self._set_stage(AssemblyStage.MOVE_INSIDE)
                self.log("entered", x=self.estimate[0], y=self.estimate[1])
            return False
        if nearest is not None and nearest[1].said.stage in _PLACED:
            uid, n = nearest
            if meets_own_gradient(self.gradient, Heard(uid, n.said.gradient, False, n.distance_mm)):
                self._stop("own_gradient")
                return True
        if about_to_leave(self.shape, self.estimate, self._ahead()):
            self._stop("shape_edge")
            return True
        return False

    def _localize(self, now: float, stationary: list[tuple[int, Neighbour]]) -> bool:
        """Update the estimate from the localized stationary neighbours in range, if there are
        at least :data:`MIN_ANCHORS`; whether it did."""
        refs = [
            n
            for _, n in stationary
            if n.said.stage in _LOCALIZED
            and now - n.heard_s <= RANGE_FRESH_S
            and trusted_range(n.distance_mm, RANGE_MM)
        ]
        stale = now - self.located_s > REFIX_S
        if self.stage_no in _MOVING and self.estimate is not None and stale:
            self.estimate = None
            self.track.clear()
        if len(refs) < MIN_ANCHORS:
            return False
        anchors = np.array([[n.said.x, n.said.y] for n in refs], dtype=float)
        ranges = np.array([n.distance_mm for n in refs], dtype=float)
        if self.estimate is None:
            fix = first_fix(anchors, ranges)
            if fix is None:
                return False
            self.estimate = fix
            self.last_step_mm = None
            self.log("fix", x=fix[0], y=fix[1], anchors=len(refs))
        else:
            (x0, y0), self.estimate = (
                self.estimate,
                localize_step(self.estimate, anchors, ranges, LOCALIZE_STEPS),
            )
            self.last_step_mm = float(np.hypot(self.estimate[0] - x0, self.estimate[1] - y0))
        self.located_s = now
        self.track.append((now, *self.estimate))
        while self.track and self.track[0][0] < now - HEADING_S:
            self.track.pop(0)
        return True

    def _ahead(self) -> tuple[float, float]:
        """The estimate carried on by its motion over the last :data:`HEADING_S`."""
        x, y = self.estimate
        if not self.track:
            return x, y
        _, x0, y0 = self.track[0]
        return 2 * x - x0, 2 * y - y0

    def _stop(self, rule: str) -> None:
        """Stop in the shape; it joins once its estimate settled (:meth:`_settle`)."""
        self._halt()
        self._set_stage(AssemblyStage.SETTLE)
        self.stopped_s = self._now_s()
        self.stop_rule = rule
        self.last_step_mm = None
        x, y = self.estimate
        self.log("stopped", rule=rule, gradient=self.gradient, x=x, y=y)

    def _settle(self, now: float, stationary: list[tuple[int, Neighbour]]) -> None:
        """Localize standing still until the estimate settled, then join the shape."""
        self._localize(now, stationary)
        if settled(now - self.stopped_s, self.last_step_mm):
            self._set_stage(AssemblyStage.JOINED)
            self.joined_s = now
            x, y = self.estimate
            self.log(
                "joined",
                rule=self.stop_rule,
                gradient=self.gradient,
                x=x,
                y=y,
                settle_s=now - self.stopped_s,
            )

    # -- motors and state --------------------------------------------------------------------
    def _drive(self, turn: str) -> None:
        if turn == self.turn:
            return
        self.turn = turn
        if turn == "":
            self.set_motors(0, 0)
            return
        self.spinup_motors()
        if turn == "left":
            self.set_motors(self.kilo_turn_left, 0)
        elif turn == "right":
            self.set_motors(0, self.kilo_turn_right)
        else:
            self.set_motors(self.kilo_straight_left, self.kilo_straight_right)

    def _halt(self) -> None:
        self.turn = ""
        self.set_motors(0, 0)

    def _set_stage(self, stage: AssemblyStage) -> None:
        self.stage = stage
        self.stage_no = _NUMBER[stage]
        self._message = None
        self.set_color(*_COLORS[stage])

    def _fresh(self, now: float) -> dict[int, Neighbour]:
        """The neighbours heard within :data:`FORGET_S`; the others are forgotten."""
        stale = [uid for uid, n in self.neighbours.items() if now - n.heard_s > FORGET_S]
        for uid in stale:
            del self.neighbours[uid]
        return self.neighbours

    def _now_s(self) -> float:
        return self.kilo_ticks * self.tick_s
