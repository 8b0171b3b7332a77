"""``kilonet analyze`` over draws of the robots and their links (issue 46, item 2).

The draws (:mod:`kilonet.scenarios.link_draws`) give the medium's links; the prediction over
them (:func:`kilonet.scenarios.analyze.predict_draws`) is a zero-width interval equal to the
deterministic prediction when every link is certain, and a wider one when a link sits at the
soft edge of its reach; the command prints both and refuses bad input in one line.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from kilonet.app.cli import main
from kilonet.params import Params
from kilonet.scenarios.analyze import predict_draws
from kilonet.scenarios.link_draws import (
    draw_held_estimates,
    link_present_probability,
    messages_before_frames,
)

#: Four robots on a 45 mm square: every distance (45, 63.6 mm) far inside the links' reach
#: (148 mm) and the neighbourhood (85 mm), so every link is certain.
SQUARE = np.array([[0.0, 0.0], [45.0, 0.0], [0.0, 45.0], [45.0, 45.0]])

#: The square and a fifth robot 35 mm beyond its right side: with a reach of 45 mm and a 6 mm
#: soft edge (the overrides below) it hears the right side (41.6 mm) in every draw and the left
#: side (83.1 mm) now and then, so whether it can localize depends on the draw.
EDGE = np.vstack([SQUARE, [[80.0, 22.5]]])
SOFT = {"medium.reach_median_mm": 45.0, "medium.edge_mm": 6.0}


def _gcs_params(overrides: dict | None = None) -> Params:
    from kilonet import scenarios
    from kilonet.scenarios.base import build_params

    return build_params(scenarios.get("gcs"), overrides or {})


def test_a_link_is_there_if_any_of_its_messages_arrives():
    got = link_present_probability(np.array([0.0, 0.01, 0.5, 1.0]), 100)
    assert got.tolist() == pytest.approx([0.0, 1 - 0.99**100, 1 - 0.5**100, 1.0])
    params = _gcs_params()
    # phase 1 (8 s) and phase 2's elections and checks (33 s), at the gcs scenario's period
    gcs = params.scenario
    window = gcs.ids_s + gcs.elect_s * (gcs.reelections + 2) + gcs.check_s * (gcs.reelections + 1)
    assert (window, params.robot.tx_period_s) == (41.0, 0.2)
    assert messages_before_frames(params) == 205
    assert messages_before_frames(_gcs_params({"robot.tx_period_s": 0.5})) == 82


def test_each_draw_draws_the_ranging_bias_of_every_link():
    params = _gcs_params()
    rng = np.random.default_rng(4)
    messages = messages_before_frames(params)
    held = np.array(
        [
            draw_held_estimates(SQUARE, params, rng, radius_mm=16.5, messages=messages)
            for _ in range(40)
        ]
    )
    side, back = held[:, 0, 1], held[:, 1, 0]  # one 45 mm link, both ways
    assert np.isfinite(held[:, ~np.eye(4, dtype=bool)]).all()  # every link, every draw
    assert len(np.unique(side)) > 5 and not np.array_equal(side, back)  # drawn, one-way
    assert abs(side.mean() - 45.0) < 5.0 and side.std() > 0.5


def test_a_link_at_the_soft_edge_is_there_in_some_draws_only():
    params = _gcs_params(SOFT)
    rng = np.random.default_rng(5)
    messages = messages_before_frames(params)
    held = np.array(
        [
            np.isfinite(draw_held_estimates(EDGE, params, rng, radius_mm=16.5, messages=messages))
            for _ in range(40)
        ]
    )
    # the square's sides (45 mm) and the fifth robot's right-side links are heard in every draw
    assert held[:, 0, 1].all() and held[:, 1, 0].all() and held[:, 1, 4].all()
    # ... the fifth robot's links from the square's left side (83.1 mm) in some draws only
    share = held[:, 0, 4].mean()
    assert 0.05 < share < 0.95, share
    # and without the soft edge's reach (the real robots' 148 mm) in all of them
    params = _gcs_params()
    always = draw_held_estimates(EDGE, params, rng, radius_mm=16.5, messages=messages)
    assert np.isfinite(always[[1, 3, 4, 4], [4, 4, 1, 3]]).all()


def test_certain_links_give_a_zero_width_interval_equal_to_the_deterministic_prediction():
    drawn = predict_draws(SQUARE, seed=2, draws=30)
    point = drawn["deterministic"]
    assert drawn["final_frames"] == dict.fromkeys(("median", "low", "high"), point["final_frames"])
    lost = len(point["unlocalizable"])
    assert drawn["unlocalizable"] == dict.fromkeys(("median", "low", "high"), lost)
    assert drawn["draws"] == 30
    assert predict_draws(SQUARE, seed=2, draws=30) == drawn  # the draws follow the seed


def test_a_link_at_the_soft_edge_widens_the_interval():
    drawn = predict_draws(EDGE, seed=3, overrides=SOFT, draws=40)
    lost = drawn["unlocalizable"]
    assert lost["low"] < lost["high"], drawn
    assert lost["low"] <= lost["median"] <= lost["high"]


def test_the_command_prints_the_interval_and_the_deterministic_prediction(tmp_path, capsys):
    placement = tmp_path / "edge.csv"
    placement.write_text("x_mm,y_mm\n" + "".join(f"{x},{y}\n" for x, y in EDGE.tolist()))
    argv = ["analyze", str(placement), "--seed", "2", "--draws", "40"]
    assert main([*argv, *(f"--set={k}={v}" for k, v in SOFT.items())]) == 0
    out = capsys.readouterr().out.splitlines()
    drawn = predict_draws(EDGE, seed=2, overrides=SOFT, draws=40)
    frames, lost = drawn["final_frames"], drawn["unlocalizable"]
    assert out[2] == "over 40 draws of the robots and their links (median, 90 % interval):"
    assert (
        out[3] == f"final global frames    {frames['median']}  [{frames['low']}, {frames['high']}]"
    )
    assert out[4] == f"cannot localize        {lost['median']}  [{lost['low']}, {lost['high']}]"
    assert out[5] == "deterministic, the links of seed 2's robots:"
    assert main([*argv, "--json", *(f"--set={k}={v}" for k, v in SOFT.items())]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["link_draws"]["unlocalizable"] == lost
    assert report["final_frames"] == drawn["deterministic"]["final_frames"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--draws", "0"], "--draws 0: give at least 1 draw"),
        (["--set", "medium.edge"], "--set expects KEY=VALUE, got 'medium.edge'"),
        (["--set", "medium.edge_mm=-3"], "medium.edge_mm"),
        (["--set", "medium.nosuch=1"], "medium.nosuch"),
    ],
)
def test_bad_input_is_refused_in_one_line_with_nothing_written(tmp_path, capsys, extra, message):
    placement = tmp_path / "square.csv"
    placement.write_text("x_mm,y_mm\n" + "".join(f"{x},{y}\n" for x, y in SQUARE.tolist()))
    before = sorted(tmp_path.iterdir())
    figure = tmp_path / "f.png"
    assert main(["analyze", str(placement), *extra, "--out", str(figure)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("kilonet: error: "), err
    assert message in lines[0], lines[0]
    assert sorted(tmp_path.iterdir()) == before
