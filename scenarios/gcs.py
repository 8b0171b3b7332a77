"""``gcs``: Rubenstein's global coordinate system, phases 1–6, on a swarm without UIDs.

Runs :class:`protocols.gcs.GcsRobot` on every robot (``robot.hardware_uids = false``: the
robots build their own IDs) and measures each phase against ground truth:

* ids — duplicate IDs left among neighbours (in the line-of-sight graph);
* seeds — seeds elected, robots whose seed condition failed;
* frames — seeds with a frame; references' coordinates;
* localization — robots located in at least one local frame, per-frame RMSE after the best
  rigid alignment (reflection allowed), rejected fixes;
* groups — merging groups;
* merge — final global frames (robots grouped by the root their estimate is in), localized
  share, RMSE of the global estimates after aligning each final frame to the truth, pooled
  over robots, and the anchor-free Cramér–Rao bound for the same graph and noise;
* failures (thesis §7) — ``failures``: what the run built (unlocalizable robots, isolated seeds,
  the frame graph's components, robots next to another final frame); ``predicted``: what the
  geometry and phase 2's election predicted (:mod:`scenarios.prediction`); ``detected``: what
  the swarm flagged itself (:mod:`protocols.split_detection`); ``recoveries`` and
  ``edge_seeds`` (:mod:`protocols.recovery`). ``robots.csv`` carries the same per robot.

The run ends when every seed is done merging, no recovery is pending, and the robots have had
a few seconds to check their neighbours without finding a split boundary that a recovery
would act on (while one lasts, the run waits for it to clear or to start a recovery).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from protocols.gcs_base import GcsParams
from scenarios.base import RunResult, Scenario, ScenarioOption

if TYPE_CHECKING:  # the rest is imported where used, so that listing scenarios stays fast
    import pandas as pd

    from kilonet.params import Params
    from kilonet.simulation import Simulation

__all__ = ["SCENARIO", "estimates_frame", "local_frames_frame"]


def _program(params: Any, positions: np.ndarray):
    from protocols.gcs import GcsRobot

    return lambda _i: GcsRobot(params.scenario)


def _windows(sim: Simulation) -> list[tuple[str, float, float]]:
    from protocols.gcs import phase_windows_s

    return phase_windows_s(sim.params.scenario)


#: After the last seed is done, the time robots get to exchange positions (a settled robot
#: sends one at every fourth transmit opportunity, about one a second) and flag a boundary.
_CHECK_S = 5.0


def _stop_when(sim: Simulation) -> bool:
    windows = _windows(sim)
    name, start, end = windows[-1]
    now = sim.env.now
    if name != "merge":
        return now >= end + 1.0  # a second more, so every robot has closed the last window
    running = sim.world.running
    robots = [r for i, r in enumerate(sim.robots) if running[i]]  # a crashed seed is never done
    seeds = [r for r in robots if r.is_seed]
    if now <= start or not seeds or not all(r.merge_done for r in seeds):
        return False
    # Nothing more will happen: every robot merges in the same epoch, no recovery is announced
    # or about to be (a split boundary that will be acted on), and since the last seed was done
    # the robots have had the time to check their neighbours (split_detection).
    p = sim.params.scenario
    if len({r.epoch for r in robots}) > 1 or any(
        r.phase_name != "merge"
        or r.recovery.pending
        or (r.check is not None and r.check.boundary_since is not None and r.epoch < p.recoveries)
        for r in robots
    ):
        return False
    settled_s = max(r.phase.done_since for r in seeds) / robots[0].ticks_per_s
    return now - settled_s >= _CHECK_S


def _expected_end_s(params: Params) -> float | None:
    """Where :func:`_stop_when` ends a run that stops before merging; merging has no known end."""
    from protocols.gcs import phase_windows_s

    name, _, end = phase_windows_s(params.scenario)[-1]
    return None if name == "merge" else end + 1.0


def _phase_note(sim: Simulation) -> str:
    """The phase the run is in, for the progress display: ``phase 3/6 frames (to 41 s)``."""
    from protocols.gcs_base import PHASES

    windows = _windows(sim)
    now = sim.env.now
    k, (name, _, end) = next(
        ((k, w) for k, w in enumerate(windows) if now < w[2]), (len(windows) - 1, windows[-1])
    )
    until = f" (to {end:g} s)" if math.isfinite(end) else ""
    return f"phase {k + 1}/{len(PHASES)} {name}{until}"


def _seed_robot_by_key(sim: Simulation) -> dict[int, int]:
    """Which robot (index) is the seed of each frame key (ground truth, for tables)."""
    return {r.frame_key(r.uid): i for i, r in enumerate(sim.robots) if r.is_seed}


def local_frames_frame(sim: Simulation) -> pd.DataFrame:
    """Long table of local positions: ``robot, seed_robot, local_x_mm, local_y_mm``."""
    import pandas as pd

    seeds = _seed_robot_by_key(sim)
    rows = [
        (i, seeds.get(key, -1), x, y)
        for i, r in enumerate(sim.robots)
        for key, (x, y) in sorted(r.frames.items())
    ]
    return pd.DataFrame(rows, columns=["robot", "seed_robot", "local_x_mm", "local_y_mm"])


def estimates_frame(sim: Simulation) -> pd.DataFrame:
    """Per robot: truth, role, ID, frames held, global estimate, final frame label."""
    import pandas as pd

    seeds = _seed_robot_by_key(sim)
    rows = []
    for i, r in enumerate(sim.robots):
        est = r.global_position() if hasattr(r, "transforms") else None
        root = r.global_root if est is not None else None
        check = getattr(r, "check", None)
        rows.append(
            {
                "robot": i,
                "uid": r.uid,
                "role": r.role,
                "frames": len(r.frames),
                "est_x_mm": est[0] if est else math.nan,
                "est_y_mm": est[1] if est else math.nan,
                "frame": "" if root is None else f"root{root}",
                "localized": est is not None,
                "seed_of_frame": seeds.get(r.frame_key(r.uid), -1) if r.is_seed else -1,
                # Failure cases as this robot ended (thesis §7) and what the swarm detected.
                "unlocalizable": not r.frames,
                "isolated_seed": r.is_seed and not r.partners,
                "split_boundary": check is not None and check.on_split_boundary,
                "inconsistent": check is not None and bool(check.inconsistent),
                "edge_seed": r.edge_seed,
            }
        )
    return pd.DataFrame(rows)


def _pooled_rmse(groups: list[tuple[np.ndarray, np.ndarray]]) -> float:
    from kilonet.alignment import procrustes_rmse

    squared, count = 0.0, 0
    for est, true in groups:
        if len(est) >= 3:
            rmse, _, _ = procrustes_rmse(est, true)
            squared += rmse**2 * len(est)
            count += len(est)
    return math.sqrt(squared / count) if count else math.nan


def _failures(sim: Simulation) -> dict[str, Any]:
    """The thesis's failure cases as this run produced them (robot indices), with the
    communication graph's rigidity facts that explain them."""
    from scenarios.topology import failure_cases, rigidity_facts

    seeds = _seed_robot_by_key(sim)
    located = {i: [seeds[k] for k in r.frames if k in seeds] for i, r in enumerate(sim.robots)}
    groups = [
        (seeds[a], seeds[b]) for r in sim.robots for a, b in r.groups if a in seeds and b in seeds
    ]
    cases = failure_cases(range(sim.n_robots), located, sorted(seeds.values()), groups)
    facts = rigidity_facts(sim.medium.graph())
    return {
        "unlocalizable": cases["unlocalizable"],
        "isolated_seeds": cases["isolated_seeds"],
        "split_frames": len(cases["frames"]) if cases["split"] else 0,
        "frame_components": cases["frames"],
        "articulation_points": facts["articulation_points"],
        "robots_with_fewer_than_3_neighbours": facts["low_degree"],
    }


