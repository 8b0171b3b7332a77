"""Sweep reports: figures aggregated over seeds, as DataFrames, matplotlib Figures and files.

From a notebook::

    from kilonet.experiments import report
    sweep, results = report.load("runs/loss")          # one row per stored run
    table = report.aggregate(results, sweep.swept, ["last_change_s"])
    fig = report.plot(table, "medium.loss_prob", "last_change_s")

From the shell: ``kilonet report runs/loss --out loss.html`` (one self-contained file with the
figures embedded as PNG) or ``--out loss.md`` (figures as PNG files in ``loss_files/``).

Aggregation is over the seeds of each cell, successful runs only: the mean, the sample standard
deviation and a Student-t confidence interval of the mean (default 95 %), cut to the values a
run can have: [0, 1] for a fraction, 0 and up for a time.
"""

from __future__ import annotations

import base64
import html
import io
import math
import os
import re
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import NullLocator
from scipy import stats

from kilonet.experiments.store import META_COLUMNS, ResultStore, write_atomically
from kilonet.experiments.sweep import Sweep

__all__ = [
    "ReportError",
    "aggregate",
    "failures",
    "is_fraction",
    "is_time",
    "load",
    "metrics_of",
    "plot",
    "write_report",
]


class ReportError(ValueError):
    """A report cannot be made as asked (output type, axis, metric); the message says why."""


#: Summary figures that describe a run rather than measure anything.
_NOT_METRICS = frozenset({"scenario", "sim_time_s"})


def load(directory: str | Path) -> tuple[Sweep, pd.DataFrame]:
    """The sweep stored in ``directory`` and its results, one row per stored run (see
    :meth:`kilonet.experiments.store.ResultStore.frame` for the columns).

    Raises
    ------
    kilonet.experiments.store.StoreError
        If ``directory`` holds no sweep results.
    """
    with ResultStore.open(directory, read_only=True) as store:
        return store.sweep(), store.frame()


def metrics_of(results: pd.DataFrame, sweep: Sweep) -> list[str]:
    """The summary figures worth reporting: the sweep's ``[report] metrics`` if it names any,
    else every numeric figure that is not constant over the successful runs.

    Raises
    ------
    ReportError
        If the sweep names a metric that no stored run reports.
    """
    ok = results[results["status"] == "ok"]
    if sweep.report.metrics:
        missing = [m for m in sweep.report.metrics if m not in results.columns]
        if missing and len(ok):
            raise ReportError(
                f"[report] metrics: no run reports {missing[0]!r}; reported: "
                f"{', '.join(_figure_columns(results, sweep))}"
            )
        return [m for m in sweep.report.metrics if m in results.columns]
    out = []
    for column in _figure_columns(results, sweep):
        values = pd.to_numeric(ok[column], errors="coerce").dropna()
        if column not in _NOT_METRICS and len(values) and values.nunique() > 1:
            out.append(column)
    return out


def _is_numeric(column: pd.Series) -> bool:
    """Whether every value of ``column`` present is a number."""
    values = column.dropna()
    return bool(len(values)) and pd.to_numeric(values, errors="coerce").notna().all()


def _figure_columns(results: pd.DataFrame, sweep: Sweep) -> list[str]:
    taken = {*sweep.swept, *META_COLUMNS}
    return [c for c in results.columns if c not in taken]


