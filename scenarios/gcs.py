"""``gcs``: Rubenstein's global coordinate system, phases 1–6, on a swarm without UIDs.

Runs :class:`kilonet.protocols.gcs.program.GcsRobot` on every robot (``robot.hardware_uids =
false``: the robots build their own IDs) and measures each phase against ground truth:

* ids — duplicate IDs left among neighbours (in the line-of-sight graph);
* seeds — seeds elected, robots whose seed condition failed;
* frames — seeds with a frame; references' coordinates;
* localization — robots located in at least one local frame, per-frame RMSE after the best
  rigid alignment (reflection allowed), rejected fixes;
* groups — merging groups;
* merge — final global frames (robots grouped by the root their estimate is in), localized
  share, RMSE of the global estimates after aligning each final frame to the truth, pooled
  over robots; beside it the bound and the optimum (:mod:`kilonet.scenarios.reference`: the
  anchor-free Cramér–Rao bound for the same graph and noise, ``rmse_over_crlb``, the bound for
  the receptions averaged, the centralized solver on the run's measured distances) and
  ``done_s``, when the last seed was done merging (``done_over_hop_limit``: over
  ``hop_diameter × robot.tx_period_s``);
* refine (``gcs.refine = true``, :mod:`kilonet.protocols.gcs.phase7_refinement`) — the summary's
  estimates, ``rmse_mm`` and the figures are the refined ones; ``merge_rmse_mm`` keeps the RMSE the
  merged estimates had, ``refined_fraction`` the share of robots that refined, and ``done_s`` is
  when the last robot stopped refining;
* failures (thesis §7) — ``failures``: what the run built (unlocalizable robots, isolated seeds,
  the frame graph's components, robots next to another final frame); ``predicted``: what the
  geometry and phase 2's election predicted (:mod:`kilonet.scenarios.prediction`); ``detected``:
  what the swarm flagged itself (:mod:`kilonet.protocols.gcs.split_detection`); ``recoveries`` and
  ``edge_seeds`` (:mod:`kilonet.protocols.gcs.recovery`). ``robots.csv`` carries the same per robot.

Every figure comes from one read of each robot's
:meth:`~kilonet.protocols.gcs.program.GcsRobot.outcome` at the end of the run
(:func:`run_outcomes`), shared by the summary, ``robots.csv``'s columns and the figure.

The run ends when every seed is done merging, no recovery is pending, and the robots have had
a few seconds to check their neighbours without finding a split boundary that a recovery
would act on (while one lasts, the run waits for it to clear or to start a recovery). With the
refinement, it ends when every robot that refines has stopped and none is about to start.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.protocols.gcs.base import PHASES, GcsParams, GcsStage
from kilonet.scenarios.base import Drawing, Reporting, RunResult, Scenario, ScenarioOption, Setup

if TYPE_CHECKING:  # the rest is imported where used, so that listing scenarios stays fast
    import pandas as pd

    from kilonet.params import Params
    from kilonet.protocols.gcs.frame_keys import FrameKey
    from kilonet.protocols.gcs.program import GcsRobot, RobotOutcome
    from kilonet.simulation import Simulation

__all__ = [
    "SCENARIO",
    "RunOutcomes",
    "estimates_frame",
    "fold_outliers",
    "local_frames_frame",
    "own_components",
    "run_outcomes",
]


def _program(params: Any, positions: np.ndarray):
    from kilonet.protocols.gcs.program import GcsRobot

    return lambda _i: GcsRobot(params.scenario)


#: After the last seed is done, the time robots get to exchange positions (a settled robot
#: sends one at every fourth transmit opportunity, about one a second) and flag a boundary.
_CHECK_S = 5.0
#: After the last seed is done, the longest the run waits for robots the fold rule is about to
#: act on (kilonet.protocols.gcs.split_detection): a settled one acts within
#: gcs.fold_confirm_s; one not settled (it holds a transform without its done mark, from a seed
#: at the edge of its range) acts, or agrees with its neighbours, once it hears the mark again.
#: One that has not within this is reported as it stands.
_FOLD_WAIT_S = 60.0


def _stop_when(sim: Simulation) -> bool:
    from kilonet.protocols.gcs.program import OPEN_ENDED, phase_windows_s

    windows = phase_windows_s(sim.params.scenario)
    name, _, end = windows[-1]
    now = sim.env.now
    if name not in OPEN_ENDED:
        return now >= end + 1.0  # a second more, so every robot has closed the last window
    open_start = next(start for phase, start, _ in windows if phase in OPEN_ENDED)
    if now <= open_start:
        return False
    running = sim.world.running
    robots = [r for i, r in enumerate(sim.robots) if running[i]]  # a crashed seed is never done
    if name == GcsStage.REFINE:
        return _refinement_over(robots)
    seeds = [r for r in robots if r.is_seed]
    if not _merging_over(robots, seeds):
        return False
    quiet = now - max(r.merge_done_at_s for r in seeds)
    return quiet >= _CHECK_S and (
        quiet >= _FOLD_WAIT_S or not any(r.awaiting_fold() for r in robots)
    )


def _refinement_over(robots: list[GcsRobot]) -> bool:
    """Nothing more will happen in a run that refines: every robot refining has stopped, no
    robot still merging is about to refine (its estimate settled, :meth:`FrameMerging.finished`
    counting) or is a seed not done, all merge in one epoch, and no recovery is announced or
    awaited."""
    from kilonet.protocols.gcs.program import OPEN_ENDED

    if len({r.epoch for r in robots}) > 1 or any(r.awaiting_recovery() for r in robots):
        return False
    for r in robots:
        name = r.phase_name
        if name == GcsStage.REFINE and not r.phase.done:
            return False
        if name == GcsStage.MERGE and (
            r.phase.settled_since is not None or (r.is_seed and not r.merge_done)
        ):
            return False
        if name and name not in OPEN_ENDED:
            return False
    return any(r.phase_name != GcsStage.MERGE for r in robots) or not any(
        r.estimate.settled() for r in robots
    )


def _merging_over(robots: list[GcsRobot], seeds: list[GcsRobot]) -> bool:
    """Nothing more will happen: every seed is done, every robot merges in the same epoch, and
    no recovery is announced or about to be (the robots then get :data:`_CHECK_S` to check
    their neighbours, :mod:`kilonet.protocols.gcs.split_detection`, and up to
    :data:`_FOLD_WAIT_S` for the fold rule)."""
    if not seeds or not all(r.merge_done for r in seeds):
        return False
    if len({r.epoch for r in robots}) > 1:
        return False
    return not any(r.phase_name != GcsStage.MERGE or r.awaiting_recovery() for r in robots)


def _expected_end_s(params: Params) -> float | None:
    """Where :func:`_stop_when` ends a run that stops before merging; merging has no known end."""
    from kilonet.protocols.gcs.program import phase_windows_s

    end = phase_windows_s(params.scenario)[-1][2]
    return end + 1.0 if math.isfinite(end) else None


def _phase_note(sim: Simulation) -> str:
    """The phase the run is in, for the progress display: ``phase 3/6 frames (to 41 s)``."""
    from kilonet.protocols.gcs.program import phase_windows_s

    windows = phase_windows_s(sim.params.scenario)
    now = sim.env.now
    k, (name, _, end) = next(
        ((k, w) for k, w in enumerate(windows) if now < w[2]), (len(windows) - 1, windows[-1])
    )
    until = f" (to {end:g} s)" if math.isfinite(end) else ""
    phases = len(PHASES) if windows[-1][0] == GcsStage.REFINE else len(PHASES) - 1  # 7 with 7
    return f"phase {k + 1}/{phases} {name}{until}"


@dataclass(frozen=True)
class RunOutcomes:
    """The robots' outcomes at the end of a run, and the tables the scenario makes of them.

    Attributes
    ----------
    robots : list of RobotOutcome
        One per robot, by index.
    seed_robot : dict
        Which robot (index) is the seed of each frame key (ground truth, for tables).
    estimates : DataFrame
        :func:`estimates_frame`'s table.
    """

    robots: list[RobotOutcome]
    seed_robot: dict[FrameKey, int]
    estimates: pd.DataFrame


#: Outcomes already read, per simulation: (simulated time they were read at, outcomes).
_READ: weakref.WeakKeyDictionary[Simulation, tuple[float, RunOutcomes]] = (
    weakref.WeakKeyDictionary()
)


def run_outcomes(sim: Simulation) -> RunOutcomes:
    """Every robot's :meth:`~kilonet.protocols.gcs.program.GcsRobot.outcome`, read once per
    simulated moment: the summary, ``robots.csv`` and the figure of a run all use the same read."""
    read = _READ.get(sim)
    if read is not None and read[0] == sim.env.now:
        return read[1]
    robots = [r.outcome() for r in sim.robots]
    seed_robot = {o.own_key: i for i, o in enumerate(robots) if o.is_seed}
    estimates = _estimates(robots, seed_robot, sim.world.positions_mm)
    outcomes = RunOutcomes(robots, seed_robot, estimates)
    _READ[sim] = (sim.env.now, outcomes)
    return outcomes


def _estimates(
    robots: list[RobotOutcome], seed_robot: dict[FrameKey, int], truth_mm: np.ndarray
) -> pd.DataFrame:
    import pandas as pd

    from kilonet.scenarios.estimates import with_alignment

    rows = []
    for i, o in enumerate(robots):
        est = o.position
        rows.append(
            {
                "robot": i,
                "uid": o.uid,
                "role": o.role,
                "frames": len(o.local_positions),
                "est_x_mm": est[0] if est else math.nan,
                "est_y_mm": est[1] if est else math.nan,
                "frame": "" if o.root is None else o.root.label,
                "root_robot": -1 if o.root is None else seed_robot.get(o.root.key, -1),
                "localized": est is not None,
                "seed_of_frame": seed_robot.get(o.own_key, -1) if o.is_seed else -1,
                # Failure cases as this robot ended (thesis §7) and what the swarm detected.
                "unlocalizable": not o.local_positions,
                "isolated_seed": o.isolated_seed,
                "split_boundary": o.split_boundary,
                "inconsistent": o.inconsistent,
                "edge_seed": o.edge_seed,
            }
        )
    return with_alignment(pd.DataFrame(rows), truth_mm)


def estimates_frame(sim: Simulation) -> pd.DataFrame:
    """Per robot: role, ID, frames held, global estimate, final frame label
    (:attr:`kilonet.protocols.gcs.frame_keys.Root.label`) and the robot that seeded that root's
    frame (``root_robot``), the estimate aligned to the truth and its error
    (:func:`kilonet.scenarios.estimates.with_alignment`), failure flags: ``robots.csv``'s
    columns."""
    return run_outcomes(sim).estimates


def local_frames_frame(sim: Simulation) -> pd.DataFrame:
    """Long table of local positions: ``robot, seed_robot, local_x_mm, local_y_mm``."""
    import pandas as pd

    outcomes = run_outcomes(sim)
    seeds = outcomes.seed_robot
    rows = [
        (i, seeds.get(key, -1), x, y)
        for i, o in enumerate(outcomes.robots)
        for key, (x, y) in sorted(o.local_positions.items())
    ]
    return pd.DataFrame(rows, columns=["robot", "seed_robot", "local_x_mm", "local_y_mm"])


def _pooled_rmse(groups: list[tuple[np.ndarray, np.ndarray]]) -> float:
    from kilonet.protocols.common.alignment import procrustes_rmse

    squared, count = 0.0, 0
    for est, true in groups:
        if len(est) >= 3:
            rmse, _, _ = procrustes_rmse(est, true)
            squared += rmse**2 * len(est)
            count += len(est)
    return math.sqrt(squared / count) if count else math.nan


def _per_frame(
    table: pd.DataFrame, by: str, xy: list[str], truth: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(estimates, truth)`` per group of ``table`` by column ``by``, for :func:`_pooled_rmse`."""
    return [(g[xy].to_numpy(), truth[g.robot.to_numpy()]) for _, g in table.groupby(by)]


