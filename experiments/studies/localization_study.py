"""Localization compared: the thesis pipeline, with and without its refinement, ``localize``,
and the centralized solver (issue 20).

Reads finished runs of the two sweeps ``experiments/localization_gcs.toml`` (scenario ``gcs``,
``gcs.refine`` false and true) and ``experiments/localization_localize.toml`` (scenario
``localize``), which share their cases and seeds, and writes a Markdown report with a table of
the 1,000-robot lattice case (:func:`lattice_table`) and, for the random placements, one table
and one figure per figure of merit, each against the four factors varied one at a time around
the base case (density, ranging noise, loss, size):

* P(one frame): the share of runs that end with one frame;
* covered fraction: the share of robots in the largest frame (for the centralized solver, the
  share it places right among its neighbours, ``central_localized_fraction``);
* RMSE / CRLB: ``rmse_over_crlb`` (the bound of one reading per pair, the issue's), and the same
  over the bound of the receptions the robots averaged (``rmse_over_crlb_received``);
* time over the hop limit: ``done_over_hop_limit``, simulated time to done over
  ``hop_diameter × robot.tx_period_s``.

The centralized solver's figures come from the ``localize`` runs (it solves from the distances
each run's robots measured). ``python -m kilonet.experiments.publish localization`` runs both sweeps
and writes the report; or, with finished sweep directories::

    python -m kilonet.experiments.studies.localization_study GCS_DIR LOCALIZE_DIR \
        [--out experiments/reports]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from kilonet.experiments.report import _markdown_table, load

__all__ = [
    "FACTORS",
    "VARIANTS",
    "base_table",
    "comparison",
    "joined",
    "lattice_table",
    "off_design",
    "shape_runs_table",
    "shapes_table",
    "summary_table",
    "targets_table",
    "write_report",
]

#: The factors varied one at a time, with how the report names them.
FACTORS = {
    "placement.density_per_m2": "density (robots per m²)",
    "ranging.intensity_noise": "ranging intensity noise (relative sd)",
    "medium.loss_prob": "loss",
    "placement.robots": "robots",
}
#: The variants compared, in the report's order.
VARIANTS = ("gcs", "gcs + refine", "localize", "central")
#: The figures of merit: column of :func:`joined`'s table -> how the report names it.
MEASURES = {
    "one_frame": "P(one frame)",
    "covered": "covered fraction",
    "rmse_over_crlb": "RMSE / CRLB (one reading per pair)",
    "rmse_over_crlb_received": "RMSE / CRLB of the receptions averaged",
    "done_over_hop_limit": "simulated time to done / (hop diameter × transmit period)",
}
_NUMERIC = (
    "frames",
    "localized_fraction",
    "largest_frame_fraction",
    "rmse_mm",
    "crlb_rmse_mm",
    "crlb_received_rmse_mm",
    "central_rmse_mm",
    "central_localized_fraction",
    "done_over_hop_limit",
    "mean_neighbours",
    "largest_frame_over_central",
    "at_optimum_over_central",
    "done_s",
)


def _ok(results: pd.DataFrame) -> pd.DataFrame:
    runs = results[results.status == "ok"].copy()
    kind = runs["placement.kind"] if "placement.kind" in runs else pd.Series(index=runs.index)
    runs["placement"] = kind.fillna("random")
    for column in _NUMERIC:
        # Results from before a key existed lack it: NaN.
        runs[column] = pd.to_numeric(runs.get(column), errors="coerce")
    runs["shape"] = [_shape(run) for _, run in runs.iterrows()]
    return runs


def _shape(run: pd.Series) -> str:
    """How the shapes table names a run's placement: its kind, size and dimensions."""

    def value(key: str) -> float:
        return float(run[key]) if key in run and pd.notna(run[key]) else math.nan

    robots, kind = int(value("placement.robots")), run["placement"]
    if kind == "corridor":
        size = f"{value('placement.length_mm') / 1000:g} m × {value('placement.width_mm'):g} mm"
    elif kind in ("c_shape", "ring"):
        inner, outer = value("placement.inner_radius_mm"), value("placement.outer_radius_mm")
        size = f"radii {inner:g}–{outer:g} mm"
        if kind == "c_shape":
            size += f", open {value('placement.opening_deg'):g}°"
    elif kind == "random":
        size = f"{value('placement.density_per_m2'):g} per m²"
    else:
        size = kind
    return f"{kind} {robots}, {size}"


