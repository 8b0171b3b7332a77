"""gcs on the one phased-protocol driver (issue 42, item 4): the driver's windows, its
``entered`` callback and ``ask``; gcs's phases as one list; and a phase defined here alone,
inserted into the sequence, running in a small gcs run."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, replace
from typing import ClassVar

import pytest

from kilonet import scenarios
from kilonet.params import param
from kilonet.protocols.common.phases import Phase as BasePhase
from kilonet.protocols.common.phases import PhaseDriver, Stage
from kilonet.protocols.gcs import program
from kilonet.protocols.gcs.base import PHASES, SEQUENCE, GcsParams, GcsStage, Phase
from kilonet.scenarios.base import build_params, place
from kilonet.simulation import Simulation


# -- the driver ------------------------------------------------------------------------------
class Step(Stage):
    FIRST = "first"
    SECOND = "second"


class Windowed(BasePhase):
    """A phase with a window of its own (``until``), that counts how often it is asked
    whether it is over."""

    def __init__(self, name: Step, until: float, calls: list[str], after: BasePhase | None = None):
        self.name, self.until, self.calls, self.after = name, until, calls, after
        self.asked = 0

    def start(self) -> None:
        self.calls.append(f"start {self.name}")

    def finish(self) -> None:
        self.calls.append(f"finish {self.name}")

    def finished(self) -> bool:
        self.asked += 1
        return False

    def following(self) -> BasePhase | None:
        return self.after


def test_the_driver_enters_a_phase_with_its_own_window_and_hands_on_with_the_next_ones():
    calls: list[str] = []
    second = Windowed(Step.SECOND, 80, calls)
    first = Windowed(Step.FIRST, 50, calls, after=second)
    driver = PhaseDriver({}, entered=lambda phase: calls.append(f"entered {phase.name}"))
    driver.enter(first)
    assert driver.until == 50
    assert driver.advance(50, ask=False) is True
    assert (driver.phase, driver.until) == (second, 80)
    assert calls == [
        "entered first",
        "start first",
        "finish first",
        "entered second",
        "start second",
    ]
    assert driver.advance(79) is False and second.asked == 1
    assert driver.advance(200, ask=False) is True
    assert (driver.phase, driver.until) == (None, math.inf)


def test_without_ask_only_a_window_ends_a_phase_and_a_reschedule_moves_it():
    calls: list[str] = []
    phase = Windowed(Step.FIRST, math.inf, calls)
    driver = PhaseDriver({})
    driver.enter(phase)
    assert driver.advance(10**6, ask=False) is False
    assert phase.asked == 0  # not asked at all
    driver.reschedule(30)
    assert driver.advance(29, ask=False) is False
    assert driver.advance(30, ask=False) is True and driver.phase is None
    assert calls == ["start first", "finish first"]


def test_a_window_given_to_enter_overrides_the_phases_own():
    driver = PhaseDriver({})
    driver.enter(Windowed(Step.FIRST, 50, []), until=20)
    assert driver.until == 20


# -- gcs's phases are one list ---------------------------------------------------------------
def test_stages_choices_and_classes_all_come_from_the_one_sequence():
    names = tuple(name for name, _ in SEQUENCE)
    assert PHASES == names == GcsStage.names()
    assert tuple(cls.name for cls in program.PHASE_SEQUENCE) == names
    for (_, path), cls in zip(SEQUENCE, program.PHASE_SEQUENCE, strict=True):
        module, _, attribute = path.partition(":")
        assert (cls.__module__, cls.__name__) == (f"kilonet.protocols.gcs.{module}", attribute)


def test_a_sequence_line_naming_the_wrong_class_fails_in_one_line():
    with pytest.raises(TypeError, match=r"^gcs SEQUENCE: phase1_unique_ids:UniqueIds is no phase "):
        program._phase_class("seeds", "phase1_unique_ids:UniqueIds")
    with pytest.raises(TypeError, match="no phase of stage 'ids'"):
        program._phase_class("ids", "base:GcsParams")


# -- a phase defined here alone runs in a gcs run ----------------------------------------------
class PauseStage(Stage):
    PAUSE = "pause"


@dataclass(frozen=True)
class PauseParams(GcsParams):
    """GcsParams with the pause's window: as GcsParams would declare it."""

    pause_s: float = param(2.0, lo=0.5, hi=60.0, doc="the pause's window")


class Pause(Phase):
    """Every robot holds still and silent for its window, ``gcs.pause_s``; each records the
    ticks (on its own clock) it started and finished at in ``spans``."""

    name = PauseStage.PAUSE
    spans: ClassVar[list[tuple[int, int]]] = []

    @staticmethod
    def window_s(p: PauseParams) -> float:
        return p.pause_s

    def start(self) -> None:
        self.loops = 0
        self.started = self.robot.kilo_ticks

    def loop(self) -> None:
        self.loops += 1

    def finish(self) -> None:
        self.spans.append((self.started, self.robot.kilo_ticks))


def test_a_phase_inserted_into_the_sequence_runs_in_its_window(monkeypatch):
    sequence = list(program.PHASE_SEQUENCE)
    sequence.insert(PHASES.index("frames") + 1, Pause)
    monkeypatch.setattr(program, "PHASE_SEQUENCE", tuple(sequence))
    monkeypatch.setattr(Pause, "spans", [])
    gcs = scenarios.get("gcs")
    params = build_params(gcs, {"placement.robots": 7, "gcs.until": "localization"})
    params = replace(params, scenario=PauseParams(**asdict(params.scenario)))
    params = params.with_overrides({"gcs.pause_s": "3"})  # as --set gcs.pause_s=3 would
    windows = program.phase_windows_s(params.scenario)
    assert [str(name) for name, _, _ in windows] == [
        "ids",
        "seeds",
        "frames",
        "pause",
        "localization",
    ]
    _, pause_start, pause_end = windows[3]
    assert pause_end - pause_start == 3.0
    positions = place(gcs, params)
    sim = Simulation(positions, gcs.setup.program(params, positions), params)
    sim.run(pause_start + 1.0)
    assert all(r.phase_name == "pause" and r.phase.loops > 0 for r in sim.robots)
    sim.run(pause_end + 1.0)
    assert all(r.phase_name == "localization" for r in sim.robots)
    events = sim.trace.events_frame()
    phases = events[events.event == "phase"]
    for robot in range(len(sim.robots)):  # in the trace, in its place
        names = [json.loads(d)["name"] for d in phases[phases.robot == robot].data]
        assert names == ["ids", "seeds", "frames", "pause", "localization"]
    # Each robot paused for its window on its own clock (its loop runs every other tick).
    tps = sim.robots[0].ticks_per_s
    assert len(Pause.spans) == len(sim.robots)
    for started, finished in Pause.spans:
        assert started == pytest.approx(pause_start * tps, abs=2)
        assert finished - started == pytest.approx(3.0 * tps, abs=2)
