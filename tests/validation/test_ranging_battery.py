"""kilonet's distance estimates and battery against Rubenstein et al., ICRA 2012.

The paper gives a distance accuracy of ±2 mm and a precision under 1 mm, and a battery life of
3 to 24 hours depending on activity (:data:`kilonet.experiments.studies.validation.CHECKS` holds
each row's figure and tolerance).
"""

from __future__ import annotations

import numpy as np
import pytest

from kilonet import Kilobot, Params, Simulation
from kilonet.experiments.studies import validation as v


@pytest.fixture(scope="module")
def ranging():
    return v.ranging_stats()


def test_ranging_accuracy_is_a_few_millimetres_per_link(ranging):
    check = v.CHECKS["accuracy"]
    assert check.passes(ranging["accuracy_mm"]), ranging


def test_repeated_readings_scatter_under_a_millimetre(ranging):
    check = v.CHECKS["precision"]
    assert check.passes(ranging["precision_mm"]), ranging
    assert ranging["precision_mm"] < 1.0


def test_averaging_does_not_remove_the_systematic_error(ranging):
    # Averaging 50 readings leaves each link's own error: the rms over links stays ~2 mm.
    assert ranging["accuracy_mm"] > 3 * ranging["precision_mm"] / np.sqrt(50)
    iid = v.ranging_stats({"ranging.model": "gaussian"})
    assert iid["accuracy_mm"] < 0.5  # the old model: averaging measures every link exactly


def test_estimates_saturate_beyond_the_calibration_tables():
    far = v.ranging_stats(distances_mm=(130.0, 140.0, 150.0), seeds=(1,))
    assert far["accuracy_mm"] > 10.0  # kilolib extrapolates the last table segment
    sim = Simulation([[0, 0], [140, 0]], Kilobot, Params(seed=1))
    est = [sim.medium.reception.systematic_mm(0, 1, d) for d in (100.0, 120.0, 140.0, 160.0)]
    assert est == sorted(est) and est[-1] < 140.0  # still rising, but well short of the truth


def test_the_effective_error_is_what_the_links_show(ranging):
    sim = Simulation([[0, 0], [50, 0]], Kilobot, Params(seed=1))
    sigma = sim.medium.reception.effective_sigma_mm(np.array([40.0, 50.0, 60, 70, 80, 90]), 50)
    assert np.sqrt(np.mean(sigma**2)) == pytest.approx(ranging["accuracy_mm"], rel=0.35)


class Driver(Kilobot):
    def setup(self):
        self.spinup_motors()
        self.set_motors(self.kilo_straight_left, self.kilo_straight_right)


@pytest.mark.parametrize(
    ("program", "check"), [(Driver, "battery_busy"), (Kilobot, "battery_idle")]
)
def test_battery_life(program, check):
    # One robot alone on a large table, to its battery's cut-off.
    params = Params(seed=1).with_overrides(
        {"duration_s": 40 * 3600.0, "battery.update_s": 60.0, "motion.step_s": 5.0}
    )
    sim = Simulation([[0.0, 0.0]], program, params, headings_rad=[0.0])
    sim.run()
    assert sim.stop_causes == {0: "battery"}
    hours = sim.trace.stops_frame()["t_s"].iloc[0] / 3600.0
    assert v.CHECKS[check].passes(hours), hours
    assert hours == pytest.approx(v.battery_life_h(2 if program is Driver else 0), abs=0.05)


def _calibration_csv(path, tables):
    header = [f"irhigh_{k}" for k in range(14)] + [f"irlow_{k}" for k in range(14)]
    rows = [",".join(map(str, t.irhigh + t.irlow)) for t in tables]
    path.write_text("\n".join([",".join(header), *rows]) + "\n")


def test_robots_can_carry_their_own_calibration_tables(tmp_path):
    from kilonet.ranging import calibration_tables

    tables = calibration_tables(2, np.random.default_rng(5))
    _calibration_csv(tmp_path / "cal.csv", tables)
    params = Params(seed=1).with_overrides({"ranging.calibration_file": str(tmp_path / "cal.csv")})
    sim = Simulation([[0, 0], [60, 0]], Kilobot, params)
    assert [t.irhigh for t in sim.calibration_tables] == [t.irhigh for t in tables]
    assert [t.gain for t in sim.calibration_tables] == pytest.approx(
        [t.gain for t in tables], abs=0.002
    )


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("irhigh_0\n1\n", "no column irhigh_1"),
        (None, "robots' tables for a swarm of 3"),
        ("bad", "rises with distance"),
        ("value", "irlow_13 = '2000' is not an integer 0-1023"),
    ],
)
def test_a_broken_calibration_file_is_one_line_naming_it(tmp_path, text, message):
    from kilonet.params import ParamError
    from kilonet.ranging import calibration_tables

    path = tmp_path / "cal.csv"
    tables = calibration_tables(2, np.random.default_rng(5))
    _calibration_csv(path, tables)
    if text == "bad":
        lines = path.read_text().splitlines()
        values = lines[1].split(",")
        values[3] = "1000"
        path.write_text("\n".join([lines[0], ",".join(values), lines[2]]) + "\n")
    elif text == "value":
        path.write_text(path.read_text().replace(",", ",", 0)[:-1].rsplit(",", 1)[0] + ",2000\n")
    elif text is not None:
        path.write_text(text)
    params = Params().with_overrides({"ranging.calibration_file": str(path)})
    with pytest.raises(ParamError, match=message) as error:
        Simulation([[0, 0], [60, 0], [120, 0]], Kilobot, params)
    assert "\n" not in str(error.value) and str(path) in str(error.value)