def joined(gcs: pd.DataFrame, localize: pd.DataFrame) -> pd.DataFrame:
    """One row per run and variant: the factors, ``placement`` (``random`` or ``hex``), ``seed``,
    ``variant``, ``mean_neighbours``, the figures of merit of :data:`MEASURES` and ``localized``,
    ``rmse_mm``, ``crlb_rmse_mm``, ``crlb_received_rmse_mm``, ``shape`` (:func:`shapes_table`'s
    name of the placement), ``over_central`` and ``at_optimum_over_central`` (the summary's
    ``largest_frame_over_central`` and ``at_optimum_over_central``) (NaN where a
    variant has none: the centralized solver builds no frame of its own and takes no time)."""
    factors = [*FACTORS, "placement", "shape"]
    parts = []
    gcs = _ok(gcs)
    refine = gcs["gcs.refine"].astype(str).str.lower() == "true"
    for variant, runs in (("gcs", gcs[~refine]), ("gcs + refine", gcs[refine])):
        parts.append(_measures(runs, variant))
    localize = _ok(localize)
    parts.append(_measures(localize, "localize"))
    central = localize[[*factors, "seed", "mean_neighbours"]].copy()
    central["variant"] = "central"
    central["one_frame"] = central["over_central"] = central["at_optimum_over_central"] = np.nan
    central["covered"] = central["localized"] = localize["central_localized_fraction"]
    central["rmse_mm"] = localize["central_rmse_mm"]
    for bound in ("crlb_rmse_mm", "crlb_received_rmse_mm"):
        central[bound] = localize[bound]
    central["rmse_over_crlb"] = localize["central_rmse_mm"] / localize["crlb_rmse_mm"]
    central["rmse_over_crlb_received"] = (
        localize["central_rmse_mm"] / localize["crlb_received_rmse_mm"]
    )
    central["done_over_hop_limit"] = np.nan
    parts.append(central)
    return pd.concat(parts, ignore_index=True)


def _measures(runs: pd.DataFrame, variant: str) -> pd.DataFrame:
    out = runs[[*FACTORS, "placement", "shape", "seed", "mean_neighbours"]].copy()
    out["variant"] = variant
    out["over_central"] = runs["largest_frame_over_central"]
    out["at_optimum_over_central"] = runs["at_optimum_over_central"]
    out["one_frame"] = (runs["frames"] == 1).astype(float)
    out["covered"] = runs["largest_frame_fraction"]
    out["localized"] = runs["localized_fraction"]
    for column in ("rmse_mm", "crlb_rmse_mm", "crlb_received_rmse_mm"):
        out[column] = runs[column]
    out["rmse_over_crlb"] = runs["rmse_mm"] / runs["crlb_rmse_mm"]
    out["rmse_over_crlb_received"] = runs["rmse_mm"] / runs["crlb_received_rmse_mm"]
    out["done_over_hop_limit"] = runs["done_over_hop_limit"]
    return out


def _base(table: pd.DataFrame) -> dict[str, float]:
    """The base case: each factor's most common value (every one-at-a-time case but its own
    keeps the others at the base)."""
    return {f: table[f].mode().iloc[0] for f in FACTORS}


def comparison(table: pd.DataFrame) -> pd.DataFrame:
    """Means over seeds of every figure of merit, by factor, level and variant: columns
    ``factor, level, variant, mean_neighbours, runs`` and one per measure. The base case
    appears once under every factor."""
    table = table[table.placement == "random"]
    base = _base(table)
    rows = []
    for factor in FACTORS:
        others = [f for f in FACTORS if f != factor]
        keep = np.logical_and.reduce([table[f] == base[f] for f in others])
        for (level, variant), group in table[keep].groupby([factor, "variant"]):
            row = {"factor": factor, "level": level, "variant": variant, "runs": len(group)}
            row["mean_neighbours"] = group["mean_neighbours"].mean()
            for measure in MEASURES:
                row[measure] = group[measure].mean()
            rows.append(row)
    return pd.DataFrame(rows)