def aggregate(
    results: pd.DataFrame,
    by: Sequence[str],
    metrics: Sequence[str],
    *,
    confidence: float = 0.95,
) -> pd.DataFrame:
    """Mean, standard deviation and confidence interval of each metric over the seeds of each
    cell (successful runs only).

    Parameters
    ----------
    results : DataFrame
        One row per run with a ``status`` column, the ``by`` columns and the metrics.
    by : sequence of str
        The columns that define a cell (the swept parameters).
    metrics : sequence of str
        The figures to aggregate; values that are not numbers count as missing.
    confidence : float
        Level of the Student-t interval of the mean, in (0, 1).

    Returns
    -------
    DataFrame
        One row per cell and metric: the ``by`` columns, ``metric``, ``runs`` (values that
        entered), ``mean``, ``std``, ``ci_low``, ``ci_high`` (NaN for a single run; for a
        fraction, :func:`is_fraction`, cut to [0, 1]; for a time, :func:`is_time`, cut at 0).

    Examples
    --------
    >>> runs = pd.DataFrame({"p": [0.1, 0.1, 0.2, 0.2], "status": ["ok"] * 4,
    ...                      "y": [1.0, 3.0, 5.0, 5.0]})
    >>> aggregate(runs, ["p"], ["y"]).round(3).to_dict("records")[0]
    {'p': 0.1, 'metric': 'y', 'runs': 2, 'mean': 2.0, 'std': 1.414, 'ci_low': -10.706, 'ci_high': 14.706}
    """  # noqa: E501
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), not {confidence}")
    ok = results[results["status"] == "ok"]
    columns = [*by, "metric", "runs", "mean", "std", "ci_low", "ci_high"]
    rows: list[dict[str, Any]] = []
    groups = ok.groupby(list(by), sort=True, dropna=False) if by else [((), ok)]
    for key, group in groups:
        key = key if isinstance(key, tuple) else (key,)
        for metric in metrics:
            values = pd.to_numeric(group[metric], errors="coerce").dropna().to_numpy(float)
            row = _stats(values, confidence)
            if is_fraction(metric):
                row["ci_low"], row["ci_high"] = _clipped(row["ci_low"], row["ci_high"], 0.0, 1.0)
            elif is_time(metric):
                row["ci_low"], row["ci_high"] = _clipped(row["ci_low"], row["ci_high"], 0.0)
            rows.append(dict(zip(by, key, strict=True)) | {"metric": metric, **row})
    return pd.DataFrame(rows, columns=columns)


def is_fraction(metric: str) -> bool:
    """Whether ``metric`` is a share in [0, 1] by its name (``..._fraction``, ``..._share``,
    ``one_frame``-style 0/1 outcomes are not named so and are left alone).

    >>> is_fraction("gradient_correct_fraction"), is_fraction("rmse_mm")
    (True, False)
    """
    return metric.endswith(("fraction", "_share"))


def is_time(metric: str) -> bool:
    """Whether ``metric`` is a time in seconds by its name (``done_s``, ``last_change_s``):
    never negative. A rate (``..._deg_s``, ``..._mm_s``, ``..._per_s``) is not one.

    >>> is_time("done_s"), is_time("follower_turn_deg_s"), is_time("rmse_mm")
    (True, False, False)
    """
    return metric.endswith("_s") and not metric.endswith(("_deg_s", "_mm_s", "_per_s"))


def _clipped(
    low: float, high: float, lowest: float, highest: float = math.inf
) -> tuple[float, float]:
    """An interval cut to the values a run can have, ``[lowest, highest]``. The Student-t
    interval is symmetric about the mean, so for a few seeds' values near a bound (a fraction
    near 0 or 1, a time near 0 with a long tail) it reaches past the bound, where no run can
    be; the cut band says what the runs allow and is no longer symmetric."""
    if math.isnan(low):
        return low, high
    return max(low, lowest), min(high, highest)


def _stats(values: np.ndarray, confidence: float) -> dict[str, float]:
    n = len(values)
    mean = float(values.mean()) if n else math.nan
    # equal values give exactly 0, not the rounding residue of the mean
    std = (0.0 if np.ptp(values) == 0 else float(values.std(ddof=1))) if n > 1 else math.nan
    half = (
        float(stats.t.ppf((1 + confidence) / 2, n - 1)) * std / math.sqrt(n) if n > 1 else math.nan
    )
    return {"runs": n, "mean": mean, "std": std, "ci_low": mean - half, "ci_high": mean + half}