def own_components(components: list[list[int]], located: dict[int, list[int]]) -> list[list[int]]:
    """The components of the frame graph that are a global frame of their own: some robot is
    located in frames of that component only. A seed in no merging group whose robots are all
    located in other frames too splits nothing (it is the thesis's case 2, not case 3).

    Examples
    --------
    >>> own_components([[1, 2], [3], [4]], {10: [1, 3], 11: [2], 12: [4]})
    [[1, 2], [4]]
    """
    return [
        c
        for c in components
        if any(frames and set(frames) <= set(c) for frames in located.values())
    ]


def _failures(sim: Simulation, outcomes: RunOutcomes) -> dict[str, Any]:
    """The thesis's failure cases as this run produced them (robot indices), with the
    communication graph's rigidity facts that explain them."""
    from kilonet.scenarios.topology import failure_cases, rigidity_facts

    seeds = outcomes.seed_robot
    robots = outcomes.robots
    located = {i: [seeds[k] for k in o.local_positions if k in seeds] for i, o in enumerate(robots)}
    groups = [
        (seeds[a], seeds[b]) for o in robots for a, b in o.groups if a in seeds and b in seeds
    ]
    cases = failure_cases(range(sim.n_robots), located, sorted(seeds.values()), groups)
    facts = rigidity_facts(sim.medium.graph())
    own = own_components(cases["frames"], located)
    return {
        "unlocalizable": cases["unlocalizable"],
        "isolated_seeds": cases["isolated_seeds"],
        "split_frames": len(own) if len(own) > 1 else 0,
        "frame_components": cases["frames"],
        "articulation_points": facts["articulation_points"],
        "robots_with_fewer_than_3_neighbours": facts["low_degree"],
    }