def base_table(table: pd.DataFrame, **case: float) -> pd.DataFrame:
    """:func:`joined`'s runs of the base case, with the factors in ``case`` (dotted names as
    keywords cannot be: pass them as ``**{"medium.loss_prob": 0.2}``) changed: a row per
    variant with the number of runs and the mean over seeds of each measure."""
    random = table[table.placement == "random"]
    chosen = {**_base(random), **case}
    keep = np.logical_and.reduce([random[f] == v for f, v in chosen.items()])
    rows = []
    for variant in VARIANTS:
        runs = random[keep & (random.variant == variant)]
        if not len(runs):
            continue
        row = {"variant": variant, "runs": len(runs)}
        for measure, title in MEASURES.items():
            row[title] = _cell(runs[measure].mean(), 1 if measure == "done_over_hop_limit" else 2)
        rows.append(row)
    return pd.DataFrame(rows)


def lattice_table(table: pd.DataFrame) -> pd.DataFrame:
    """The lattice case (``placement.kind = hex``): per variant, the runs and the means over
    seeds of frames-related shares, RMSE, both bounds and the ratios, and time to done."""
    rows = []
    lattice = table[table.placement == "hex"]
    for variant in VARIANTS:
        runs = lattice[lattice.variant == variant]
        if not len(runs):
            continue
        rows.append(
            {
                "variant": variant,
                "robots": int(runs["placement.robots"].iloc[0]),
                "runs": len(runs),
                "one frame": _cell(runs.one_frame.mean()),
                "localized": _cell(runs.localized.mean(), 3),
                "largest frame": _cell(runs.covered.mean(), 3),
                "RMSE mm": _cell(runs.rmse_mm.mean(), 3),
                "CRLB mm": _cell(runs.crlb_rmse_mm.mean(), 3),
                "RMSE / CRLB": _cell(runs.rmse_over_crlb.mean()),
                "CRLB received mm": _cell(runs.crlb_received_rmse_mm.mean(), 3),
                "RMSE / CRLB received": _cell(runs.rmse_over_crlb_received.mean()),
                "done / hop limit": _cell(runs.done_over_hop_limit.mean(), 1),
            }
        )
    return pd.DataFrame(rows)


def off_design(table: pd.DataFrame) -> pd.Series:
    """Which rows of :func:`joined`'s table lie off the one-at-a-time design around the
    random base case: other placements than ``random`` and ``hex``, and random cases with more
    than one factor changed (the sparse swarm: fewer robots per m², more robots)."""
    random = table.placement == "random"
    base = _base(table[random])
    changed = sum((table[f] != base[f]).astype(int) for f in FACTORS)
    return (~random & (table.placement != "hex")) | (random & (changed > 1))


def shapes_table(table: pd.DataFrame) -> pd.DataFrame:
    """The shapes off the design (:func:`off_design`: corridors, C shapes, rings, sparse
    swarms), a row per shape, loss and variant: the runs, their mean neighbour count, P(one
    frame), the mean localized fraction, the largest frame and its robots at the optimum over
    the robots the centralized solver localizes (least over the seeds; a folded frame is large
    but not at the optimum), mean RMSE / CRLB and time to done."""
    shapes = table[off_design(table)]
    rows = []
    for (shape, loss), group in shapes.groupby(["shape", "medium.loss_prob"], sort=True):
        for variant in VARIANTS:
            runs = group[group.variant == variant]
            if not len(runs):
                continue
            rows.append(
                {
                    "shape": shape,
                    "loss": f"{loss:g}",
                    "variant": variant,
                    "runs": len(runs),
                    "mean neighbours": _cell(runs.mean_neighbours.mean(), 1),
                    "one frame": _cell(runs.one_frame.mean()),
                    "localized": _cell(runs.localized.mean(), 3),
                    "largest frame / central (min)": _cell(runs.over_central.min(), 3),
                    "at optimum / central (min)": _cell(runs.at_optimum_over_central.min(), 3),
                    "RMSE / CRLB": _cell(runs.rmse_over_crlb.mean()),
                    "done / hop limit": _cell(runs.done_over_hop_limit.mean(), 1),
                }
            )
    return pd.DataFrame(rows)


