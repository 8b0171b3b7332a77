"""The measured figures of ``docs/results/gcs.md``, one function per generated block.

Each ``*_block`` function returns the Markdown of one ``<!-- publish:NAME -->`` block of the
page; :data:`kilonet.experiments.publish.BLOCKS` registers them, and ``python -m
kilonet.experiments.publish docs`` (or ``docs --block NAME``) writes them. Runs are the ``gcs``
scenario's jittered hex lattices with its defaults (σ = 1 mm, no loss) unless a row says otherwise;
a run that several blocks show is made once per process (:func:`gcs_run`). CPU seconds are process
time, less disturbed than wall time by other work on the machine but not free of it.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = [
    "LOSS",
    "PHASE_EVENTS",
    "THIN_DEG",
    "GcsRun",
    "error_by_distance_block",
    "gcs_run",
    "isolated_seeds_block",
    "last_events",
    "merging_choices_block",
    "robot_model_block",
    "runs_block",
    "windows_block",
]

#: The lossy channel of the page's tables: 20 % of receptions lost, with the longer phase-3
#: and phase-4 windows the loss tests use.
LOSS = {"medium.loss_prob": 0.2, "gcs.frames_s": 90, "gcs.localization_s": 40}
#: A seed's references at least this far apart, seen from the seed (∠BAC, degrees), make a
#: thin frame: nearly collinear with the seed.
THIN_DEG = 170.0
#: The events that mark progress in each fixed window (:func:`last_events`).
PHASE_EVENTS = {
    "ids": ("id", "duplicate"),
    "frames": ("frame", "frame_failed"),
    "localization": ("located",),
}
#: Distance bands from the root's seed for :func:`error_by_distance_block`, mm.
_BANDS_MM = ((0, 150), (150, 300), (300, 450), (450, 800))


@dataclass(frozen=True)
class GcsRun:
    """What the page's tables read from one ``gcs`` run.

    Attributes
    ----------
    summary : dict
        The run's ``summary.json``.
    cpu_s : float
        Process time the run took, s.
    reference_angles_deg : tuple of float
        ∠BAC of every seed that built a frame, degrees.
    isolated : int
        Seeds no merging group was registered with.
    isolated_alone : int
        Of those, seeds whose frame holds only the seed and its two references.
    isolated_alone_thin : int
        Of those, seeds whose references are at least :data:`THIN_DEG` apart.
    pairs_with_group : int
        Frame pairs (elected seeds) some robot found a merging group for.
    pairs_unregistered : int
        Of those, pairs at least one of whose two seeds received no registration for the other.
    error_bands : tuple of (int, int, int, float)
        ``(from_mm, to_mm, robots, rmse_mm)``: error after the best rigid alignment of the
        robots of the final frame that holds the most, by distance from its root's seed.
    """

    summary: dict[str, Any]
    cpu_s: float
    reference_angles_deg: tuple[float, ...]
    isolated: int
    isolated_alone: int
    isolated_alone_thin: int
    pairs_with_group: int
    pairs_unregistered: int
    error_bands: tuple[tuple[int, int, int, float], ...]

    @property
    def thin_frames(self) -> int:
        """Seeds whose references are at least :data:`THIN_DEG` apart."""
        return sum(a >= THIN_DEG for a in self.reference_angles_deg)


@functools.cache
def gcs_run(robots: int, seed: int, overrides: tuple[tuple[str, Any], ...] = ()) -> GcsRun:
    """One ``gcs`` run of ``robots`` robots (master seed ``seed``, parameter ``overrides`` as
    sorted key-value pairs), read once and kept for the process's other blocks."""
    from kilonet import scenarios

    cpu = time.process_time()
    result = scenarios.run(
        scenarios.get("gcs"), {"placement.robots": robots, **dict(overrides)}, seed=seed
    )
    cpu_s = time.process_time() - cpu
    return _read(result, cpu_s)


def _read(result: Any, cpu_s: float) -> GcsRun:
    from kilonet.scenarios.gcs import run_outcomes

    sim, summary = result.sim, result.summary
    outcomes = run_outcomes(sim)
    robots = outcomes.robots
    angles, isolated, alone, alone_thin = [], 0, 0, 0
    for i, o in enumerate(robots):
        if not o.is_seed:
            continue
        angle = _reference_angle_deg(sim.robots[i].references)
        if angle is not None:
            angles.append(angle)
        if o.isolated_seed:
            isolated += 1
            if sum(o.own_key in other.local_positions for other in robots) == 3:
                alone += 1
                alone_thin += angle is not None and angle >= THIN_DEG
    found = {
        frozenset(pair)
        for o in robots
        for pair in o.groups
        if all(key in outcomes.seed_robot for key in pair)
    }
    unregistered = sum(
        any(
            b not in sim.robots[outcomes.seed_robot[a]].partners
            for a, b in (tuple(pair), tuple(pair)[::-1])
        )
        for pair in found
    )
    return GcsRun(
        summary,
        cpu_s,
        tuple(angles),
        isolated,
        alone,
        alone_thin,
        len(found),
        unregistered,
        _error_bands(sim, outcomes),
    )


