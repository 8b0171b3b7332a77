"""kilonet.experiments.studies.localization_study: the tables it builds from the two sweeps'
results, on a small results table written out by hand (the columns a results store gives)."""

from __future__ import annotations

import pandas as pd
import pytest

from kilonet.experiments.studies.localization_study import (
    base_table,
    comparison,
    joined,
    lattice_table,
    shape_runs_table,
    shapes_table,
    summary_table,
    targets_table,
)

BASE = {
    "placement.kind": "random",
    "placement.density_per_m2": 400,
    "ranging.intensity_noise": 0.015,
    "medium.loss_prob": 0.0,
    "placement.robots": 150,
}


def _run(seed, frames, rmse, **changes):
    row = {**BASE, **changes, "seed": seed, "status": "ok"}
    row.update(
        frames=frames,
        localized_fraction=1.0,
        largest_frame_fraction=1.0 / frames,
        rmse_mm=rmse,
        crlb_rmse_mm=1.0,
        crlb_received_rmse_mm=0.1,
        rmse_over_crlb=rmse / 1.0,
        rmse_over_crlb_received=rmse / 0.1,
        central_rmse_mm=0.1,
        central_localized_fraction=1.0,
        largest_frame_over_central=1.0 / frames,
        at_optimum_over_central=0.96 / frames,
        done_over_hop_limit=10.0 * frames,
        mean_neighbours=7.0 if (changes.get("placement.density_per_m2") or 400) >= 400 else 5.0,
    )
    return row


@pytest.fixture
def results():
    localize = pd.DataFrame(
        [
            _run(1, 1, 0.2),
            _run(2, 1, 0.4),
            _run(1, 1, 0.3, **{"medium.loss_prob": 0.2}),
            _run(1, 2, 0.5, **{"placement.density_per_m2": 300}),
            _run(1, 1, 0.1, **{"placement.kind": "hex", "placement.robots": 1000}),
        ]
    )
    gcs = pd.concat(
        [
            localize.assign(**{"gcs.refine": False, "frames": 4, "largest_frame_fraction": 0.25}),
            localize.assign(**{"gcs.refine": True, "frames": 4, "largest_frame_fraction": 0.25}),
        ],
        ignore_index=True,
    )
    return gcs, localize


def test_joined_has_a_row_per_run_and_variant(results):
    table = joined(*results)
    assert table.groupby("variant").size().to_dict() == {
        "central": 5,
        "gcs": 5,
        "gcs + refine": 5,
        "localize": 5,
    }
    loc = table[(table.variant == "localize") & (table.placement == "random")]
    assert loc.one_frame.tolist() == [1.0, 1.0, 1.0, 0.0]
    assert loc.rmse_over_crlb_received.tolist() == pytest.approx([2.0, 4.0, 3.0, 5.0])
    central = table[table.variant == "central"]
    assert central.rmse_over_crlb.tolist() == pytest.approx([0.1] * 5)
    assert central.one_frame.isna().all() and central.done_over_hop_limit.isna().all()


def test_comparison_varies_one_factor_around_the_base(results):
    means = comparison(joined(*results))
    loss = means[(means.factor == "medium.loss_prob") & (means.variant == "localize")]
    assert loss.level.tolist() == [0.0, 0.2]
    assert loss.rmse_over_crlb.tolist() == pytest.approx([0.3, 0.3])  # seeds 1 and 2: 0.2, 0.4
    density = means[(means.factor == "placement.density_per_m2") & (means.variant == "gcs")]
    assert density.level.tolist() == [300, 400]
    assert density.mean_neighbours.tolist() == [5.0, 7.0]
    assert not (means.level == 1000).any()  # the lattice case is left out
    table = summary_table(means, "one_frame")
    row = table[(table.factor == "density (robots per m²)") & (table.level == 300)]
    assert row[["gcs", "localize", "central"]].values.tolist() == [["0.00", "0.00", "–"]]