def shape_runs_table(joined_table: pd.DataFrame, localize: pd.DataFrame) -> pd.DataFrame:
    """``localize``'s runs on the shapes off the design (:func:`off_design`), a row each, by
    shape and seed: the localized fraction, the largest frame's robots at the optimum over the
    robots the centralized solver localizes (below 0.95: a folded or twisted frame), the RMSE
    beside the solver's, and when the run was done (s)."""
    runs = _ok(localize)
    shapes = set(joined_table.loc[off_design(joined_table), "shape"])
    runs = runs[runs["shape"].isin(shapes)].sort_values(["shape", "medium.loss_prob", "seed"])
    return pd.DataFrame(
        {
            "shape": runs["shape"],
            "loss": [f"{v:g}" for v in runs["medium.loss_prob"]],
            "seed": runs["seed"].astype(int),
            "localized": [_cell(v, 3) for v in runs.localized_fraction],
            "at optimum / central": [_cell(v, 3) for v in runs.at_optimum_over_central],
            "RMSE mm": [_cell(v, 1) for v in runs.rmse_mm],
            "central RMSE mm": [_cell(v, 1) for v in runs.central_rmse_mm],
            "done s": [_cell(v, 0) for v in runs.done_s],
        }
    ).reset_index(drop=True)


def targets_table(localize: pd.DataFrame, *, min_neighbours: float = 6.0) -> pd.DataFrame:
    """Issue 20's targets for ``localize`` on the random placements with at least
    ``min_neighbours`` mean neighbours, by case: the runs, their mean neighbour count, the worst
    run of each figure (the largest frame's robots, and those of them at the optimum, over the
    robots the centralized solver localizes; RMSE over either bound, time to done over the hop
    limit) and how many runs meet every target — the largest frame places ≥ 0.95 of the
    solver's robots at the optimum (a folded frame's robots do not count), RMSE ≤ 1.5 × the
    bound, done ≤ 20 × the hop limit —
    judged against the bound of one reading per pair (the issue's) and against the bound of
    the receptions averaged."""
    runs = _ok(localize)
    runs = runs[(runs.placement == "random") & (runs.mean_neighbours >= min_neighbours)].copy()
    for column in (
        "largest_frame_over_central",
        "at_optimum_over_central",
        "rmse_over_crlb",
        "rmse_over_crlb_received",
    ):
        runs[column] = pd.to_numeric(runs[column], errors="coerce")
    frame_ok = runs.at_optimum_over_central >= 0.95
    time_ok = runs.done_over_hop_limit <= 20
    runs["met"] = frame_ok & time_ok & (runs.rmse_over_crlb <= 1.5)
    runs["met_received"] = frame_ok & time_ok & (runs.rmse_over_crlb_received <= 1.5)
    base = _base(_ok(localize).query("placement == 'random'"))
    rows = []
    for values, group in runs.groupby(list(FACTORS)):
        case = dict(zip(FACTORS, values, strict=True))
        changed = [f for f in FACTORS if case[f] != base[f]]
        order = (list(FACTORS).index(changed[0]) + 1, case[changed[0]]) if changed else (0, 0)
        rows.append(
            {
                "order": order,
                "case": ", ".join(f"{FACTORS[f]} {case[f]:g}" for f in changed) or "base",
                "runs": len(group),
                "mean neighbours": _cell(group.mean_neighbours.mean(), 1),
                "largest frame / central (min)": _cell(group.largest_frame_over_central.min(), 3),
                "at optimum / central (min)": _cell(group.at_optimum_over_central.min(), 3),
                "RMSE / CRLB (max)": _cell(group.rmse_over_crlb.max()),
                "RMSE / CRLB received (max)": _cell(group.rmse_over_crlb_received.max()),
                "done / hop limit (max)": _cell(group.done_over_hop_limit.max(), 1),
                "targets met": f"{int(group.met.sum())} of {len(group)}",
                "met, received bound": f"{int(group.met_received.sum())} of {len(group)}",
            }
        )
    table = pd.DataFrame(rows)
    return table.sort_values("order").drop(columns="order").reset_index(drop=True)


def _cell(value: float, digits: int = 2) -> str:
    return "–" if pd.isna(value) else f"{value:.{digits}f}"