def _duplicate_ids(uids: np.ndarray, i: np.ndarray, j: np.ndarray) -> int:
    """Neighbours (pairs ``i``, ``j``) sharing an ID, plus two robots with one ID seen by a
    common neighbour."""
    duplicates = int(np.sum(uids[i] == uids[j]))
    for k in range(len(uids)):
        near = np.concatenate([j[i == k], i[j == k]])
        duplicates += len(near) - len(set(uids[near].tolist()))
    return duplicates


def _prediction(sim: Simulation, robots: list[RobotOutcome]) -> dict[str, Any]:
    """What the geometry and phase 2's election predicted (kilonet.scenarios.prediction), to report
    next to what happened: the topology sweep compares the two."""
    from kilonet.scenarios.neighbourhood import held_estimates_mm
    from kilonet.scenarios.prediction import predict_from_seeds

    elected = [k for k, o in enumerate(robots) if o.is_seed and not o.edge_seed]
    keys = {k: robots[k].own_key for k in elected}
    estimates = held_estimates_mm(sim, sim.params.scenario.neighbour_max_mm)
    prediction = predict_from_seeds(estimates, sim.params, elected, keys)
    names = ("final_frames", "unlocalizable", "isolated_seeds", "boundary")
    return {name: prediction[name] for name in names}