def failures(results: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """Failed runs per cell and error message: the ``by`` columns, ``error``, ``runs`` and the
    ``seeds`` that failed."""
    failed = results[results["status"] == "failed"]
    columns = [*by, "error", "runs", "seeds"]
    if failed.empty:
        return pd.DataFrame(columns=columns)
    table = (
        failed.groupby([*by, "error"], sort=True, dropna=False)["seed"]
        .agg(runs="count", seeds=lambda s: ", ".join(map(str, sorted(s))))
        .reset_index()
    )
    return table[columns]


def plot(
    aggregated: pd.DataFrame,
    x: str,
    metric: str,
    *,
    xscale: str = "linear",
    confidence: float | None = 0.95,
) -> Figure:
    """Mean of ``metric`` against ``x`` with the confidence band, one line per combination of
    the other swept parameters in ``aggregated`` (the output of :func:`aggregate`).

    Raises
    ------
    KeyError
        If ``aggregated`` has no column ``x`` or no rows for ``metric``.
    """
    rows = aggregated[aggregated["metric"] == metric]
    if x not in aggregated.columns:
        raise KeyError(f"no column {x!r} to plot against; columns: {list(aggregated.columns)}")
    if rows.empty:
        raise KeyError(f"no aggregated rows for metric {metric!r}")
    others = [c for c in aggregated.columns[: list(aggregated.columns).index("metric")] if c != x]
    numeric_x = pd.api.types.is_numeric_dtype(rows[x])
    categories = list(dict.fromkeys(rows[x])) if not numeric_x else []
    fig = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = fig.add_subplot()
    groups = rows.groupby(others, sort=True, dropna=False) if others else [((), rows)]
    for key, line in groups:
        key = key if isinstance(key, tuple) else (key,)
        line = line.sort_values(x) if numeric_x else line
        xs = line[x].to_numpy(float) if numeric_x else [categories.index(v) for v in line[x]]
        label = ", ".join(f"{k} = {_short(v)}" for k, v in zip(others, key, strict=True))
        (drawn,) = ax.plot(xs, line["mean"], marker="o", label=label or None)
        if line["ci_low"].notna().any():
            ax.fill_between(xs, line["ci_low"], line["ci_high"], color=drawn.get_color(), alpha=0.2)
    if not numeric_x:
        ax.set_xticks(range(len(categories)), [str(c) for c in categories])
    ax.set_xscale(xscale)
    if xscale == "log" and numeric_x:  # label the swept values, not powers of ten
        ticks = sorted(set(rows[x]))
        ax.set_xticks(ticks, [_short(v) for v in ticks])
        ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xlabel(x)
    ax.set_ylabel(metric)
    band = f" (band: {confidence:.0%} CI of the mean)" if confidence is not None else ""
    ax.set_title(f"{metric}{band}", fontsize=10)
    ax.grid(True, alpha=0.3)
    if others:
        ax.legend(fontsize=8)
    return fig


def _short(value: Any) -> str:
    return _number(value) if isinstance(value, float) else str(value)


# ------------------------------------------------------------------------------ report files


def write_report(
    directory: str | Path,
    out: str | Path,
    *,
    x: str | None = None,
    metrics: Sequence[str] | None = None,
    confidence: float = 0.95,
    stamp: str | None = None,
) -> list[Path]:
    """Write the report of the sweep in ``directory`` to ``out`` (``.html``: one self-contained
    file; ``.md``: Markdown with the figures in ``<stem>_files/``). Returns the paths written.

    ``stamp`` is the report's last line (default: the command that makes it from the results;
    :func:`kilonet.experiments.publish.stamp` adds date, machine and versions).

    Raises
    ------
    kilonet.experiments.store.StoreError
        If ``directory`` holds no sweep results.
    ReportError
        If ``out`` is neither ``.html`` nor ``.md``, ``x`` is not a swept parameter, or a metric
        is not reported by any run.
    """
    out = Path(out)
    kind = out.suffix.lower()
    if kind not in (".html", ".md"):
        raise ReportError(f"--out {out}: a report is .html or .md")
    sweep, results = load(directory)
    x = x or sweep.report.x or (sweep.swept[0] if sweep.swept else None)
    if x is not None and x not in sweep.swept:
        raise ReportError(
            f"x = {x!r} is not a swept parameter; swept: {', '.join(sweep.swept) or 'none'}"
        )
    if metrics:
        unknown = [m for m in metrics if m not in results.columns]
        if unknown:
            raise ReportError(f"metric {unknown[0]!r} is not reported by any stored run")
        for metric in metrics:
            values = results.loc[results["status"] == "ok", metric].dropna()
            text = values[pd.to_numeric(values, errors="coerce").isna()]
            if len(text):
                numeric = [c for c in _figure_columns(results, sweep) if _is_numeric(results[c])]
                raise ReportError(
                    f"--metric {metric!r} is not a numeric result (a run reports "
                    f"{text.iloc[0]!r}); numeric results: {', '.join(numeric) or 'none'}"
                )
        chosen = list(metrics)
    else:
        chosen = metrics_of(results, sweep)
    table = aggregate(results, sweep.swept, chosen, confidence=confidence)
    sections = []
    for metric in chosen:
        wide = table[table["metric"] == metric].drop(columns="metric")
        png = None
        if x is not None and wide["mean"].notna().any():  # a figure needs an axis and a value
            fig = plot(table, x, metric, xscale=sweep.report.xscale, confidence=confidence)
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=100)
            png = buffer.getvalue()
        sections.append((metric, png, wide))
    stamp = stamp or f"Generated by `kilonet report {directory}`."
    page = _Page(sweep, results, sections, failures(results, sweep.swept), confidence, stamp)
    out.parent.mkdir(parents=True, exist_ok=True)
    if kind == ".html":
        write_atomically(out, page.html())
        return [out]
    return _write_markdown(out, page)


