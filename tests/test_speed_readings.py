"""The reception model's one-look-up estimates against the careful path (issue 44).

:class:`kilonet.ranging.ReadingLookup` answers a pair of readings from one intensity with one
look-up in a table per robot; the careful path is :meth:`kilonet.ranging.TableLookup.estimates`
(kilolib's interpolation on each table and its blend) followed by the clip. Both must give the
same estimate for every intensity a reception can have, and the draws of a run must not change.
"""

from __future__ import annotations

import numpy as np
import pytest

from kilonet.params import Params
from kilonet.ranging import (
    ReadingLookup,
    TableLookup,
    calibration_tables,
    estimate_distance_array,
    intensity,
    readings,
)
from kilonet.reception import LossShares, TableRanging


def _lookup(n: int, seed: int = 1) -> tuple[TableLookup, np.ndarray, np.ndarray]:
    tables = calibration_tables(n, np.random.default_rng(seed))
    irhigh = np.array([t.irhigh for t in tables])
    irlow = np.array([t.irlow for t in tables])
    return TableLookup(irhigh, irlow), irhigh, irlow


def test_every_blended_high_reading_keeps_its_low_readings_in_its_band() -> None:
    lookup, _, _ = _lookup(2)
    fast = ReadingLookup(lookup, 0, 255)
    high = np.arange(701, 900)
    # the intensity band of high reading h, widened past its edges
    edges = np.stack([(high - 40.5) / 1400.0 - 1e-9, (high - 39.5) / 1400.0 + 1e-9])
    _, low = readings(edges)
    slots = fast._offset[high] + np.rint(low).astype(np.intp) - (701 + 4 * (high - 701))
    assert slots.min() >= 0 and slots.max() <= ReadingLookup._BAND - 1


@pytest.mark.parametrize(("min_mm", "max_mm"), [(0, 255), (40, 90)])
def test_one_look_up_gives_kilolibs_estimate_for_every_intensity(min_mm: int, max_mm: int) -> None:
    lookup, irhigh, irlow = _lookup(7)
    fast = ReadingLookup(lookup, min_mm, max_mm)
    # every reading pair an intensity from 0 to saturation can give, on every robot
    intensity = np.linspace(0.0, 1.2, 400_001)
    high, low = readings(intensity)
    high, low = np.rint(high), np.rint(low)
    assert len(np.unique(high)) == 1023 - 40 + 1  # every high reading from the floor on
    for robot in range(7):
        receivers = np.full(len(intensity), robot)
        careful = np.clip(lookup.estimates(high, low, receivers), min_mm, max_mm)
        kilolib = estimate_distance_array(high, low, irhigh[receivers], irlow[receivers]).clip(
            min_mm, max_mm
        )
        got = fast.estimates(high, low, receivers)
        assert got.dtype == np.uint8
        assert np.array_equal(got, careful)
        assert np.array_equal(got, kilolib)


def test_the_models_draws_are_the_careful_paths_bit_for_bit() -> None:
    n = 30
    tables = calibration_tables(n, np.random.default_rng(3))
    strength = np.exp(0.1 * np.random.default_rng(4).standard_normal(n))
    params = Params()

    def model() -> TableRanging:
        return TableRanging(
            params,
            n,
            np.random.default_rng(5),
            np.random.default_rng(6),
            tables=tables,
            strength=strength,
        )

    fast, careful = model(), model()
    receivers = np.arange(1, n)
    distance = np.linspace(34.0, 130.0, n - 1)
    shares = LossShares(0.0, *(np.zeros(n - 1),) * 4)
    for rows in (1, 8, 64):
        got = fast.draw(0, receivers, distance, shares, rows).estimates
        # the careful path on the same draws: the model's own arithmetic, then
        # TableLookup.estimates and the clip
        noise = careful._ranging_rng.standard_normal((rows, len(receivers)))
        noise *= params.ranging.intensity_noise
        noise += 1.0
        mean = strength[0] * careful._gain[receivers] * intensity(np.maximum(distance - 33, 0))
        high, low = readings(np.maximum(noise * mean, 0.0))
        want = careful._table_lookup().estimates(np.rint(high), np.rint(low), receivers)
        want = np.clip(want, params.ranging.min_mm, params.ranging.max_mm).astype(np.uint8)
        assert np.array_equal(got, want)