def test_base_and_lattice_tables(results):
    table = joined(*results)
    base = base_table(table).set_index("variant")
    assert base.loc["localize", "runs"] == 2
    assert base.loc["localize", "RMSE / CRLB (one reading per pair)"] == "0.30"
    lossy = base_table(table, **{"medium.loss_prob": 0.2}).set_index("variant")
    assert lossy.loc["localize", "runs"] == 1
    lattice = lattice_table(table).set_index("variant")
    assert lattice.loc["localize", "robots"] == 1000
    assert lattice.loc["localize", "RMSE mm"] == "0.100"
    assert lattice.loc["central", "one frame"] == "–"


def test_targets_table_judges_both_bounds(results):
    _, localize = results
    rows = targets_table(localize).set_index("case")
    # Cases whose runs average fewer than 6 neighbours are left out.
    assert list(rows.index) == ["base", "loss 0.2"]
    base = rows.loc["base"]
    assert base["runs"] == 2
    assert base["RMSE / CRLB received (max)"] == "4.00"
    assert base["targets met"] == "2 of 2"
    assert base["met, received bound"] == "0 of 2"


def test_shapes_off_the_design_get_a_table_of_their_own(results):
    gcs, localize = results
    corridor = {"placement.kind": "corridor", "placement.length_mm": 3400.0}
    corridor["placement.width_mm"], corridor["placement.density_per_m2"] = 200.0, None
    shapes = pd.DataFrame(
        [
            _run(1, 1, 0.5, **{**corridor, "placement.robots": 400}),
            _run(2, 2, 0.7, **{**corridor, "placement.robots": 400}),
            # two factors changed at once: the sparse swarm, off the one-at-a-time design
            _run(1, 1, 0.4, **{"placement.density_per_m2": 350, "placement.robots": 400}),
        ]
    )
    table = joined(gcs, pd.concat([localize, shapes], ignore_index=True))
    rows = shapes_table(table)
    localize_rows = rows[rows.variant == "localize"].set_index("shape")
    assert list(localize_rows.index) == [
        "corridor 400, 3.4 m × 200 mm",
        "random 400, 350 per m²",
    ]
    corridor_row = localize_rows.loc["corridor 400, 3.4 m × 200 mm"]
    assert corridor_row["runs"] == 2
    assert corridor_row["one frame"] == "0.50"
    assert corridor_row["largest frame / central (min)"] == "0.500"
    assert corridor_row["at optimum / central (min)"] == "0.480"
    assert corridor_row["RMSE / CRLB"] == "0.60"
    assert set(rows.variant) == {"localize", "central"}  # gcs did not run the shapes
    # The one-at-a-time tables do not see them.
    means = comparison(table)
    assert not (means.level == 350).any()
    assert not ((means.factor == "placement.robots") & (means.level == 400)).any()
    assert base_table(table).set_index("variant").loc["localize", "runs"] == 2


#: The study's corridor: a placement off the one-at-a-time design.
SHAPE = {
    "placement.kind": "corridor",
    "placement.length_mm": 3400.0,
    "placement.width_mm": 200.0,
    "placement.density_per_m2": None,
    "placement.robots": 400,
}


def test_shape_runs_table_lists_each_shape_run_with_its_optimum_share():
    folded = {**_run(1, 1, 2.0, **SHAPE), "at_optimum_over_central": 0.5, "done_s": 61.0}
    # The base case (the last row) lies on the design: not listed.
    localize = pd.DataFrame([folded, _run(2, 1, 3.0, **SHAPE), _run(1, 1, 2.0)])
    table = joined(pd.DataFrame([_run(1, 1, 2.0, **{"gcs.refine": False})]), localize)
    rows = shape_runs_table(table, localize)
    assert rows["seed"].tolist() == [1, 2]
    assert rows["at optimum / central"].tolist() == ["0.500", "0.960"]
    assert rows["done s"].tolist() == ["61", "–"]
    assert set(rows["shape"]) == {"corridor 400, 3.4 m × 200 mm"}
