"""Trilateration with Kilobots: three robots build a frame, a fourth walks to its centroid.

Roles are flashed per robot, as in the seed (no other identity is needed):

====  ==============================  ========  ===============================
ID    function                        Tx LED    Rx LED
====  ==============================  ========  ===============================
1     coordinate frame origin         white     –
2     x-axis robot                    blue      yellow (from 1)
3     third robot of the frame        green     yellow (from 1) / purple (from 2)
4     follower                        –         –
====  ==============================  ========  ===============================

Message (the seed's table; type 8, one byte per field, :data:`FRAME_BYTE`)::

    data[0]  sender ID (1, 2, 3)                                uint8
    data[1]  coordinates known (0/1)                            uint8
    data[2]  X of the sender, mm (whole mm, -128..127)          int8
    data[3]  Y of the sender, mm (whole mm, 0..255; y >= 0)     uint8
    data[4]  d12, origin to x-axis robot, mm (whole mm)         uint8  (filled by 2, 3)
    data[5]  d13, origin to third robot, mm (whole mm)          uint8  (filled by 3)
    data[6]  d23, x-axis to third robot, mm (whole mm)          uint8  (filled by 3)
    data[7], data[8]  not used (not sent)

Whole millimetres are what kilolib's distance estimate gives (a uint8), so a byte per distance
loses only the sub-millimetre part that averaging several readings recovers (≤ 0.5 mm of
rounding). X is signed (robot 3 may lie behind the origin) and fits a byte at 1 mm only for
frames whose sides are at most 127 mm, which the hardware range (about 85 mm) guarantees.
X is rounded to whole millimetres (≤ 0.5 mm). The 16-bit variant (type 9, :data:`FRAME_WIDE`)
keeps ``data[0..1]`` and stores X and Y as int16 and d12 as uint16 in tenths of a millimetre
(``data[2..7]``, ±3276.7 mm); it drops d13 and d23, which follow from X, Y and d12
(``d13 = |(x3, y3)|``, ``d23 = |(x3 − d12, y3)|``), so it loses nothing and fits 9 bytes.

The frame robots average ``samples`` distance readings before they flag their coordinates:
robot 2 sets ``(d12, 0)``; robot 3, once it has a flagged d12 from robot 2 and readings from
both, sets ``x3 = (d13² − d23² + d12²)/(2 d12)``, ``y3 = √(d13² − x3²)``
(:func:`kilonet.protocols.common.geometry.place_references`). y3 is taken positive, so when robot 3
stands on the
right of the 1→2 axis the frame is a mirror image of the floor.

The follower (:class:`Follower`) transmits nothing. It listens until it has fresh readings
(received after its motors stopped) from all three robots and robot 3's flagged frame, then
trilaterates with the seed's formulas
(:func:`kilonet.protocols.common.geometry.trilaterate_linear`), takes the goal to be the centroid of
robots 1–3 and steps: a small first move gives its heading u
(the chord between two fixes); then it turns toward the goal and steps, and re-trilaterates,
until it is within ``tolerance_mm`` of the goal. A turn runs one motor for ``t = f(angle)`` from
its linear turn calibration and pivots the body about the rear leg on that side, so the centre
swings on an arc (:mod:`kilonet.protocols.follower.pivot_turns`): the seed's α = atan2(u₁v₂ − u₂v₁,
u₁v₁ + u₂v₂) is only where planning starts. What the seed leaves open is handled as follows:

* **Planning with the swing.** Every move is the next move of the plan of at most two
  (turn, step) moves expected to end nearest the aim, the swing and the robot's own heading
  and turn errors included (:func:`kilonet.protocols.follower.pivot_turns.best_pivot_move`); the
  second move of a two-move plan is made, not planned again. Swings and steps keep clear of the
  frame robots' bodies and within ``hearing_mm`` of all three.
* **Mirror frames.** In a mirrored frame a physical left turn shows up as a right turn about
  the frame's right leg. The follower starts assuming a floor-handed frame; every large turn
  votes twice: by its swing (the fix after it minus the one before,
  :func:`kilonet.protocols.follower.pivot_turns.swing_vote`) and by the rotation between the step
  directions before and after it. Until one handedness leads, every turn is a probe of at least
  ``probe_deg`` with a short step.
* **Outside the triangle.** The robot knows where robots 1–3 stand (their coordinates) and
  that bodies are 33 mm discs; it aims at the goal when the straight line is clear of their
  bodies and otherwise at a waypoint on a detour round them, on a consistent side. A goal too
  close to a robot to be reached is moved out to contact distance.
* **Message loss and silence.** Readings taken while moving or before the current listening
  window are never used. A robot unheard for ``listen_timeout_s`` is left out: two distances
  and the dead-reckoned previous position pick one of the two circle intersections, never one
  within hearing of the robot unheard, and only one that both handedness agree on while the
  handedness is open. A distance at the sensor's ceiling (``saturation_mm``, kilolib's 255) is
  "at least that far": it only rules out candidates; so is one above ``neighbour_max_mm``,
  where kilolib's estimates saturate (:mod:`kilonet.protocols.ranging_limit`). A step after which it
  cannot locate itself at all is undone: the way back to the last fix is planned in the
  robot's own body frame. When that does not help, or a distance is saturated, the follower
  walks to reduce its nearest distance (measuring the bearing from how that distance changes)
  until it can locate itself again. Before its first move it only waits. After ``give_up_s``
  of silence or ``max_steps`` steps it gives up.
* **Calibration error.** The follower learns its real speed from its free steps and, with
  ``adapt_turns``, the real rate of each motor from conclusive turns (each motor has its own
  curve and stored value).

Events logged (``self.log``): ``frame`` (robots 2 and 3), ``fix`` (every position estimate, in
the follower's frame), ``move``, ``handedness``, ``turn_rate``, ``reached``, ``gave_up``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import median
from typing import Literal

from kilonet.message import Message
from kilonet.params import ParamError, param
from kilonet.protocols.common.geometry import (
    GeometryError,
    circle_intersections,
    rotate,
    trilaterate_linear,
    wrap_angle,
)
from kilonet.protocols.common.ranging_limit import trusted_range
from kilonet.protocols.follower.frame_robots import (
    FOLLOWER,
    FRAME_BYTE,
    FRAME_WIDE,
    ORIGIN,
    THIRD,
    X_AXIS,
    FrameReport,
    Origin,
    ThirdRobot,
    XAxisRobot,
    decode,
    encode,
)
from kilonet.protocols.follower.pivot_turns import (
    PIVOT_LEG_MM,
    PivotMove,
    best_pivot_move,
    handedness_vote,
    pivot_displacement,
    segment_blocked,
    swing_arc,
    swing_turn_rad,
    swing_vote,
    turn_rate_ratio,
)
from kilonet.protocols.follower.planning import (
    frame_direction,
    plan_direction,
    reachable_goal,
    turn_angle,
)
from kilonet.protocols.follower.turn_calibration import TurnCalibration
from kilonet.robot import Kilobot

__all__ = [
    "FOLLOWER",
    "FRAME_BYTE",
    "FRAME_WIDE",
    "GUARD_S",
    "MIN_TURN_DEG",
    "ORIGIN",
    "PIVOT_LEG_MM",
    "THIRD",
    "X_AXIS",
    "Follower",
    "FollowerParams",
    "FrameReport",
    "Origin",
    "ThirdRobot",
    "XAxisRobot",
    "circle_intersections",
    "decode",
    "encode",
    "frame_direction",
    "pivot_displacement",
    "plan_direction",
    "reachable_goal",
    "rotate",
    "turn_angle",
    "wrap_angle",
]

_ESCAPE_TURNS = (math.pi, math.pi / 2, -math.pi / 2, 3 * math.pi / 4)

Point = tuple[float, float]


# ------------------------------------------------------------------------------ follower


#: Wait after the motors stop before readings count, s: a message on the air while the robot
#: moved carries an old distance.
GUARD_S = 0.1
#: Turns smaller than this are skipped, degrees.
MIN_TURN_DEG = 2.0
#: Relative error of a turn the planner assumes before the turning motor's rate is learned
#: (two turns of it seen), and after: the calibration is made on another robot, about 10 %
#: off, and what is learned is good to a few per cent.
#: A step after a turn tells the turn only if it went at least this share of the distance
#: timed; a shorter one touched a body and slid along it (fixes are about 1 mm off, so a
#: free 10 mm step comes out at 0.85 or more).
CLEAN_STEP_SHARE = 0.85
#: Turn-rate ratios (real / calibrated) taken as possible: the calibration robot and this one
#: differ by per-robot and per-motor errors of about 10 % each, rarely by more than 40 %;
#: a ratio outside is a misread turn.
RATE_RATIO_RANGE = (0.6, 1.6)
#: Turns whose swing's length tells the rate (:func:`swing_turn_rad`), rad: from 40°, where
#: the swing is 11 mm, to 140°, beyond which the chord hardly grows.
SWING_RATE_TURNS = (math.radians(40.0), math.radians(140.0))
#: Turns from this size on tell the handedness by their swing (:func:`swing_vote`), rad.
MIN_SWING_RAD = math.radians(30.0)
#: A robot unheard through a whole listening window (several of its messages lost) is
#: taken to be at least this much less than the hearing range away, mm: a two-distance fix
#: that puts it nearer is the mirror candidate.
UNHEARD_MARGIN_MM = 10.0
#: How far inside its hearing range the follower plans to stay, mm.
HEARING_MARGIN_MM = 5.0
TURN_SD_UNLEARNED = 0.1
TURN_SD_LEARNED = 0.04


@dataclass(frozen=True)
class FollowerParams:
    """Parameters of the follower scenario (section ``follower``): how the scenario places the
    four robots and judges the walk, and the knobs the robots' programs take directly
    (lengths mm, times s, angles degrees).

    The programs read ``frame_samples``, ``message`` (robots 1-3) and ``listen_samples``,
    ``listen_timeout_s``, ``give_up_s``, ``first_step_mm``, ``step_mm``, ``step_fraction`` (far
    from the goal a step may be this share of the remaining distance instead; a first or probe
    step half of it, up to ``step_mm``, since far fixes are less precise), ``tolerance_mm``,
    ``clearance_mm`` (kept from the frame robots' bodies when planning), ``max_steps``,
    ``probe_deg`` and ``adapt_turns`` (the follower); the scenario reads the rest.
    """

    section_name = "follower"
    side_min_mm: float = param(60.0, lo=33.0, hi=1000.0, doc="generated frame: shortest side")
    side_max_mm: float = param(80.0, lo=33.0, hi=1000.0, doc="generated frame: longest side")
    handedness: Literal["random", "left", "right"] = param(
        "random", doc="robot 3 left/right of the 1->2 axis (right: mirrored frame)"
    )
    start_min_mm: float = param(
        20.0, lo=0.0, hi=10_000.0, doc="follower start: min from goal (20: it has to walk)"
    )
    start_max_mm: float = param(0.0, lo=0.0, hi=10_000.0, doc="follower start: max (0: range)")
    direct_start: bool = param(True, doc="generated start has a passable straight line to goal")
    message: Literal["byte", "wide"] = param(
        "byte", doc="the seed's byte-per-field message, or the 16-bit variant"
    )
    frame_samples: int = param(8, lo=1, hi=1000, doc="readings robots 2, 3 average")
    listen_samples: int = param(4, lo=1, hi=1000, doc="fresh readings per robot per fix")
    neighbour_max_mm: float = param(
        100.0,
        lo=33.0,
        hi=255.0,
        doc="follower: a larger reading means only 'at least this far' (kilolib's tables end at "
        "98 mm, estimates saturate beyond)",
    )
    listen_timeout_s: float = param(3.0, lo=0.1, hi=600.0, doc="then fix without the unheard")
    give_up_s: float = param(60.0, lo=1.0, hi=1e5, doc="silence before the follower gives up")
    first_step_mm: float = param(10.0, lo=1.0, hi=500.0, doc="first and probe step length")
    step_mm: float = param(20.0, lo=1.0, hi=500.0, doc="longest ordinary step near the goal")
    step_fraction: float = param(0.25, lo=0.0, hi=1.0, doc="far away: step this share of the way")
    tolerance_mm: float = param(3.0, lo=0.1, hi=500.0, doc="follower stops this close (estimate)")
    clearance_mm: float = param(1.5, lo=0.0, hi=100.0, doc="kept from robot bodies when planning")
    max_steps: int = param(100, lo=1, hi=100_000, doc="steps before the follower gives up")
    probe_deg: float = param(60.0, lo=20.0, hi=120.0, doc="smallest turn testing handedness")
    adapt_turns: bool = param(True, doc="follower learns its turn rate from its turns")
    calibration_seed: int = param(1, lo=0, doc="seed of the robot the turn calibration is made on")
    calibration_sd_deg: float = param(3.0, lo=0.0, hi=90.0, doc="error reading each timed angle")
    success_mm: float = param(8.0, lo=0.0, hi=1000.0, doc="reached: true distance to the goal")

    def __post_init__(self) -> None:
        if self.side_min_mm > self.side_max_mm:
            raise ParamError("follower.side_min_mm must not exceed follower.side_max_mm")
        if self.start_max_mm and self.start_min_mm > self.start_max_mm:
            raise ParamError("follower.start_min_mm must not exceed follower.start_max_mm")


class Follower(Kilobot):
    """Robot 4: trilaterates itself in the frame of robots 1–3 and walks to their centroid.

    Parameters
    ----------
    params : FollowerParams
        The scenario's section: listening, stepping and tolerance settings.
    calibration : TurnCalibration
        The linear ``t = f(angle)`` this robot turns by (made on some robot, not exactly this
        one).
    speed_mm_s : float
        Nominal forward speed (the data sheet's); the real one is learned from steps.
    saturation_mm : int
        The distance sensor's ceiling: a reading this large means "at least this far".
    body_mm : float
        Kilobot body diameter.
    hearing_mm : float
        How far the robot hears the frame robots (the radio's range, a hardware figure), mm:
        the planner keeps its moves within ``hearing_mm - HEARING_MARGIN_MM`` of all three
        where it can.

    Attributes
    ----------
    outcome : str or None
        ``"reached"`` or ``"gave_up"`` once the walk ended.
    steps : int
        Forward steps taken.
    mirrored : bool
        Whether the robot concluded that its frame is a mirror image of the floor.
    handedness_settled : bool
        Whether that conclusion rests on a conclusive turn.
    """

    def __init__(
        self,
        params: FollowerParams,
        calibration: TurnCalibration,
        *,
        speed_mm_s: float,
        saturation_mm: int,
        body_mm: float,
        hearing_mm: float = math.inf,
    ) -> None:
        self.params = params
        self.calibration = calibration
        self.nominal_speed_mm_s = speed_mm_s
        self.saturation_mm = saturation_mm
        self.body_mm = body_mm
        self.hearing_mm = hearing_mm

    # -- state ---------------------------------------------------------------------------
    def setup(self) -> None:
        self.outcome: str | None = None
        self.steps = 0
        self.mirrored = False
        self.frame: tuple[float, float, float] | None = None  # d12, x3, y3
        self.phase = "listen"
        self.phase_end_tick = 0
        self._readings: dict[int, list[int]] = {ORIGIN: [], X_AXIS: [], THIRD: []}
        self._listen_from_tick = 0
        self._listen_started_tick = 0
        self._silent_since_tick = 0
        # Where the robot believes it is, its heading in the frame and how it got there.
        self.position: Point | None = None
        self._heading: Point | None = None
        self._heading_measured = False
        self._heading_chord_mm = 0.0  # the step the heading was measured from
        self._last_plan_final = True  # else the next move is the second of a two-move plan
        self._last_turn_rad = 0.0  # physical, counter-clockwise positive, as intended
        self._last_step_mm = 0.0
        self._last_step_ticks = 0
        self._last_mode = ""
        # A turn pivots the body about a leg and may push it along another body: the follower
        # takes a fix between turn and step, so each step it learns from is a straight one.
        self._step_pending = False
        self._fixed_after_turn = False
        self._votes = {False: 0, True: 0}
        self._side = 0  # detour side memory of the planner
        self._blocked_steps = 0  # consecutive steps that did not move the robot
        self._speed_samples: list[tuple[float, float]] = []  # (mm moved, s) of clean steps
        self.speed_mm_s = self.nominal_speed_mm_s
        # Real turn rate / calibrated rate, as learned, per motor (+1 left, -1 right): each
        # motor has its own curve and stored value, so the two turn at different rates.
        self._rate_samples: dict[int, list[float]] = {1: [], -1: []}
        self.turn_gains = {1: 1.0, -1: 1.0}
        self._last_turn_gain = 1.0
        # Walking toward the nearest robot when no fix is possible yet.
        self._approach: dict[str, float] | None = None

    @property
    def handedness_settled(self) -> bool:
        """Whether a conclusive turn has told the frame's handedness (else ``mirrored`` is the
        starting assumption)."""
        return self._votes[False] != self._votes[True]

    # -- kilolib callbacks -------------------------------------------------------------------
    def message_rx(self, message: Message, distance_mm: int) -> None:
        report = decode(message)
        if report is None or report.sender not in self._readings:
            return
        if report.sender == THIRD and report.known and report.y_mm > 0:
            self.frame = (report.d12_mm, report.x_mm, report.y_mm)
        if self.phase == "listen" and self.kilo_ticks >= self._listen_from_tick:
            self._readings[report.sender].append(distance_mm)

    def loop(self) -> None:
        if self.outcome is not None:
            return
        now = self.kilo_ticks
        if self.phase == "turn" and now >= self.phase_end_tick:
            self.set_motors(0, 0)
            self._step_pending = True
            self._start_listening(now)
        elif self.phase == "step" and now >= self.phase_end_tick:
            self.set_motors(0, 0)
            self._start_listening(now)
        elif self.phase == "listen" and now >= self._listen_from_tick:
            self._listen(now)

    # -- listening and locating --------------------------------------------------------------
    def _start_listening(self, now: int) -> None:
        self.phase = "listen"
        self._listen_from_tick = now + max(1, round(GUARD_S * self.ticks_per_s))
        self._listen_started_tick = self._listen_from_tick
        self._silent_since_tick = self._listen_from_tick
        for readings in self._readings.values():
            readings.clear()

    def _listen(self, now: int) -> None:
        c = self.params
        tps = self.ticks_per_s
        if (now - self._silent_since_tick) / tps > c.give_up_s:
            self._finish("gave_up", reason="silence")
            return
        full = all(len(r) >= c.listen_samples for r in self._readings.values())
        timed_out = (now - self._listen_started_tick) / tps >= c.listen_timeout_s
        if self.frame is None or not (full or timed_out):
            return
        distances = {k: self._average(r) for k, r in self._readings.items()}
        if self._step_pending:
            self._fix_after_turn(distances)
            self._start_step(now)
            return
        if self._act(distances):
            return
        # Nothing to act on yet: a fresh window, but keep counting the silence.
        self._listen_started_tick = now
        for readings in self._readings.values():
            readings.clear()

    def _fix_after_turn(self, distances: dict[int, float | None]) -> None:
        """Where the turn left the robot: a fix if the readings allow, else dead reckoning."""
        self._step_pending = False
        fix = self._locate(distances)
        if fix is None:
            predicted = self._predicted_position()
            if predicted is not None and self._heading is not None:
                step = self._last_step_ticks / self.ticks_per_s * self.speed_mm_s
                heading = self._heading_after_turn()
                # The prediction covers turn and step; before the step, take the turn alone.
                predicted = (predicted[0] - step * heading[0], predicted[1] - step * heading[1])
            self._fixed_after_turn = False
            if predicted is not None:
                self.position = predicted
            return
        position, kind = fix
        turned = self._last_turn_rad
        if self.position is not None and self._heading_measured and abs(turned) >= MIN_SWING_RAD:
            moved = (position[0] - self.position[0], position[1] - self.position[1])
            verdict = swing_vote(self._heading, turned, moved)
            if verdict is not None:
                self._record_vote(verdict)
        if self.position is not None and SWING_RATE_TURNS[0] <= abs(turned) <= SWING_RATE_TURNS[1]:
            # The swing's length tells how far the turn went, whatever the heading.
            moved = (position[0] - self.position[0], position[1] - self.position[1])
            self._learn_rate(turned, swing_turn_rad(moved) * math.copysign(1.0, turned))
        self.position = position
        self._fixed_after_turn = True
        self.log("fix", x_mm=position[0], y_mm=position[1], kind=kind, after="turn")

    def _average(self, readings: list[int]) -> float | None:
        """Mean reading in mm; ``None`` if unheard, ``inf`` if at the sensor's ceiling."""
        if not readings:
            return None
        farthest = max(readings)
        if farthest >= self.saturation_mm or not trusted_range(
            farthest, self.params.neighbour_max_mm
        ):
            return math.inf
        return sum(readings) / len(readings)

    def _anchors(self) -> dict[int, Point]:
        d12, x3, y3 = self.frame
        return {ORIGIN: (0.0, 0.0), X_AXIS: (d12, 0.0), THIRD: (x3, y3)}

    def _locate(self, distances: dict[int, float | None]) -> tuple[Point, str] | None:
        """A position fix in the frame from this window's readings, or ``None``."""
        usable = {k: d for k, d in distances.items() if d is not None and math.isfinite(d)}
        anchors = self._anchors()
        if len(usable) == 3:
            roles = (ORIGIN, X_AXIS, THIRD)
            try:
                return trilaterate_linear(
                    [anchors[k] for k in roles], [usable[k] for k in roles]
                ), "three"
            except GeometryError:
                return None
        if len(usable) != 2:
            return None
        (i, di), (j, dj) = usable.items()
        candidates = circle_intersections(anchors[i], di, anchors[j], dj)
        (k,) = set(anchors) - {i, j}
        if distances[k] is not None:  # saturated: at least the ceiling away from robot k
            floor_mm = min(self.saturation_mm, self.params.neighbour_max_mm) - 3
        else:  # unheard for a whole window: most likely out of hearing
            floor_mm = self.hearing_mm - UNHEARD_MARGIN_MM
        candidates = [p for p in candidates if _dist(p, anchors[k]) >= floor_mm]
        if not candidates:
            return None
        # The dead-reckoned position picks the intersection; while the handedness is open it
        # must pick the same one under both (they are mirror images across the line of the
        # two robots heard, and so are the predictions).
        handedness = (self.mirrored,) if self.handedness_settled else (False, True)
        priors = [self._predicted_position(m) for m in handedness]
        if all(prior is not None for prior in priors):
            picks = {min(candidates, key=lambda p, q=q: _dist(p, q)) for q in priors}
            return (picks.pop(), "two") if len(picks) == 1 else None
        if len(candidates) == 1:
            return candidates[0], "two"
        return None

    def _predicted_position(self, mirrored: bool | None = None) -> Point | None:
        """Where dead reckoning puts the robot after its last move (frame mm), if it knows; in
        a frame of the given handedness (default: the one concluded)."""
        if mirrored is None:
            mirrored = self.mirrored
        if self.position is None or self._last_mode in ("", "approach"):
            return None
        if self._last_mode == "retreat":
            return self.position  # back where the last fix was taken
        if self._heading is None:
            return self.position
        heading = rotate(self._heading, self._frame_turn(mirrored))
        dx, dy = pivot_displacement(self._heading, self._frame_turn(mirrored))
        step = self._last_step_ticks / self.ticks_per_s * self.speed_mm_s
        return (
            self.position[0] + dx + step * heading[0],
            self.position[1] + dy + step * heading[1],
        )

    def _frame_turn(self, mirrored: bool) -> float:
        """The last physical turn as a frame of the given handedness sees it."""
        return -self._last_turn_rad if mirrored else self._last_turn_rad

    def _heading_after_turn(self) -> Point | None:
        """The heading before the last turn rotated by that turn, as the frame sees it."""
        if self._heading is None:
            return None
        return rotate(self._heading, self._frame_turn(self.mirrored))

    # -- deciding the next move --------------------------------------------------------------
    def _act(self, distances: dict[int, float | None]) -> bool:
        """Locate and plan the next move; False if there is nothing to act on yet."""
        if self.steps >= self.params.max_steps:
            self._finish("gave_up", reason="steps")
            return True
        fix = self._locate(distances)
        if fix is None:
            usable = {k: d for k, d in distances.items() if d is not None and math.isfinite(d)}
            saturated = any(d == math.inf for d in distances.values())
            if self.steps == 0 and not saturated:
                return False  # wait for fresh readings from all three (never act on stale ones)
            if self.position is not None and self._last_mode not in ("retreat", "approach"):
                # The last step took the robot where it cannot locate itself (out of range or
                # in a body's shadow): go back the way it came and detour the other way.
                self._side = -self._side
                self._retreat()
                return True
            if not usable:
                return False
            # Some robot is beyond the sensor's reach (or still unheard after going back):
            # get closer to the nearest one heard before locating again.
            self.position = None
            self._approach_step(usable)
            return True
        position, kind = fix
        self._learn_from_step(position)
        self.position = position
        goal = self._goal()
        obstacles = list(self._anchors().values())
        radius = self.body_mm + self.params.clearance_mm
        target = reachable_goal(goal, obstacles, radius)
        to_goal = _dist(position, goal)
        to_target = _dist(position, target)
        self.log(
            "fix",
            x_mm=position[0],
            y_mm=position[1],
            kind=kind,
            goal_x_mm=goal[0],
            goal_y_mm=goal[1],
            to_goal_mm=to_goal,
            heard=sorted(k for k, d in distances.items() if d is not None),
        )
        if min(to_goal, to_target) <= self.params.tolerance_mm:
            self._finish("reached", to_goal_mm=to_goal)
            return True
        heading = self._heading
        if heading is None:
            if self._blocked_steps:
                # Against a body with no trusted heading: turn (round, first) and step away.
                turn = _ESCAPE_TURNS[(self._blocked_steps - 1) % len(_ESCAPE_TURNS)]
                self._plan(turn, self.params.first_step_mm, "escape")
            else:
                self._plan(0.0, self._short_step_mm(to_target), "first")
            return True
        # Aim at the goal if the straight line is clear, else at a waypoint a step along the
        # detour; the turn that faces the aim takes the pivot's swing into account.
        step = self._goal_step_mm(to_target)
        direction, self._side = plan_direction(
            position, target, obstacles, radius, step, self._side
        )
        line = (target[0] - position[0], target[1] - position[1])
        detour = abs(turn_angle(line, direction)) > 1e-9
        aim = (position[0] + step * direction[0], position[1] + step * direction[1])
        if detour:
            move = self._aim(position, heading, aim, step)
        else:
            c = self.params
            move = self._aim(position, heading, target, max(c.step_mm, c.step_fraction * to_target))
        alpha, step = move.turn_rad, move.step_mm
        self._last_plan_final = move.final
        mode = "goal"
        if not self.handedness_settled:
            # Handedness not settled: make this turn big enough to tell, and the step short.
            step = self._short_step_mm(to_target)
            alpha = self._probe_turn(position, heading, alpha, step, obstacles, radius)
            mode = "probe"
            self._last_plan_final = True
        if abs(alpha) < math.radians(MIN_TURN_DEG) and step >= 1.0:
            alpha = 0.0  # a turn alone is kept, however small: it is the whole move
        # α is in the frame; the pivot is physical, and flips in a mirrored frame.
        physical = abs(alpha) * frame_direction(alpha, self.mirrored)
        self._plan(physical, step, mode)
        return True

    def _goal_step_mm(self, to_target_mm: float) -> float:
        """Length of an ordinary step ``to_target_mm`` from the target: up to ``step_mm``, or
        far away ``step_fraction`` of the way (fewer steps, and a longer baseline for the
        heading where fixes are least precise), never past the target."""
        c = self.params
        return min(max(c.step_mm, c.step_fraction * to_target_mm), to_target_mm)

    def _aim(self, position: Point, heading: Point, aim: Point, max_step_mm: float) -> PivotMove:
        """The next move toward ``aim`` (:func:`best_pivot_move`), with the uncertainties this
        robot has: its heading from the chord of its last step (fixes about 0.7 mm off per
        axis), its turns from how many it has learned from."""
        learned = sum(len(samples) for samples in self._rate_samples.values())
        return best_pivot_move(
            position,
            heading,
            aim,
            max_step_mm,
            turn_sd=TURN_SD_LEARNED if learned >= 2 else TURN_SD_UNLEARNED,
            heading_sd_rad=max(0.03, 1.0 / max(self._heading_chord_mm, 1.0)),
            obstacles=list(self._anchors().values()),
            radius_mm=self.body_mm + self.params.clearance_mm,
            within_mm=self.hearing_mm - HEARING_MARGIN_MM,
            two_moves=self._last_plan_final,
        )

    def _short_step_mm(self, to_target_mm: float) -> float:
        """Length of a first, probe or after-long-turn step: ``first_step_mm``, longer far
        from the goal where a fix is less precise (half the far-field step fraction), but at
        most ``step_mm`` (the step may well lead away from the goal)."""
        c = self.params
        return max(c.first_step_mm, min(c.step_mm, c.step_fraction / 2 * to_target_mm))

    def _probe_turn(
        self,
        position: Point,
        heading: Point,
        alpha: float,
        step_mm: float,
        obstacles: list[Point],
        radius_mm: float,
    ) -> float:
        """A frame turn that tells the handedness: between ``probe_deg`` and 150°, as close
        to ``alpha`` as possible, whose step is clear of the robots whichever handedness the
        frame has (the robot ends up heading ``±turn`` from ``heading``)."""
        probe, limit = math.radians(self.params.probe_deg), math.radians(150)
        s = 1.0 if alpha >= 0 else -1.0
        # Preference order: the turn toward the goal itself, then the nearest big enough.
        near = (alpha, alpha + s * probe, alpha - s * probe)
        fixed = (s * math.pi / 2, -s * math.pi / 2, s * probe, -s * probe, s * limit, -s * limit)
        candidates = [wrap_angle(a) for a in (*near, *fixed)]
        valid = [a for a in candidates if probe - 1e-9 <= abs(a) <= limit]
        reach = max([self.hearing_mm - HEARING_MARGIN_MM, *(_dist(position, c) for c in obstacles)])

        def fits(turn: float) -> bool:
            arc = swing_arc(position, heading, turn)
            start = arc[-1]
            h = rotate(heading, turn)
            end = (start[0] + step_mm * h[0], start[1] + step_mm * h[1])
            return not any(
                min(_dist(p, c) for p in arc) < radius_mm - 0.5
                or segment_blocked(start, h, step_mm, c, radius_mm)
                or max(_dist(start, c), _dist(end, c)) > reach
                for c in obstacles
            )

        for a in valid:
            if fits(a) and fits(-a):
                return a
        return valid[0]

    def _learn_from_step(self, position: Point) -> None:
        """Update heading, handedness, speed and turn rate from the step just completed."""
        if self._last_mode in ("approach", "retreat") or self.position is None:
            self._heading, self._heading_measured = None, False
            return
        dx, dy = position[0] - self.position[0], position[1] - self.position[1]
        step_s = self._last_step_ticks / self.ticks_per_s
        expected = self._last_step_mm
        # A step that went less far than timed touched a body and slid: its direction is not
        # the heading, so it tells nothing about the turn before it.
        clean = expected * CLEAN_STEP_SHARE
        # The step is measured by itself when a fix followed the turn (or there was none);
        # else the turn's swing, taken out by dead reckoning, blurs it.
        direct = self._fixed_after_turn or not self._last_turn_rad
        if self._fixed_after_turn:
            self._fixed_after_turn = False
            turned = self._heading is not None and self._heading_measured and self._last_turn_rad
            if turned and math.hypot(dx, dy) >= clean:
                seen = _turn_seen(self._heading, (dx, dy))  # a straight step after the turn
                self._vote(seen, seen)
        elif self._heading is not None and self._last_turn_rad:
            # Under each handedness the turn moved the centre differently before the step.
            steps = {}
            for mirrored in (False, True):
                px, py = pivot_displacement(self._heading, self._frame_turn(mirrored))
                steps[mirrored] = (dx - px, dy - py)
            if self._heading_measured and min(math.hypot(*v) for v in steps.values()) >= clean:
                self._vote(*(_turn_seen(self._heading, steps[m]) for m in (False, True)))
            dx, dy = steps[self.mirrored]
        moved = math.hypot(dx, dy)
        if expected < 1.0:
            # A turn alone (the planner's pivot onto the aim): the heading is the old one
            # turned, as far as the handedness is known.
            trusted = self.handedness_settled and self._heading is not None
            self._heading = self._heading_after_turn() if trusted else None
            self._heading_measured = False
        elif moved >= max(3.0, 0.4 * expected):
            measured = (dx / moved, dy / moved)
            if direct and 0.7 * expected <= moved <= 1.5 * expected and step_s > 0:
                self._speed_samples.append((moved, step_s))
                total_mm = sum(m for m, _ in self._speed_samples)
                total_s = sum(s for _, s in self._speed_samples)
                self.speed_mm_s = total_mm / total_s
            self._heading, self._heading_measured = measured, True
            self._heading_chord_mm = moved
            self._blocked_steps = 0
        else:
            # Blocked (contact) or too short to tell. Dead reckoning is only trusted once the
            # handedness is known and the robot is not stuck; otherwise it escapes.
            self._blocked_steps += 1
            trusted = self.handedness_settled and self._blocked_steps < 2
            self._heading = self._heading_after_turn() if trusted else None
            self._heading_measured = False

    def _vote(self, observed_floor_rad: float | None, observed_mirror_rad: float | None) -> None:
        """Compare the rotation seen in the frame with the physical turn commanded, under each
        handedness (whose pivot displacement differs; ``None`` where the step was too short),
        and learn the turning motor's rate from it (:func:`handedness_vote`,
        :func:`turn_rate_ratio`)."""
        commanded = self._last_turn_rad
        if observed_floor_rad is None or observed_mirror_rad is None:
            return
        verdict = handedness_vote(commanded, observed_floor_rad, observed_mirror_rad)
        if verdict is not None:
            self._record_vote(verdict)
        if not (self.params.adapt_turns and self.handedness_settled):
            return
        if not math.radians(40) <= abs(commanded) <= math.radians(150):
            return
        seen = -observed_mirror_rad if self.mirrored else observed_floor_rad
        self._learn_rate(commanded, seen)

    def _learn_rate(self, commanded_rad: float, seen_physical_rad: float) -> None:
        """One sample of the turning motor's real rate over the calibrated one."""
        if not self.params.adapt_turns:
            return
        # The turn was timed for commanded / gain, so the real rate is ratio × gain.
        ratio = turn_rate_ratio(commanded_rad, seen_physical_rad) * self._last_turn_gain
        if RATE_RATIO_RANGE[0] <= ratio <= RATE_RATIO_RANGE[1]:  # else a misread turn
            side = 1 if commanded_rad > 0 else -1
            self._rate_samples[side].append(ratio)
            self.turn_gains[side] = median(self._rate_samples[side])
            self.log("turn_rate", side=side, ratio=ratio, gain=self.turn_gains[side])

    def _retreat(self) -> None:
        """Go back to where the last fix was taken. The robot does not need its heading or the
        frame's handedness for that: in its own body frame before the last move (heading +x,
        counter-clockwise = physical left), the move it made is known, and so is the way back
        (:func:`best_pivot_move`, one move)."""
        turn = self._last_turn_rad
        if turn:  # as far as it really went, by what the robot has learned since
            turn *= self.turn_gains[1 if turn > 0 else -1] / self._last_turn_gain
        step = self._last_step_ticks / self.ticks_per_s * self.speed_mm_s
        dx, dy = pivot_displacement((1.0, 0.0), turn)
        here = (dx + step * math.cos(turn), dy + step * math.sin(turn))
        move = best_pivot_move(
            here,
            (math.cos(turn), math.sin(turn)),
            (0.0, 0.0),
            max(self.params.step_mm, math.hypot(*here)),
            two_moves=False,
        )
        self._plan(move.turn_rad, move.step_mm, "retreat")

    def _record_vote(self, mirrored_vote: bool) -> None:
        """Count one conclusive reading of the handedness; the majority decides."""
        self._votes[mirrored_vote] += 1
        mirrored = self._votes[True] > self._votes[False]
        if mirrored != self.mirrored or sum(self._votes.values()) == 1:
            self.mirrored = mirrored
            self.log(
                "handedness", mirrored=mirrored, floor=self._votes[False], mirror=self._votes[True]
            )

    def _approach_step(self, usable: dict[int, float]) -> None:
        """No fix yet: walk to reduce the distance to the nearest robot heard."""
        k, d = min(usable.items(), key=lambda kv: kv[1])
        state = self._approach
        turn = 0.0
        if state is not None and state["robot"] == k and self._last_mode == "approach":
            step_mm = self._last_step_ticks / self.ticks_per_s * self.speed_mm_s
            cos_theta = max(-1.0, min(1.0, (state["distance"] - d) / step_mm))
            theta = math.acos(cos_theta)
            side = state["side"]
            if theta > math.radians(30):
                if state["turned"] and theta > 0.7 * state["theta"]:
                    side = -side  # turning that way made it worse: the robot is on the other side
                turn = side * theta
            state.update(distance=d, theta=theta, side=side, turned=float(turn != 0.0))
        else:
            state = {"robot": k, "distance": d, "theta": 0.0, "side": 1.0, "turned": 0.0}
        self._approach = state
        self._plan(turn, self.params.step_mm, "approach")

    def _plan(self, physical_turn_rad: float, step_mm: float, mode: str) -> None:
        """Start the move: a physical pivot (counter-clockwise positive), then a step."""
        if mode != "goal":
            self._last_plan_final = True  # any other move ends a two-move plan
        tps = self.ticks_per_s
        gain = self.turn_gains[1 if physical_turn_rad > 0 else -1]
        turn_s = self.calibration.turn_time_s(physical_turn_rad / gain)
        turn_ticks = round(turn_s * tps) if physical_turn_rad else 0
        step_ticks = max(1, round(step_mm / self.speed_mm_s * tps))
        self._last_turn_rad = physical_turn_rad if turn_ticks else 0.0
        self._last_turn_gain = gain
        self._last_step_mm = step_mm
        self._last_step_ticks = step_ticks
        self._last_mode = mode
        self.log(
            "move",
            mode=mode,
            turn_rad=self._last_turn_rad,
            turn_s=turn_ticks / tps,
            step_mm=step_mm,
            step_s=step_ticks / tps,
        )
        now = self.kilo_ticks
        if turn_ticks:
            self.phase = "turn"
            self.phase_end_tick = now + turn_ticks
            self.spinup_motors()  # kilolib: a motor at rest needs the burst to start
            if physical_turn_rad > 0:
                self.set_motors(self.kilo_turn_left, 0)  # kilolib: left motor turns left
            else:
                self.set_motors(0, self.kilo_turn_right)
        else:
            self._start_step(now)

    def _start_step(self, now: int) -> None:
        self.phase = "step"
        self.phase_end_tick = now + self._last_step_ticks
        self.steps += 1
        self.spinup_motors()
        self.set_motors(self.kilo_straight_left, self.kilo_straight_right)

    def _goal(self) -> Point:
        """The centroid of robots 1–3 in the frame (the seed's goal)."""
        d12, x3, y3 = self.frame
        return ((d12 + x3) / 3, y3 / 3)

    def _finish(self, outcome: str, **fields: float | str) -> None:
        self.set_motors(0, 0)
        self.outcome = outcome
        self.phase = "done"
        self.log(outcome, steps=self.steps, mirrored=self.mirrored, **fields)


def _dist(a: Point, b: Point) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def _turn_seen(heading: Point, step: Point) -> float | None:
    """The rotation from ``heading`` to the direction of ``step``; ``None`` for a step under
    3 mm, whose direction says nothing."""
    if math.hypot(*step) < 3.0:
        return None
    return turn_angle(heading, step)