@dataclass(frozen=True)
class _Run:
    """What the metrics of one run are computed from."""

    sim: Simulation
    outcomes: RunOutcomes
    counts: dict[str, int]  # events logged, by name
    i: np.ndarray  # pairs of robots in range and line of sight
    j: np.ndarray

    @property
    def robots(self) -> list[RobotOutcome]:
        return self.outcomes.robots

    @property
    def truth(self) -> np.ndarray:
        return self.sim.world.positions_mm

    def count(self, event: str) -> int:
        return int(self.counts.get(event, 0))


def _seed_metrics(run: _Run, out: dict[str, Any]) -> None:
    out["seeds"] = int(sum(o.is_seed for o in run.robots))
    out["seed_check_failed"] = run.count("seed_check_failed")


def _frame_metrics(run: _Run, out: dict[str, Any]) -> None:
    out["seeds_with_frame"] = int(sum(o.has_frame for o in run.robots))
    out["busy_resets"] = run.count("busy_reset")


def _localization_metrics(run: _Run, out: dict[str, Any]) -> None:
    local, n = local_frames_frame(run.sim), run.sim.n_robots
    out["locally_localized_fraction"] = local.robot.nunique() / n
    out["mean_frames_per_robot"] = len(local) / n
    xy = ["local_x_mm", "local_y_mm"]
    out["local_rmse_mm"] = _pooled_rmse(_per_frame(local, "seed_robot", xy, run.truth))
    out["fix_rejections"] = run.count("fix_rejected")