class _Page:
    """The content of a report, rendered as HTML or Markdown."""

    def __init__(
        self,
        sweep: Sweep,
        results: pd.DataFrame,
        sections: list[tuple[str, bytes | None, pd.DataFrame]],
        failed: pd.DataFrame,
        confidence: float,
        stamp: str,
    ) -> None:
        self.sweep = sweep
        self.results = results
        self.sections = sections
        self.failed = failed
        self.confidence = confidence
        self.stamp = stamp

    def facts(self) -> list[tuple[str, str]]:
        s = self.sweep
        total = len(s.runs())
        counts = self.results["status"].value_counts()
        ok, failed = int(counts.get("ok", 0)), int(counts.get("failed", 0))
        missing = total - ok - failed
        seeds = f"{len(s.seeds)} ({_seed_text(s.seeds)})"
        facts = [("scenario", s.scenario), ("seeds per cell", seeds)]
        facts += [(f"fixed {k}", _short(v)) for k, v in s.fixed.items()]
        facts += [(f"swept {k}", ", ".join(_short(v) for v in s.grid[k])) for k in s.grid]
        for i, case in enumerate(s.cases):
            facts.append(
                (f"case {i + 1}", ", ".join(f"{k} = {_short(v)}" for k, v in case.items()))
            )
        runs = f"{total} in {len(s.cells())} cells: {ok} ok, {failed} failed"
        facts.append(("runs", runs + (f", {missing} not run yet" if missing else "")))
        facts.append(
            (
                "aggregation",
                f"over seeds; band and CI: {self.confidence:.0%} Student t, cut to [0, 1] "
                "for fractions and at 0 for times",
            )
        )
        return facts

    def html(self) -> str:
        s = self.sweep
        parts = [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            f"<title>kilonet sweep {html.escape(s.name)}</title>",
            f"<style>{_CSS}</style></head><body>",
            f"<h1>Sweep {html.escape(s.name)}</h1>",
        ]
        if s.description:
            parts.append(f"<p>{html.escape(s.description)}</p>")
        parts.append("<table class='facts'>")
        parts += [
            f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in self.facts()
        ]
        parts.append("</table>")
        for metric, png, table in self.sections:
            parts.append(f"<h2>{html.escape(metric)}</h2>")
            if png is not None:
                encoded = base64.b64encode(png).decode("ascii")
                parts.append(
                    f'<img alt="{html.escape(metric)}" src="data:image/png;base64,{encoded}">'
                )
            parts.append(_html_table(table))
        if not self.failed.empty:
            parts += ["<h2>Failed runs</h2>", _html_table(self.failed)]
        parts.append(f"<p class='foot'>{html.escape(self.stamp)}</p>")
        parts.append("</body></html>")
        return "\n".join(parts) + "\n"

    def markdown(self, figure_paths: dict[str, str]) -> str:
        s = self.sweep
        lines = [f"# Sweep {s.name}", ""]
        if s.description:
            lines += [s.description, ""]
        lines += [*_markdown_table(pd.DataFrame(self.facts(), columns=["", "value"])), ""]
        for metric, _png, table in self.sections:
            lines += [f"## {metric}", ""]
            if metric in figure_paths:
                lines += [f"![{metric}]({figure_paths[metric]})", ""]
            lines += [*_markdown_table(table), ""]
        if not self.failed.empty:
            lines += ["## Failed runs", "", *_markdown_table(self.failed), ""]
        lines += [self.stamp, ""]
        return "\n".join(lines)


