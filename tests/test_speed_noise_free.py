"""Noise-free estimates of many links at once (the reception models' ``noise_free_mm``, which
the scenarios' truth of who ranges whom is built from) give, link by link, what kilolib's own
``estimate_distance`` gives on that link's readings."""

from __future__ import annotations

import numpy as np

from kilonet.params import Params
from kilonet.ranging import DistanceMeasurement, estimate_distance, intensity, readings
from kilonet.reception import GaussianRanging
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation


def _links(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pairs = np.array([(s, r) for s in range(n) for r in range(n) if s != r])
    return pairs[:, 0], pairs[:, 1], rng.uniform(30.0, 220.0, len(pairs))


def test_table_model_noise_free_mm_is_kilolibs_estimate_on_each_link():
    sim = Simulation(np.c_[np.arange(9) * 40.0, np.zeros(9)], lambda i: Kilobot())
    model = sim.medium.reception
    senders, receivers, distances = _links(9, np.random.default_rng(3))
    many = model.noise_free_mm(senders, receivers, distances)
    rg = sim.params.ranging
    for s, r, d, got in zip(senders, receivers, distances, many, strict=True):
        tables = sim.calibration_tables[r]
        strength = sim.transceivers.strength[s]
        high, low = readings(strength * tables.gain * intensity(max(d - 33.0, 0.0)))
        m = DistanceMeasurement(int(np.rint(low)), int(np.rint(high)))
        assert got == min(max(estimate_distance(m, tables), rg.min_mm), rg.max_mm)
        assert got == model.systematic_mm(int(s), int(r), float(d))
    assert len(set(many.tolist())) > 20  # the links do differ


def test_gaussian_model_noise_free_mm_is_distance_plus_receiver_bias():
    params = Params().with_overrides({"ranging.bias_sigma_mm": 2.0})
    rng = np.random.default_rng(0)
    model = GaussianRanging(params, 5, rng, rng)
    senders, receivers, distances = _links(5, rng)
    expected = [d + model.bias_mm[r] for r, d in zip(receivers, distances, strict=True)]
    assert model.noise_free_mm(senders, receivers, distances).tolist() == expected