def _group_metrics(run: _Run, out: dict[str, Any]) -> None:
    out["merging_groups"] = int(sum(len(o.groups) for o in run.robots))
    out["failures"] = _failures(run.sim, run.outcomes)
    out["predicted"] = _prediction(run.sim, run.robots)


def _merge_metrics(run: _Run, out: dict[str, Any]) -> None:
    """Final frames, localized share, RMSE and the bound, rounds, recoveries, detection."""
    sim, robots, est = run.sim, run.robots, run.outcomes.estimates
    n = sim.n_robots
    done = est[est.localized]
    sizes = done.groupby("frame").size()
    seeds = [o for o in robots if o.is_seed]
    out.update(
        {
            "localized_fraction": len(done) / n,
            "frames": len(sizes),
            "largest_frame_fraction": float(sizes.max() / n) if len(sizes) else 0,
            "rmse_mm": _pooled_rmse(_per_frame(done, "frame", ["est_x_mm", "est_y_mm"], run.truth)),
            "merge_rounds": run.count("merge_round"),
            "merge_rounds_max_per_seed": int(max((o.merge_rounds for o in seeds), default=0)),
            "seeds_done": int(sum(o.merge_done for o in seeds)),
            "recoveries": int(max(o.epoch for o in robots)),
            "edge_seeds": int(est.edge_seed.sum()),
            "detected": {
                "split_boundary": est.robot[est.split_boundary].tolist(),
                "inconsistent": est.robot[est.inconsistent].tolist(),
            },
        }
    )
    out.setdefault("failures", {})["boundary"] = _boundary(est, run.i, run.j)
    out["fold_outliers"] = fold_outliers(
        est, run.truth, run.i, run.j, sim.params.scenario.check_tolerance_mm
    )
    # What the swarm did about folds (gcs.fold) that stands at the end: robots holding a repair,
    # robots split off into a frame of their own (the events fold_repaired and fold_split log
    # every action, those a recovery epoch voided too).
    folds = [o.fold for o in robots]
    out["fold_repaired"] = folds.count("repaired")
    out["fold_split"] = folds.count("split")


def fold_outliers(
    est: pd.DataFrame, truth_mm: np.ndarray, i: np.ndarray, j: np.ndarray, tolerance_mm: float
) -> list[int]:
    """The truth a fold repair is judged by: robots whose estimated distance to their linked
    neighbours (pairs ``i``, ``j``) in the same final frame differs from the true one by more
    than ``tolerance_mm`` for a majority, and at least two, of those neighbours
    (:func:`kilonet.protocols.gcs.fold_rule.is_outlier`, applied to the truth): a frame whose
    robots disagree with each other beyond the ranging error, not one merely bent.

    Examples
    --------
    >>> import pandas as pd
    >>> truth = np.array([[0.0, 0], [40, 0], [0, 40], [40, 40]])
    >>> est = pd.DataFrame({"robot": range(4), "frame": ["a"] * 4,
    ...                     "est_x_mm": [0.0, 40, 0, 140], "est_y_mm": [0.0, 0, 40, 40]})
    >>> i, j = np.array([0, 0, 0, 1, 1, 2]), np.array([1, 2, 3, 2, 3, 3])
    >>> fold_outliers(est, truth, i, j, 8.0)
    [3]
    """
    from kilonet.protocols.gcs.fold_rule import is_outlier

    label = est.frame.to_numpy()
    xy = est[["est_x_mm", "est_y_mm"]].to_numpy()
    same = (label[i] != "") & (label[i] == label[j])
    a, b = i[same], j[same]
    mismatch = np.abs(
        np.hypot(*(xy[a] - xy[b]).T) - np.hypot(*(truth_mm[a] - truth_mm[b]).T)
    ).tolist()
    by_robot: dict[int, dict[int, float]] = {}
    for p, q, m in zip(a.tolist(), b.tolist(), mismatch, strict=True):
        by_robot.setdefault(p, {})[q] = m
        by_robot.setdefault(q, {})[p] = m
    return sorted(k for k, seen in by_robot.items() if is_outlier(seen, tolerance_mm))