_CSS = (
    "body{font-family:sans-serif;max-width:60rem;margin:2rem auto;padding:0 1rem;color:#222}"
    "table{border-collapse:collapse;margin:0.5rem 0 1.5rem}"
    "th,td{border:1px solid #ccc;padding:0.2rem 0.5rem;text-align:right}"
    "table.facts th,table.facts td{text-align:left}"
    "img{max-width:100%}.foot{color:#777;font-size:0.8rem}"
)


def _html_table(frame: pd.DataFrame) -> str:
    return frame.to_html(index=False, border=0, na_rep="–", float_format=_number)


def _markdown_table(frame: pd.DataFrame) -> list[str]:
    """``frame`` as a GitHub Markdown table.

    >>> _markdown_table(pd.DataFrame({"p": [0.5], "mean": [1 / 3]}))
    ['| p | mean |', '| --- | --- |', '| 0.5 | 0.3333 |']
    """

    def cell(value: Any) -> str:
        if isinstance(value, float | np.floating):
            return "–" if math.isnan(value) else _number(float(value))
        return str(value).replace("|", "\\|")

    header = "| " + " | ".join(map(str, frame.columns)) + " |"
    rule = "| " + " | ".join("---" for _ in frame.columns) + " |"
    body = ["| " + " | ".join(cell(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return [header, rule, *body]


def _number(value: float) -> str:
    """A table's number: four significant digits, whole numbers from 10,000 up with thousands
    separators instead of an exponent, an exponent only below 0.001.

    >>> [_number(v) for v in (76510.4, 9999.7, 123.456, 0.5, 0.0, 0.000012, -25000.0)]
    ['76,510', '10,000', '123.5', '0.5', '0', '1.2e-05', '-25,000']
    """
    if not math.isfinite(value):
        return "–" if math.isnan(value) else str(value)
    if abs(value) >= 9999.5:
        return f"{value:,.0f}"
    if value == 0 or abs(value) >= 1e-3:
        return f"{value:.4g}"
    return f"{value:.2g}"


def _seed_text(seeds: Sequence[int]) -> str:
    if list(seeds) == list(range(seeds[0], seeds[0] + len(seeds))) and len(seeds) > 2:
        return f"{seeds[0]}–{seeds[-1]}"
    return ", ".join(map(str, seeds))


def _write_markdown(out: Path, page: _Page) -> list[Path]:
    """The Markdown file and its figures, each moved into place only when complete."""
    figures_dir = out.with_name(f"{out.stem}_files")
    tmp_dir = out.with_name(f".{figures_dir.name}.{os.getpid()}.tmp")
    shutil.rmtree(tmp_dir, ignore_errors=True)
    tmp_dir.mkdir()
    try:
        paths: dict[str, str] = {}
        written = []
        for metric, png, _table in page.sections:
            if png is None:
                continue
            name = re.sub(r"[^\w.-]", "_", metric) + ".png"
            (tmp_dir / name).write_bytes(png)
            paths[metric] = f"{figures_dir.name}/{name}"
            written.append(figures_dir / name)
        if figures_dir.exists():
            shutil.rmtree(figures_dir)
        tmp_dir.replace(figures_dir)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    write_atomically(out, page.markdown(paths))
    return [out, *written]