def _reference_angle_deg(references: Sequence[tuple[int, float, float]]) -> float | None:
    """∠BAC of a seed's references ``[(B, x, y), (C, x, y)]`` (B on +x), degrees.

    >>> round(_reference_angle_deg([(1, 40.0, 0.0), (2, -40.0, 4.0)]), 1)
    174.3
    >>> _reference_angle_deg([]) is None
    True
    """
    if len(references) != 2:
        return None
    (_, _, _), (_, x, y) = references
    return math.degrees(math.atan2(abs(y), x))


def _error_bands(sim: Any, outcomes: Any) -> tuple[tuple[int, int, int, float], ...]:
    import numpy as np

    from kilonet.protocols.common.alignment import procrustes_rmse

    localized = outcomes.estimates[outcomes.estimates.localized]
    if len(localized) < 3:
        return ()
    done = localized[localized.frame == localized.frame.mode().iloc[0]]  # the largest frame
    truth = sim.world.positions_mm[done.robot.to_numpy()]
    _, _, aligned = procrustes_rmse(done[["est_x_mm", "est_y_mm"]].to_numpy(), truth)
    root = outcomes.robots[int(done.robot.iloc[0])].root
    root_seed = outcomes.seed_robot.get(root.key) if root is not None else None
    if root_seed is None:
        return ()
    from_root = np.linalg.norm(truth - sim.world.positions_mm[root_seed], axis=1)
    error = np.linalg.norm(aligned - truth, axis=1)
    bands = []
    for lo, hi in _BANDS_MM:
        near = (from_root >= lo) & (from_root < hi)
        if near.any():
            bands.append((lo, hi, int(near.sum()), float(np.sqrt(np.mean(error[near] ** 2)))))
    return tuple(bands)


def _key(overrides: dict[str, Any]) -> tuple[tuple[str, Any], ...]:
    return tuple(sorted(overrides.items()))


def _table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """A Markdown table, the first column left-aligned and the others right-aligned.

    >>> _table(["run", "s"], [["a", 1]])
    ['| run | s |', '|---|---:|', '| a | 1 |']
    """
    rule = "|---|" + "---:|" * (len(header) - 1)
    return [
        "| " + " | ".join(header) + " |",
        rule,
        *("| " + " | ".join(str(v) for v in row) + " |" for row in rows),
    ]


def _mm(value: float | None) -> str:
    """A length in mm to two decimals, a dash for none.

    >>> _mm(1.234), _mm(None), _mm(math.nan)
    ('1.23', '–', '–')
    """
    return "–" if value is None or math.isnan(value) else f"{value:.2f}"


def _last(phase: dict[str, Any]) -> str:
    """A window's last event, s, and the events at its close in brackets.

    >>> _last({"last_s": 28.3, "at_close": 0}), _last({"last_s": 30.05, "at_close": 4})
    ('28.30', '30.05 (4 at the close)')
    >>> _last({"last_s": None, "at_close": 0})
    '–'
    """
    if phase["last_s"] is None:
        return "–"
    close = f" ({phase['at_close']} at the close)" if phase["at_close"] else ""
    return f"{phase['last_s']:.2f}{close}"


def _merge_s(summary: dict[str, Any]) -> float:
    return summary["phase_times_s"].get("merge", math.nan)


#: The runs of the page's main table: (label, robots, seed, overrides).
_RUNS = (
    ("100 robots, seed 1", 100, 1, {}),
    ("100 robots, seed 2", 100, 2, {}),
    ("100 robots, seed 3", 100, 3, {}),
    ("100 robots, seed 1, 20 % loss", 100, 1, LOSS),
    ("300 robots, seed 1", 300, 1, {}),
)