def _reference_metrics(run: _Run, out: dict[str, Any]) -> None:
    """The bound and the optimum beside the swarm's result (:mod:`kilonet.scenarios.reference`; no
    two robots in range: nothing is measured, ``crlb_rmse_mm`` is null), and when the swarm was
    done: the last seed done merging, or the last robot done refining."""
    import pandas as pd

    from kilonet.scenarios.reference import largest_frame_mm, reference_metrics

    sim, est = run.sim, run.outcomes.estimates
    labels = np.where(est.localized, pd.factorize(est.frame)[0], -1)
    out.update(
        reference_metrics(
            sim,
            [r.table for r in sim.robots],
            (run.i, run.j),
            rmse_mm=out["rmse_mm"],
            frame_mm=largest_frame_mm(est[["est_x_mm", "est_y_mm"]].to_numpy(), labels),
        )
    )
    events = sim.trace.events_frame()
    last = "refine_done" if out["phases_run"][-1] == GcsStage.REFINE else "merge_done"
    times = events.t_s[events.event == last] if len(events) else []
    stopped = sim.env.now < sim.params.duration_s  # the run ended by itself
    out["done_s"] = round(float(max(times)), 3) if len(times) and stopped else math.nan
    if out["hop_diameter"]:
        limit = out["hop_diameter"] * sim.params.robot.tx_period_s
        out["done_over_hop_limit"] = out["done_s"] / limit


def _refine_metrics(run: _Run, out: dict[str, Any]) -> None:
    """The merged estimates' RMSE (before refinement) and the share of robots that refined."""
    robots = run.robots
    merged = [(i, o) for i, o in enumerate(robots) if o.merged_position is not None]
    groups: dict[str, list[int]] = {}
    for i, o in merged:
        groups.setdefault(o.merged_root.label, []).append(i)
    pairs = [
        (np.array([robots[i].merged_position for i in members]), run.truth[members])
        for members in groups.values()
    ]
    out["merge_rmse_mm"] = _pooled_rmse(pairs)
    out["refined_fraction"] = sum(o.refined for o in robots) / len(robots)


#: The metrics of each phase, added to the summary once the run has reached the phase.
_PHASE_METRICS = (
    (GcsStage.SEEDS, _seed_metrics),
    (GcsStage.FRAMES, _frame_metrics),
    (GcsStage.LOCALIZATION, _localization_metrics),
    (GcsStage.GROUPS, _group_metrics),
    (GcsStage.MERGE, _merge_metrics),
    (GcsStage.MERGE, _reference_metrics),
    (GcsStage.REFINE, _refine_metrics),
)


def _boundary(est: pd.DataFrame, i: np.ndarray, j: np.ndarray) -> list[int]:
    """The truth the swarm's detection is judged by: robots with a neighbour (line of sight)
    whose estimate ended in another final frame."""
    label = est.frame.to_numpy()
    split = (label[i] != "") & (label[j] != "") & (label[i] != label[j])
    return sorted({int(k) for k in np.concatenate([i[split], j[split]])})