def summary_table(means: pd.DataFrame, measure: str, *, digits: int = 2) -> pd.DataFrame:
    """One measure as a table: a row per factor level (with the mean neighbour count), a
    column per variant; '–' where a variant has no value."""
    wide = means.pivot(index=["factor", "level"], columns="variant", values=measure)
    wide = wide.reindex(columns=[v for v in VARIANTS if v in wide.columns])
    neighbours = means.groupby(["factor", "level"])["mean_neighbours"].mean()
    out = wide.reset_index()
    out.insert(2, "mean neighbours", neighbours.reindex(wide.index).to_numpy().round(1))
    order = {f: k for k, f in enumerate(FACTORS)}
    out = out.sort_values(
        ["factor", "level"], key=lambda c: c.map(order) if c.name == "factor" else c
    )
    out["factor"] = [FACTORS[f] for f in out["factor"]]
    for variant in VARIANTS:
        if variant in out:
            out[variant] = [_cell(v, digits) for v in out[variant].to_numpy()]
    return out


def _figure(means: pd.DataFrame, measure: str, path: Path) -> None:
    fig, axes = plt.subplots(1, len(FACTORS), figsize=(14, 3.6), sharey=True)
    for ax, factor in zip(axes, FACTORS, strict=True):
        part = means[means.factor == factor]
        for variant in VARIANTS:
            line = part[part.variant == variant].sort_values("level")
            if line[measure].notna().any():
                x = line["mean_neighbours"] if factor == "placement.density_per_m2" else line.level
                ax.plot(x, line[measure], marker="o", label=variant)
        ax.set_xlabel(
            "mean neighbours" if factor == "placement.density_per_m2" else FACTORS[factor]
        )
        if factor == "placement.robots":
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(MEASURES[measure])
    if measure.startswith("rmse"):
        axes[0].set_yscale("log")
    axes[-1].legend(fontsize=8)
    fig.suptitle(MEASURES[measure])
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_report(
    gcs_dir: str | Path, localize_dir: str | Path, out_dir: str | Path, *, stamp: str | None = None
) -> Path:
    """Write ``localization.md`` and its figures (``localization_files/*.png``) under
    ``out_dir``; ``stamp`` is its last line (default: the command that makes it)."""
    _, gcs = load(gcs_dir)
    localize_sweep, localize = load(localize_dir)
    table = joined(gcs, localize)
    means = comparison(table)
    out = Path(out_dir)
    files = out / "localization_files"
    files.mkdir(parents=True, exist_ok=True)
    failed = int((gcs.status != "ok").sum() + (localize.status != "ok").sum())
    lines = [
        "# Localization compared: gcs, gcs with refinement, localize, the centralized solver",
        "",
        localize_sweep.description,
        "",
        f"{len(gcs) + len(localize)} runs ({len(gcs)} gcs, {len(localize)} localize), "
        f"{failed} failed. Every figure is the mean over the seeds of a case; the base case "
        "appears under every factor. `gcs` ends with many small frames on random placements: "
        "its RMSE is pooled over all of them, each aligned on its own, so it is small where the "
        "frames are; read it with the covered fraction.",
        "",
        "## The jittered hex lattice, σ = 1 mm",
        "",
        *_markdown_table(lattice_table(table)),
        "",
    ]
    shapes = shapes_table(table)
    if len(shapes):
        lines += [
            "## Shapes",
            "",
            "Placements off the one-at-a-time design: sparse random swarms, corridors, C shapes "
            "(`placement.kind`, docs/localize.md).",
            "",
            *_markdown_table(shapes),
            "",
        ]
    for measure, title in MEASURES.items():
        figure = f"localization_files/{measure}.png"
        _figure(means, measure, out / figure)
        digits = 1 if measure == "done_over_hop_limit" else 2
        lines += [
            f"## {title}",
            "",
            *_markdown_table(summary_table(means, measure, digits=digits)),
            "",
            f"![{title}]({figure})",
            "",
        ]
    lines += [
        stamp
        or "Generated by `python -m kilonet.experiments.studies.localization_study "
        f"{gcs_dir} {localize_dir}`.",
        "",
    ]
    path = out / "localization.md"
    path.write_text("\n".join(lines))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("gcs_dir", help="results of kilonet sweep localization_gcs.toml")
    parser.add_argument("localize_dir", help="results of kilonet sweep localization_localize.toml")
    parser.add_argument("--out", default="experiments/reports")
    args = parser.parse_args()
    print(write_report(args.gcs_dir, args.localize_dir, args.out))


if __name__ == "__main__":
    main()
