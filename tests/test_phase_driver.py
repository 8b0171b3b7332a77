"""The phased-protocol driver (kilonet.protocols.common.phases.PhaseDriver): the running phase,
receive handlers by message type byte, and window-or-finished transitions."""

from __future__ import annotations

import math

from kilonet.protocols.common.phases import Phase, PhaseDriver, Stage


class Steps(Stage):
    ONE = "one"
    TWO = "two"
    THREE = "three"


class Recorded(Phase):
    """A phase that records its calls in a shared list and ends when told to."""

    def __init__(self, name: Steps, calls: list[str], *, after: Phase | None = None, **handlers):
        self.name = name
        self.calls = calls
        self.after = after
        self.done = False
        self.table = {int(kind[1:]): handler for kind, handler in handlers.items()}
        self.handler_tables = 0

    def start(self) -> None:
        self.calls.append(f"start {self.name}")

    def finish(self) -> None:
        self.calls.append(f"finish {self.name}")

    def finished(self) -> bool:
        return self.done

    def handlers(self):
        self.handler_tables += 1
        return self.table

    def following(self) -> Phase | None:
        self.calls.append(f"following {self.name}")
        return self.after


def test_a_new_driver_runs_no_phase_and_dispatches_the_protocols_handlers():
    driver = PhaseDriver({5: "five"})
    assert (driver.phase, driver.stage, driver.until) == (None, "", math.inf)
    assert (driver.handler(5), driver.handler(6)) == ("five", None)
    assert driver.advance(10**9) is False


def test_a_phase_replaces_the_handlers_it_names_only_while_it_runs():
    calls: list[str] = []
    two = Recorded(Steps.TWO, calls)
    one = Recorded(Steps.ONE, calls, after=two, t5="one's five", t9="one's nine")
    driver = PhaseDriver({5: "five", 6: "six"})
    driver.enter(one)
    assert [driver.handler(k) for k in (5, 6, 9)] == ["one's five", "six", "one's nine"]
    one.done = True
    assert driver.advance(0) is True
    assert driver.phase is two
    assert [driver.handler(k) for k in (5, 6, 9)] == ["five", "six", None]


def test_the_handler_table_is_built_once_per_phase_not_per_message():
    one = Recorded(Steps.ONE, [], t5="one's five")
    driver = PhaseDriver({})
    driver.enter(one)
    for _ in range(100):
        driver.handler(5)
    assert one.handler_tables == 1


def test_a_window_ends_its_phase_at_its_closing_tick_and_the_next_is_open_ended():
    calls: list[str] = []
    two = Recorded(Steps.TWO, calls)
    one = Recorded(Steps.ONE, calls, after=two)
    driver = PhaseDriver({})
    driver.enter(one, until=50)
    assert (driver.advance(49), driver.stage) == (False, "one")
    assert (driver.advance(50), driver.stage, driver.until) == (True, "two", math.inf)
    assert calls == ["start one", "following one", "finish one", "start two"]


def test_finished_phases_hand_on_in_one_advance_until_one_runs_on():
    calls: list[str] = []
    three = Recorded(Steps.THREE, calls)
    two = Recorded(Steps.TWO, calls, after=three)
    one = Recorded(Steps.ONE, calls, after=two)
    driver = PhaseDriver({})
    driver.enter(one)
    one.done = two.done = True
    assert driver.advance(0) is True
    assert driver.phase is three
    assert calls == [
        "start one",
        "following one",
        "finish one",
        "start two",
        "following two",
        "finish two",
        "start three",
    ]
    assert driver.stage == Steps.THREE and driver.stage.number == 3


def test_the_last_phase_hands_on_to_none_and_the_driver_falls_back_to_the_protocols_table():
    calls: list[str] = []
    one = Recorded(Steps.ONE, calls, t5="one's five")
    driver = PhaseDriver({5: "five"})
    driver.enter(one)
    one.done = True
    assert driver.advance(0) is True
    assert (driver.phase, driver.stage, driver.handler(5)) == (None, "", "five")
    assert calls[-1] == "finish one"
    assert driver.advance(1) is False


def test_entering_a_phase_directly_finishes_the_running_one_first():
    calls: list[str] = []
    one = Recorded(Steps.ONE, calls)
    driver = PhaseDriver({})
    driver.enter(one, until=10)
    driver.enter(Recorded(Steps.TWO, calls))
    assert calls == ["start one", "finish one", "start two"]
    assert driver.until == math.inf