def _metrics(sim: Simulation) -> dict[str, Any]:
    from kilonet.protocols.gcs.program import phase_windows_s
    from kilonet.visibility import LinkModel

    events = sim.trace.events_frame()
    from kilonet.scenarios.neighbourhood import neighbourhood_mm

    p = sim.params
    # The protocol's neighbours: robots it hears, within gcs.neighbour_max_mm.
    reach_mm = neighbourhood_mm(p.medium, p.scenario.neighbour_max_mm)
    links = LinkModel.from_params(p.medium, sim.world.radius_mm, range_mm=reach_mm).links(
        sim.world.positions_mm
    )
    i, j = links.i, links.j
    counts = events["event"].value_counts().to_dict() if len(events) else {}
    run = _Run(sim, run_outcomes(sim), counts, i, j)
    windows = phase_windows_s(sim.params.scenario)
    now = sim.env.now
    reached = [(name, start, end) for name, start, end in windows if now >= start]
    out: dict[str, Any] = {
        "mean_neighbours": 2.0 * len(i) / sim.n_robots,  # in the communication graph
        "phases_run": [name for name, _, _ in windows],
        "phase_times_s": {name: round(min(now, end) - start, 3) for name, start, end in reached},
        "ids_duplicate_neighbours": _duplicate_ids(np.array([o.uid for o in run.robots]), i, j),
        "ids_redraws": run.count("id"),
    }
    names = {name for name, _, _ in reached}
    if GcsStage.MERGE in names and windows[-1][0] == GcsStage.REFINE:
        names.add(GcsStage.REFINE)  # its window opens on each robot when merging is over there
    for phase, section in _PHASE_METRICS:
        if phase in names:
            section(run, out)
    return out


def _outputs(result: RunResult, out_dir: Path) -> None:
    from kilonet.scenarios.figures import frames_figure

    sim, summary = result.sim, result.summary
    local_frames_frame(sim).to_csv(out_dir / "local_frames.csv", index=False)
    outcomes = run_outcomes(sim)
    frames_figure(
        sim.world.positions_mm,
        outcomes.estimates,
        np.array([i for i, o in enumerate(outcomes.robots) if o.is_seed], dtype=int),
        "seed",
        _figure_title(summary),
        out_dir / "gcs.png",
    )


def _figure_title(summary: dict[str, Any]) -> str:
    """The figure's title: frames and RMSE, or where a run that stopped early stopped.

    >>> _figure_title({"frames": 1, "rmse_mm": 2.414})
    'global coordinate system: 1 frame, RMSE 2.41 mm'
    >>> _figure_title({"phases_run": ["ids", "seeds"]})
    'global coordinate system: stopped after phase seeds, before any global estimate'
    """
    if "frames" not in summary:
        last = summary.get("phases_run", ["?"])[-1]
        return f"global coordinate system: stopped after phase {last}, before any global estimate"
    frames, rmse = summary["frames"], summary.get("rmse_mm")
    error = f"RMSE {rmse:.2f} mm" if rmse is not None and math.isfinite(rmse) else "no RMSE"
    return f"global coordinate system: {frames} frame{'s' if frames != 1 else ''}, {error}"


SCENARIO = Scenario(
    name="gcs",
    summary="Rubenstein's global coordinate system, phases 1-6 (IDs, seeds, frames, "
    "localization, merging groups, merging)",
    setup=Setup(
        program=_program,
        section=GcsParams,
        robots=100,
        defaults={
            "duration_s": 3600.0,
            "robot.hardware_uids": False,
            # The thesis's library: a message every 200 ms with jitter, CSMA/CA back-off, a send
            # buffer that is sampled once a period; its loop only needs to run every other tick.
            "robot.tx_period_s": 0.2,
            "robot.tx_jitter_s": 0.02,
            "robot.tx_retry": "period",
            "medium.backoff_max_s": 0.01,
            "robot.loop_ticks": 2,
            "placement.jitter_mm": 2.0,
        },
        supports={"medium.message_format": ("kilolib",), "robot.rx_distance": ("estimate",)},
        stop_when=_stop_when,
        options=(ScenarioOption("--until", "gcs.until", "stop after this phase"),),
    ),
    reporting=Reporting(
        metrics=_metrics,
        robot_columns=estimates_frame,
        expected_end_s=_expected_end_s,
        ends_when="merging (or with gcs.refine, refining) is done",
        progress_note=_phase_note,
    ),
    drawing=Drawing(
        figures=_outputs,
    ),
)
