"""Tests for kilonet.scenarios.prediction: the prediction follows the estimates the robots will
hold."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet import scenarios
from kilonet.protocols.common.geometry import (
    GeometryError,
    choose_references_max_angle,
    multilaterate,
    place_references,
)
from kilonet.protocols.gcs.frame_keys import FrameKey
from kilonet.protocols.gcs.phase3_local_frames import reference_candidates
from kilonet.scenarios.base import build_params
from kilonet.scenarios.neighbourhood import RECEPTION_NOISE_MM, held_estimates_mm, trusted_links
from kilonet.scenarios.prediction import _final_frames, predict_from_seeds

#: Seed 0 with robots 1 and 2 on opposite sides, 176° apart seen from it: |BC| = 72.54 mm reaches
#: the seed as 73 mm, longer than |AB| + |AC| = 72.59 mm, so the triangle the seed holds does not
#: exist. Robots 3-5 stand around the seed.
THIN = np.array([[0.0, 0.0], [36.0, 0.0], [-36.5, 2.5], [0.0, 36.0], [5.0, -34.0], [30.0, 30.0]])


#: The geometries here are built for the mirror test at 1 mm of assumed ranging noise, the
#: thesis's figure (the default gcs.sigma_mm assumes real robots' per-link error).
THIN_GEOMETRY = {"medium.range_mm": 85, "gcs.sigma_mm": 1.0}


def _true_estimates(pos: np.ndarray, reach_mm: float = 85.0) -> np.ndarray:
    """Estimates without systematic error: the true distances within ``reach_mm``."""
    d = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    d[(d > reach_mm) | np.eye(len(pos), dtype=bool)] = np.nan
    return d


def _distances(pos: np.ndarray, seed: int, b: int, c: int) -> tuple[float, float, float]:
    return math.dist(pos[seed], pos[b]), math.dist(pos[seed], pos[c]), math.dist(pos[b], pos[c])


def test_a_pair_that_whole_millimetres_make_degenerate_is_skipped_as_the_seed_skips_it():
    d_ab, d_ac, d_bc = _distances(THIN, 0, 1, 2)
    place_references(d_ab, d_ac, d_bc)  # with true distances the thin triangle exists ...
    with pytest.raises(GeometryError):  # ... with the tables' whole millimetres it does not
        place_references(d_ab, d_ac, round(d_bc))
    # The seed's own choice, from its distances and its neighbours' whole-mm tables:
    ids = range(1, len(THIN))
    tables = {b: {c: round(math.dist(THIN[b], THIN[c])) for c in ids if c != b} for b in ids}
    own = {b: math.dist(THIN[0], THIN[b]) for b in ids}
    (b, c), _ = choose_references_max_angle(reference_candidates(own, tables, tolerance_mm=5.0))
    assert {b, c} != {1, 2}
    # The prediction skips the pair too, so every robot is located in seed 0's frame; with the
    # thin pair, three nearly collinear anchors would have left robots 3-5 unlocalizable.
    params = build_params(scenarios.get("gcs"), THIN_GEOMETRY)
    prediction = predict_from_seeds(_true_estimates(THIN), params, [0])
    assert prediction["located_in"] == {i: [0] for i in range(len(THIN))}
    assert prediction["unlocalizable"] == []


def test_a_systematic_error_of_half_a_millimetre_makes_the_thin_pair_the_seeds_references():
    # The seed's estimate of robot 1 reads 0.5 mm long (a real link's systematic error is
    # several mm): |AB| + |AC| = 73.09 mm now exceeds the tables' |BC| = 73 mm, so the thin
    # triangle exists, the largest-angle rule takes it, and robots 3-5 face three nearly
    # collinear anchors: unlocalizable. From true distances they were all located.
    params = build_params(scenarios.get("gcs"), THIN_GEOMETRY)
    estimates = _true_estimates(THIN)
    estimates[1, 0] += 0.5  # [sender, receiver]: the seed's estimate of robot 1
    prediction = predict_from_seeds(estimates, params, [0])
    assert prediction["located_in"] == {0: [0], 1: [0], 2: [0], 3: [], 4: [], 5: []}
    assert prediction["unlocalizable"] == [3, 4, 5]
    # The error is one direction's: robot 1's estimate of the seed reading long changes nothing.
    estimates = _true_estimates(THIN)
    estimates[0, 1] += 0.5
    assert predict_from_seeds(estimates, params, [0])["unlocalizable"] == []


def test_a_robot_that_estimates_the_seed_beyond_the_limit_does_not_join_its_frame():
    # Robot 5 stands 42 mm from the seed but reads it beyond gcs.neighbour_max_mm (85 mm): it
    # ignores the seed, so it is located in no frame, though the seed still hears it.
    params = build_params(scenarios.get("gcs"), THIN_GEOMETRY)
    estimates = _true_estimates(THIN)
    estimates[0, 5] = params.scenario.neighbour_max_mm + 1.0
    prediction = predict_from_seeds(estimates, params, [0])
    assert prediction["unlocalizable"] == [5]
    assert all(prediction["located_in"][i] == [0] for i in range(5))


def test_robots_are_located_where_the_seeds_frame_puts_their_anchors():
    # References 174° apart: |BC| = 66.08 mm reaches the seed as 66 mm, which puts C 4.5 mm off
    # line AB instead of 3.3 mm. In that wider frame robot 3's fix from the seed and the two
    # references passes the mirror test; with the anchors where they truly are it does not.
    pos = np.array([[0.0, 0.0], [36.0, 0.0], [-30.0, 3.3], [0.0, 38.0]])
    anchors, ranges = pos[:3], np.linalg.norm(pos[:3] - pos[3], axis=1)
    assert multilaterate(anchors, ranges, max_rmse_mm=4.0).reason == "mirror_ambiguity"
    b, c = place_references(*_distances(pos, 0, 1, 2)[:2], round(math.dist(pos[1], pos[2])))
    assert multilaterate(np.array([(0.0, 0.0), b, c]), ranges, max_rmse_mm=4.0).ok
    params = build_params(scenarios.get("gcs"), THIN_GEOMETRY)
    prediction = predict_from_seeds(_true_estimates(pos), params, [0])
    assert prediction["located_in"] == {0: [0], 1: [0], 2: [0], 3: [0]}


def test_a_robot_reports_an_isolated_seeds_frame_only_when_it_has_no_other():
    # Components: seeds 1 and 2 merged, seed 0 isolated with the smallest key. Robot 5 is in
    # frames 0 and 1, robot 6 in frame 0 alone (the protocol ranks isolated roots last).
    frames, keys = [[1, 2], [0]], {0: FrameKey(3, 0), 1: FrameKey(7, 0), 2: FrameKey(9, 0)}
    located = {5: [0, 1], 6: [0], 7: []}
    assert _final_frames(frames, located, keys, isolated=[0]) == {5: 0, 6: 1, 7: None}
    assert _final_frames(frames, located, keys)[5] == 1  # by keys alone the isolated one wins


def test_the_tables_hold_the_links_the_noise_brings_within_the_limit_at_about_the_limit():
    # A real-Kilobot medium (its estimates carry per-link systematic errors), without running.
    result = scenarios.run(
        scenarios.get("gcs"),
        {
            "placement.kind": "random",
            "placement.area": "disc",
            "placement.robots": 30,
            "placement.density_per_m2": 300,
            "gcs.until": "ids",
            "gcs.ids_s": 0.5,
        },
        seed=1,
    )
    sim, limit = result.sim, 85.0
    held = held_estimates_mm(sim, limit)
    within = trusted_links(sim, limit)
    beyond = trusted_links(sim, limit, -RECEPTION_NOISE_MM)
    assert set(within.edges) < set(beyond.edges)  # some links only the noise brings in
    # Each entry is the noise's dithered mean around the link's whole-mm noise-free estimate,
    # within the limit.
    for s, r, estimate in beyond.edges(data="estimate_mm"):
        assert held[s, r] <= limit
        assert abs(held[s, r] - min(estimate, limit)) <= 1.0
    assert np.mean(held[~np.isnan(held)] % 1.0 != 0.0) > 0.5  # mostly between the steps
    assert np.count_nonzero(~np.isnan(held)) == beyond.number_of_edges()
    # Directed: the two ends of a link estimate it differently.
    assert any(held[s, r] != held[r, s] for s, r in beyond.edges if beyond.has_edge(r, s))
