"""robots.csv's aligned estimates and errors (gcs, localize) and the estimates-against-truth
figure both scenarios draw (scenarios/estimates.py, scenarios/figures.py)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from matplotlib.collections import LineCollection
from PIL import Image

from kilonet import scenarios
from kilonet.scenarios.estimates import ALIGNED_COLUMNS, with_alignment
from kilonet.scenarios.figures import MAX_LEGEND_FRAMES, error_magnification, frames_figure


@pytest.fixture(scope="module", params=["gcs", "localize"])
def run_dir(request, tmp_path_factory):
    """A small run of each scenario written as ``kilonet run --out`` writes it."""
    result = scenarios.run(scenarios.get(request.param), {"placement.robots": 14}, seed=4)
    out = tmp_path_factory.mktemp(request.param) / "run"
    scenarios.write_outputs(result, out)
    return result, out


def test_robots_csv_has_the_aligned_estimate_and_its_error(run_dir):
    result, out = run_dir
    robots = pd.read_csv(out / "robots.csv")
    assert set(ALIGNED_COLUMNS) <= set(robots.columns)
    truth = robots[["x0_mm", "y0_mm"]].to_numpy()
    aligned = robots[["aligned_x_mm", "aligned_y_mm"]].to_numpy()
    located = robots.localized.to_numpy(dtype=bool)
    assert located.sum() >= 3
    # error_mm is the aligned estimate's distance from the truth, robot by robot ...
    np.testing.assert_allclose(robots.error_mm, np.hypot(*(aligned - truth).T), atol=1e-6)
    # ... its root mean square is the summary's RMSE (the same alignment) ...
    error = robots.error_mm.to_numpy()
    assert math.sqrt(np.nanmean(error**2)) == pytest.approx(result.summary["rmse_mm"], rel=1e-6)
    # ... and robots without an estimate have none.
    assert robots.loc[~located, list(ALIGNED_COLUMNS)].isna().all().all()
    roots = robots.root_robot[located].unique()
    assert all(robots.localized[r] for r in roots)


def test_aligned_estimates_undo_a_rotation_and_reflection_per_frame():
    truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0], [80.0, 0.0], [120.0, 0.0]])
    est = truth @ np.array([[0.0, 1.0], [-1.0, 0.0]]) + [300.0, -20.0]  # turned and shifted
    est[:3, 1] *= -1  # frame a is mirrored too
    table = pd.DataFrame(
        {
            "robot": range(5),
            "est_x_mm": est[:, 0],
            "est_y_mm": est[:, 1],
            "frame": ["a", "a", "a", "b", "b"],
            "localized": True,
        }
    )
    out = with_alignment(table, truth)
    np.testing.assert_allclose(out[["aligned_x_mm", "aligned_y_mm"]][:3], truth[:3], atol=1e-9)
    np.testing.assert_allclose(out.error_mm[:3], 0.0, atol=1e-9)
    # Frame b has two robots: it cannot be aligned, so it has no aligned estimate.
    assert out.loc[3:, list(ALIGNED_COLUMNS)].isna().all().all()
    # One robot 3 mm off: the best fit spreads it over the frame, below the unfitted RMS.
    table.loc[0, "est_y_mm"] += 3.0
    error = with_alignment(table, truth).error_mm[:3]
    assert 0.5 < math.sqrt(np.mean(error**2)) < math.sqrt(3.0**2 / 3)


def _strip(errors_mm: float = 1.0) -> tuple[np.ndarray, pd.DataFrame]:
    """A 160 x 40 mm swarm of 10 robots: frames of 6 (root robot 3) and 3 (root robot 8), one
    robot alone in a frame and none unlocalized; every aligned estimate ``errors_mm`` off."""
    truth = np.array([[x, y] for y in (0.0, 40.0) for x in (0.0, 40.0, 80.0, 120.0, 160.0)])
    frame = ["root77", "root77", "root77", "root77", "root77", "root77", "r5", "r5", "r5", "x"]
    root = [3] * 6 + [8] * 3 + [9]
    angle = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    aligned = truth + errors_mm * np.column_stack([np.cos(angle), np.sin(angle)])
    aligned[9] = np.nan
    table = pd.DataFrame(
        {
            "robot": range(10),
            "frame": frame,
            "root_robot": root,
            "localized": True,
            "aligned_x_mm": aligned[:, 0],
            "aligned_y_mm": aligned[:, 1],
        }
    )
    table["error_mm"] = np.hypot(*(aligned - truth).T)
    return truth, table


def test_a_wide_swarm_gets_a_wide_figure_with_the_legend_outside(tmp_path):
    truth, table = _strip()
    path = tmp_path / "f.png"
    fig = frames_figure(truth, table, np.array([3, 8]), "root", "strip", path)
    fig.canvas.draw()
    ax = fig.axes[0]
    box = ax.get_window_extent()
    # The axes take the data's aspect: (160 + 2 * 26.5) mm by (40 + 2 * 26.5) mm.
    assert box.width / box.height == pytest.approx(213 / 93, rel=0.01)
    legend = ax.get_legend().get_window_extent()
    assert legend.y1 < box.y0  # wholly below the axes: it covers no robot
    width, height = Image.open(path).size
    assert width / height > 1.3  # not a square canvas


def test_errors_are_magnified_and_the_legend_says_by_how_much(tmp_path):
    truth, table = _strip(errors_mm=1.0)
    fig = frames_figure(truth, table, np.array([3]), "root", "strip", tmp_path / "f.png")
    ax = fig.axes[0]
    factor = error_magnification(table.error_mm.to_numpy())
    assert factor == 10.0
    (vectors,) = [c for c in ax.collections if isinstance(c, LineCollection)]
    segments = np.array(vectors.get_segments())
    aligned = table[["aligned_x_mm", "aligned_y_mm"]].to_numpy()[:9]
    np.testing.assert_allclose(segments[:, 0], truth[:9])
    np.testing.assert_allclose(segments[:, 1], truth[:9] + 10.0 * (aligned - truth[:9]))
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(label.startswith("error × 10: ") for label in labels)
    # Frames by size, named by their root robot; the single robot's frame cannot be aligned.
    assert "frame 1 (root: robot 3), 6 robots" in labels
    assert "frame 2 (root: robot 8), 3 robots" in labels
    assert "in a frame of < 3 robots, not aligned (1)" in labels


def test_large_errors_are_drawn_at_true_scale_and_many_frames_share_an_entry(tmp_path):
    truth = np.column_stack([np.arange(30) * 40.0, np.zeros(30)])
    table = pd.DataFrame(
        {
            "robot": range(30),
            "frame": [f"f{k // 3}" for k in range(30)],
            "root_robot": [k // 3 * 3 for k in range(30)],
            "localized": True,
            "aligned_x_mm": truth[:, 0],
            "aligned_y_mm": truth[:, 1] + 20.0,
            "error_mm": 20.0,
        }
    )
    fig = frames_figure(truth, table, np.array([], dtype=int), "seed", "t", tmp_path / "f.png")
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any(label.startswith("error (true scale): ") for label in labels)
    assert sum(label.startswith("frame ") for label in labels) == MAX_LEGEND_FRAMES
    assert f"{10 - MAX_LEGEND_FRAMES} smaller frames" in labels


@pytest.mark.parametrize("run_dir", ["gcs"], indirect=True)
def test_gcs_records_no_global_estimate_before_merging(run_dir):
    from kilonet.protocols.gcs.program import phase_windows_s

    result, out = run_dir
    start = {name: start for name, start, _ in phase_windows_s(result.params.scenario)}
    held = pd.read_csv(out / "estimates.csv")
    # Each robot enters merging on its own drifting clock, a second or so around the nominal
    # window: none holds a global estimate in phases 1-4.
    assert len(held) and start["groups"] < held.t_s.min() <= start["merge"] + 2.0
    # What each robot held last is what robots.csv reports, in the same frame.
    last = held.groupby("robot").last()
    robots = pd.read_csv(out / "robots.csv").set_index("robot")
    np.testing.assert_allclose(last.x_mm, robots.est_x_mm[last.index], atol=0.05)
    assert (last.frame == robots.frame[last.index]).all()