def _metrics(sim: Simulation) -> dict[str, Any]:
    from kilonet.geometry import crlb_rmse_mm
    from kilonet.visibility import LinkModel
    from scenarios.prediction import predict_from_seeds

    windows = _windows(sim)
    robots = sim.robots
    truth = sim.world.positions_mm
    events = sim.trace.events_frame()
    counts = events["event"].value_counts().to_dict() if len(events) else {}
    links = LinkModel.from_params(sim.params.medium, sim.world.radius_mm).links(truth)
    i, j = links.i, links.j
    uids = np.array([r.uid for r in robots])
    # Two robots with one ID seen by a common neighbour, or neighbours sharing an ID.
    duplicates = int(np.sum(uids[i] == uids[j]))
    for k in range(sim.n_robots):
        near = np.concatenate([j[i == k], i[j == k]])
        duplicates += len(near) - len(set(uids[near].tolist()))
    phase_times = {}
    now = sim.env.now
    for name, start, end in windows:
        if now >= start:
            phase_times[name] = round(min(now, end) - start, 3)
    out: dict[str, Any] = {
        "mean_neighbours": 2.0 * len(i) / sim.n_robots,  # in the line-of-sight graph
        "phases_run": [name for name, _, _ in windows],
        "phase_times_s": phase_times,
        "ids_duplicate_neighbours": duplicates,
        "ids_redraws": int(counts.get("id", 0)),
    }
    reached = {name for name, start, _ in windows if now >= start}
    if "seeds" in reached:
        out["seeds"] = int(sum(r.is_seed for r in robots))
        out["seed_check_failed"] = int(counts.get("seed_check_failed", 0))
    if "frames" in reached:
        out["seeds_with_frame"] = int(sum(bool(r.references) for r in robots))
        out["busy_resets"] = int(counts.get("busy_reset", 0))
    if "localization" in reached:
        local = local_frames_frame(sim)
        located = local.robot.nunique()
        per_frame = [
            (g[["local_x_mm", "local_y_mm"]].to_numpy(), truth[g.robot.to_numpy()])
            for _, g in local.groupby("seed_robot")
        ]
        out["locally_localized_fraction"] = located / sim.n_robots
        out["mean_frames_per_robot"] = len(local) / sim.n_robots
        out["local_rmse_mm"] = _pooled_rmse(per_frame)
        out["fix_rejections"] = int(counts.get("fix_rejected", 0))
    if "groups" in reached:
        out["merging_groups"] = int(sum(len(r.groups) for r in robots))
        out["failures"] = _failures(sim)
        # What the geometry and phase 2's election predicted (scenarios.prediction), next to
        # what happened: the topology sweep compares the two.
        elected = [k for k, r in enumerate(robots) if r.is_seed and not r.edge_seed]
        keys = {k: robots[k].frame_key(robots[k].uid) for k in elected}
        prediction = predict_from_seeds(truth, sim.params, elected, keys)
        out["predicted"] = {
            "final_frames": prediction["final_frames"],
            "unlocalizable": prediction["unlocalizable"],
            "isolated_seeds": prediction["isolated_seeds"],
            "boundary": prediction["boundary"],
        }
    if "merge" in reached:
        est = estimates_frame(sim)
        done = est[est.localized]
        per_frame = [
            (g[["est_x_mm", "est_y_mm"]].to_numpy(), truth[g.robot.to_numpy()])
            for _, g in done.groupby("frame")
        ]
        sizes = done.groupby("frame").size()
        edges = np.column_stack([i, j])
        out.update(
            {
                "localized_fraction": len(done) / sim.n_robots,
                "frames": len(sizes),
                "largest_frame_fraction": float(sizes.max() / sim.n_robots) if len(sizes) else 0,
                "rmse_mm": _pooled_rmse(per_frame),
                # No two robots in range: nothing is measured, the bound is infinite (null).
                "crlb_rmse_mm": crlb_rmse_mm(truth, edges, sim.params.ranging.sigma_mm)
                if len(edges)
                else None,
                "merge_rounds": int(counts.get("merge_round", 0)),
                "merge_rounds_max_per_seed": int(
                    max((r.phase.rounds for r in robots if r.is_seed and r.phase), default=0)
                ),
                "seeds_done": int(sum(r.merge_done for r in robots if r.is_seed)),
                "recoveries": int(max(r.epoch for r in robots)),
                "edge_seeds": int(est.edge_seed.sum()),
                "detected": {
                    "split_boundary": est.robot[est.split_boundary].tolist(),
                    "inconsistent": est.robot[est.inconsistent].tolist(),
                },
            }
        )
        # The truth the swarm's detection is judged by: robots with a neighbour (line of
        # sight) whose estimate ended in another final frame.
        label = est.frame.to_numpy()
        split = (label[i] != "") & (label[j] != "") & (label[i] != label[j])
        boundary = sorted({int(k) for k in np.concatenate([i[split], j[split]])})
        out.setdefault("failures", {})["boundary"] = boundary
    return out


