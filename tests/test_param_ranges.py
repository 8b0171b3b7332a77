"""Parameter ranges exclude values that cannot work, and the kernel does not spin on one that
slips past validation (parameters built in code)."""

from __future__ import annotations

import dataclasses

import pytest

import kilonet.app.cli
from kilonet.medium import BACKOFF_MAX_FLOOR_S
from kilonet.message import Message
from kilonet.params import MediumParams, Params
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation


@pytest.mark.parametrize("value", ["0", "1e-12", "1e-9", "0.0001"])
def test_a_back_off_shorter_than_one_kilolib_timer_count_is_refused(tmp_path, capsys, value):
    argv = ["run", "gradient", "--robots", "3", "--duration", "1"]
    argv += ["--set", f"medium.backoff_max_s={value}", "--out", str(tmp_path / "out")]
    assert kilonet.app.cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err == (
        f"kilonet: error: medium.backoff_max_s = {float(value)} is out of range [0.000128, 10.0]\n"
    )
    assert not (tmp_path / "out").exists()


def test_the_lower_bound_is_one_count_of_kilolibs_timer():
    field = {f.name: f for f in dataclasses.fields(MediumParams)}["backoff_max_s"]
    assert field.metadata["lo"] == BACKOFF_MAX_FLOOR_S == 256 / 8e6 * 4  # 1024 / 8 MHz
    Params().with_overrides({"medium.backoff_max_s": BACKOFF_MAX_FLOOR_S})  # allowed


class Chatter(Kilobot):
    """Offers the same message at every opportunity."""

    def setup(self) -> None:
        self.msg = Message(bytes([self.kilo_uid]))

    def message_tx(self) -> Message:
        return self.msg


@pytest.mark.parametrize("backoff_max_s", [0.0, 1e-12])
def test_a_zero_back_off_built_in_code_cannot_spin(backoff_max_s):
    # A value slipped past validation (Params check their ranges when built, so only forcing
    # the frozen field gets it there): the medium still waits up to one timer count, so a
    # run of 3 robots for 1 s stays a few thousand events instead of never ending.
    params = Params(seed=3).with_overrides({"battery.enabled": False, "robot.tx_period_s": 0.01})
    object.__setattr__(params.medium, "backoff_max_s", backoff_max_s)
    sim = Simulation([(0.0, 0.0), (40.0, 0.0), (80.0, 0.0)], lambda i: Chatter(), params)
    sim.start()
    steps = 0
    while sim.env.peek() < 1.0 and steps < 200_000:  # a bound on events, so a spin fails
        sim.env.step()
        steps += 1
    assert sim.env.now > 0.99, f"{steps} events reached only t = {sim.env.now} s"
    counters = sim.medium.counters
    backoffs, sent = sum(counters["backoffs"]), sum(counters["sent"])
    assert sent > 100
    # each back-off waits U(0, 128 µs): at most a few dozen per airtime of 3.2 ms a sender hears
    assert 0 < backoffs < 100 * sent