def runs_block() -> str:
    """Frames, localized share, RMSE against the bound, time and rounds of the page's runs."""
    header = [
        "run",
        "frames",
        "localized",
        "RMSE mm",
        "CRLB mm",
        "simulated s (merging)",
        "merge rounds",
        "CPU s",
    ]
    rows = []
    for label, n, seed, overrides in _RUNS:
        run = gcs_run(n, seed, _key(overrides))
        s = run.summary
        rows.append(
            [
                label,
                s["frames"],
                f"{s['localized_fraction']:.2f}",
                _mm(s["rmse_mm"]),
                _mm(s["crlb_rmse_mm"]),
                f"{s['sim_time_s']:.0f} ({_merge_s(s):.0f})",
                f"{s['merge_rounds']:,}",
                f"{run.cpu_s:.1f}",
            ]
        )
    loss = ", ".join(f"`{k}={v}`" for k, v in LOSS.items())
    return "\n".join([*_table(header, rows), "", f"The lossy run: {loss}."])


def error_by_distance_block() -> str:
    """The 300-robot run's error by distance from the root's seed."""
    run = gcs_run(300, 1)
    rows = [[f"{lo}–{hi}", robots, f"{rmse:.2f}"] for lo, hi, robots, rmse in run.error_bands]
    return "\n".join(_table(["mm from the root's seed", "robots", "RMSE mm"], rows))


#: The merging choices compared, by column: (heading, overrides).
_CHOICES = (
    ("default", {}),
    ("`merge_member=fixed`", {"gcs.merge_member": "fixed"}),
    ("no whole steps (`merge_whole_step_mm=128`)", {"gcs.merge_whole_step_mm": 128}),
)


def merging_choices_block() -> str:
    """Merging time and RMSE with a fixed member, and without whole steps, against the
    defaults; the sentence under the table counts what the table shows."""
    header = ["run", *(f"{name}: s of merging, RMSE mm" for name, _ in _CHOICES)]
    rows, runs = [], []
    for label, n, seed, _ in (r for r in _RUNS if not r[3]):
        row = [gcs_run(n, seed, _key(over)) for _, over in _CHOICES]
        runs.append(row)
        rows.append(
            [label]
            + [
                f"{_merge_s(r.summary):.0f} s, {_mm(r.summary['rmse_mm'])} mm, "
                f"{r.summary['frames']} frame{'s' if r.summary['frames'] != 1 else ''}"
                for r in row
            ]
        )
    faster = sum(_merge_s(f.summary) < _merge_s(d.summary) for d, f, _ in runs)
    worse = sum(f.summary["rmse_mm"] > d.summary["rmse_mm"] for d, f, _ in runs)
    change = [_merge_s(d.summary) / _merge_s(w.summary) - 1 for d, _, w in runs]
    text = (
        f"Against the same runs without them, whole steps change the time of merging by "
        f"{min(change):+.0%} to {max(change):+.0%}; a fixed member merges faster in {faster} "
        f"of {len(runs)} runs and less accurately in {worse} of {len(runs)}."
    )
    return "\n".join([*_table(header, rows), "", text])


def last_events(n: int, seed: int, overrides: dict[str, Any]) -> dict[str, Any]:
    """One run of ``n`` robots up to localization: per fixed window, its length, the time of
    its last progress event (:data:`PHASE_EVENTS`) from the window's start (``None`` if nothing
    happened), s, and how many of those events came at the window's close (a seed choosing its
    references with the tables it has when phase 3 ends: cut short).

    Times are read on each robot's own clock, as its windows run: with drifting clocks a
    robot's phase 3 opens and closes up to a second or so away from the nominal times.
    """
    from kilonet import scenarios
    from kilonet.protocols.gcs.program import phase_windows_s

    result = scenarios.run(
        scenarios.get("gcs"),
        {"placement.robots": n, **overrides, "gcs.until": "localization"},
        seed=seed,
    )
    events, clocks = result.sim.trace.events_frame(), result.sim.clocks
    row: dict[str, Any] = {"robots": n, "seed": seed}
    for name, start, end in phase_windows_s(result.params.scenario):
        if name not in PHASE_EVENTS:
            continue
        marks = events[events.event.isin(PHASE_EVENTS[name])]
        own_s = [
            clocks.ticks_at(robot, t) / clocks.ticks_per_s
            for robot, t in zip(marks.robot, marks.t_s, strict=True)
        ]
        row[name] = {
            "window_s": end - start,
            "last_s": round(max(own_s) - start, 2) if own_s else None,
            "at_close": sum(t >= end for t in own_s),
        }
    return row