def _outputs(result: RunResult, out_dir: Path) -> None:
    sim = result.sim
    local_frames_frame(sim).to_csv(out_dir / "local_frames.csv", index=False)
    _figure(sim, estimates_frame(sim), out_dir / "gcs.png")


def _figure(sim: Simulation, est: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kilonet.alignment import procrustes_rmse

    truth = sim.world.positions_mm
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.scatter(truth[:, 0], truth[:, 1], s=40, facecolors="none", edgecolors="0.6", label="truth")
    done = est[est.localized]
    cmap = plt.get_cmap("tab10")
    for n, (label, g) in enumerate(done.groupby("frame")):
        idx = g.robot.to_numpy()
        pts = g[["est_x_mm", "est_y_mm"]].to_numpy()
        if len(pts) >= 3:
            _, _, aligned = procrustes_rmse(pts, truth[idx])
        else:
            aligned = truth[idx]
        color = cmap(n % 10)
        ax.scatter(aligned[:, 0], aligned[:, 1], s=14, color=color, label=f"frame {label}")
        for (x0, y0), (x1, y1) in zip(truth[idx], aligned, strict=True):
            ax.plot([x0, x1], [y0, y1], color="red", lw=0.8)
    seeds = [i for i, r in enumerate(sim.robots) if r.is_seed]
    ax.scatter(truth[seeds, 0], truth[seeds, 1], marker="x", s=30, c="k", label="seeds")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    summary = _metrics(sim)
    ax.set_title(
        f"global coordinate system: {summary.get('frames', '?')} frame(s), "
        f"RMSE {summary.get('rmse_mm', math.nan):.2f} mm"
    )
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


SCENARIO = Scenario(
    name="gcs",
    summary="Rubenstein's global coordinate system, phases 1-6 (IDs, seeds, frames, "
    "localization, merging groups, merging)",
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
    metrics=_metrics,
    stop_when=_stop_when,
    outputs=_outputs,
    robot_columns=estimates_frame,
    options=(ScenarioOption("--until", "gcs.until", "stop after this phase"),),
    expected_end_s=_expected_end_s,
    ends_when="every seed is done merging",
    progress_note=_phase_note,
)