def windows_block(seeds: Sequence[int] = (1, 2, 3)) -> str:
    """How much of the fixed windows of phases 1, 3 and 4 the robots use, per run."""
    cases = (
        ("100 robots", 100, {}),
        ("300 robots", 300, {}),
        ("100 robots, 20 % loss", 100, LOSS),
    )
    phases = tuple(PHASE_EVENTS)
    header, rows = None, []
    for label, n, overrides in cases:
        found = [last_events(n, seed, overrides) for seed in seeds]
        if header is None:
            header = [
                "run",
                *(f"phase {name} ({found[0][name]['window_s']:g} s)" for name in phases),
            ]
        seeds_text = f"seeds {seeds[0]}–{seeds[-1]}" if len(seeds) > 1 else f"seed {seeds[0]}"
        cells = [" / ".join(_last(r[name]) for r in found) for name in phases]
        rows.append([f"{label}, {seeds_text}", *cells])
    note = (
        "Windows are the defaults but for the lossy rows (phase 3 "
        f"{LOSS['gcs.frames_s']} s, phase 4 {LOSS['gcs.localization_s']} s); times on each "
        'robot\'s own clock; "at the close": seeds that chose their references when phase 3 '
        "ended, before they had every table."
    )
    return "\n".join([*_table(header, rows), "", note])


#: The robot-model comparison: (label, overrides).
_MODEL_VARIANTS = (
    ("defaults (no occlusion)", {}),
    ("`medium.occlusion=block`", {"medium.occlusion": "block"}),
    ("`gcs.reference_rule=best_conditioned`", {"gcs.reference_rule": "best_conditioned"}),
)


def robot_model_block(
    runs: Sequence[tuple[int, int]] = ((100, 1), (100, 2), (100, 3), (300, 1)),
) -> str:
    """Runs of ``(robots, seed)`` with the defaults, with bodies blocking links as the thesis
    assumed, and with the well-conditioned reference rule: where the error and the time went."""
    header = [
        "variant",
        "robots, seed",
        "mean neighbours",
        "seeds",
        f"references ≥ {THIN_DEG:g}° apart",
        "isolated seeds",
        "frames",
        "RMSE mm",
        "CRLB mm",
        "simulated s (merging)",
    ]
    rows = []
    for label, overrides in _MODEL_VARIANTS:
        for n, seed in runs:
            run = gcs_run(n, seed, _key(overrides))
            s = run.summary
            rows.append(
                [
                    label,
                    f"{n}, {seed}",
                    f"{s['mean_neighbours']:.1f}",
                    s["seeds"],
                    run.thin_frames,
                    run.isolated,
                    s["frames"],
                    _mm(s["rmse_mm"]),
                    _mm(s["crlb_rmse_mm"]),
                    f"{s['sim_time_s']:.0f} ({_merge_s(s):.0f})",
                ]
            )
    return "\n".join(_table(header, rows))


#: The suspects for isolated seeds, each a variant of the 40-robot runs: (label, overrides).
_ISOLATION_VARIANTS = (
    ("defaults (no occlusion, 3 s phase 5, clocks ±1 %)", {}),
    ("`gcs.groups_s=10`", {"gcs.groups_s": 10}),
    ("`robot.clock_sd=0` (perfect clocks)", {"robot.clock_sd": 0.0}),
    ("`medium.occlusion=block`", {"medium.occlusion": "block"}),
    ("`gcs.reference_rule=best_conditioned`", {"gcs.reference_rule": "best_conditioned"}),
)


def isolated_seeds_block(seeds: Sequence[int] = tuple(range(1, 9))) -> str:
    """Isolated seeds at the end of phase 5 on 40-robot lattices under each suspect's variant,
    summed over seeds."""
    header = [
        f"40 robots, seeds {seeds[0]}–{seeds[-1]}, after phase 5",
        "seeds",
        f"references ≥ {THIN_DEG:g}° apart",
        "isolated seeds",
        "isolated, frame of seed and references only",
        f"of which references ≥ {THIN_DEG:g}° apart",
        "frame pairs with a group",
        "of which a seed got no registration",
    ]
    rows = []
    for label, overrides in _ISOLATION_VARIANTS:
        runs = [gcs_run(40, seed, _key({**overrides, "gcs.until": "groups"})) for seed in seeds]
        rows.append(
            [
                label,
                sum(r.summary["seeds"] for r in runs),
                sum(r.thin_frames for r in runs),
                sum(r.isolated for r in runs),
                sum(r.isolated_alone for r in runs),
                sum(r.isolated_alone_thin for r in runs),
                sum(r.pairs_with_group for r in runs),
                sum(r.pairs_unregistered for r in runs),
            ]
        )
    return "\n".join(_table(header, rows))
