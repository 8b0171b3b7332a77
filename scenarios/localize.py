"""``localize``: one global frame at the Cramér–Rao bound, by the swarm alone.

Runs :class:`kilonet.protocols.localize.program.LocalizeRobot` on every robot (``robot.hardware_uids
= false``: the robots draw their own IDs; ``robot.tx_period_s = 0.2``, the thesis library's
period, as in ``gcs``) until every running robot is done (the swarm decides: see
:mod:`kilonet.protocols.localize.phase3_termination`), and scores the result against the truth the
robots never saw:

* ``frames``, ``localized_fraction``, ``largest_frame_fraction``: robots grouped by the root
  (election key) their frame grew from; ``rmse_mm`` after the best rigid alignment of each
  frame (reflection allowed), pooled over located robots; ``within_5mm_fraction`` (after that
  one alignment of the whole frame: a long shape's own measurement errors bend it by more);
* the bound and the optimum beside them (:mod:`kilonet.scenarios.reference`, as ``gcs`` reports
  them): ``crlb_rmse_mm`` and ``rmse_over_crlb``, ``crlb_received_rmse_mm`` and
  ``rmse_over_crlb_received``, ``central_rmse_mm``, ``central_localized_fraction``,
  ``largest_frame_over_central``, ``at_optimum_over_central`` (the share of what the solver
  localizes that the largest frame places at the optimum: a folded frame's robots are not)
  and ``off_optimum_robots``, on the distances the robots' neighbour records hold (every
  reception of every message type counts; records marked ambiguous are left out);
* ``phase_times_s``: when the root was elected, when the last robot was located, when the root
  declared done and when the last robot was done (``done_s``: a robot that stays awake after
  DONE for an island, :mod:`kilonet.protocols.localize.phase4_island`, when its island work is over;
  NaN unless every running robot did; ``done_fraction`` is the share of running robots that heard
  DONE or declared it);
  ``hop_diameter`` of the communication graph, and ``done_over_hop_limit``, ``done_s`` over
  ``hop_diameter × robot.tx_period_s`` (the time information needs to cross the swarm);
* ``unplaced_why``: the unplaced running robots counted by why they stayed so
  (:func:`why_unplaced`; ``why_unplaced`` in ``robots.csv``), and ``unplaced_robots``, the
  first 50 of them by index;
* ``misplaced_fixes`` and ``first_misplaced``: the fixes that were wrong given the anchors
  they used (:mod:`kilonet.scenarios.placement_audit`), per rule, and the earliest of them — where a
  folded frame began;
* ``unsendable_messages`` (messages a robot could not pack, sent as nothing) and
  ``out_of_frame_robots`` (robots that refused a position beyond the coordinates messages
  carry, :data:`kilonet.protocols.localize_base.MAX_COORDINATE_MM`, 49 m from the root).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.protocols.localize.base import LocalizeParams
from kilonet.scenarios.base import Drawing, Reporting, RunResult, Scenario, Setup
from kilonet.scenarios.neighbourhood import trusted_links
from kilonet.scenarios.reference import LISTED_ROBOTS

if TYPE_CHECKING:  # the rest is imported where used, so that listing scenarios stays fast
    import pandas as pd

    from kilonet.simulation import Simulation

__all__ = ["SCENARIO", "WHY_UNPLACED", "estimates_frame", "why_unplaced"]


def _program(params: Any, positions: np.ndarray):
    from kilonet.protocols.localize.program import LocalizeRobot

    return lambda _i: LocalizeRobot(params.scenario)


def _stop_when(sim: Simulation) -> bool:
    running = sim.world.running
    return all(r.stage == "done" for i, r in enumerate(sim.robots) if running[i])


#: Why a robot ended unplaced, by the placed neighbours (anchors) it knew at the end: the
#: rule of :mod:`kilonet.protocols.localize_spread` that could not place it.
WHY_UNPLACED = {
    "no_anchor": "no placed neighbour: every rule needs two or more",
    "one_anchor": "one placed neighbour: rules 1-3 need two or more",
    "two_anchors": "two placed neighbours: the mirror ambiguity stayed (rules 3-4)",
    "anchors_rejected": "three or more placed neighbours, rejected by rule 1 (one line, poor "
    "fit, or a mirror image that fits as well)",
}


def why_unplaced(anchors: int, *, island_closed: bool = False) -> str:
    """The reason an unplaced robot with ``anchors`` placed neighbours stayed so (a key of
    :data:`WHY_UNPLACED`), with ``+island_full`` when its island was too large to solve
    (``localize.island_max_reports``).

    Examples
    --------
    >>> why_unplaced(2), why_unplaced(0, island_closed=True), why_unplaced(5)
    ('two_anchors', 'no_anchor+island_full', 'anchors_rejected')
    """
    key = ("no_anchor", "one_anchor", "two_anchors")[anchors] if anchors < 3 else "anchors_rejected"
    return key + ("+island_full" if island_closed else "")


def estimates_frame(sim: Simulation) -> pd.DataFrame:
    """Per robot: its ID, role, hop count, estimate, frame label, the robot that is its
    frame's root (``root_robot``), the estimate aligned to the truth and its error
    (:func:`kilonet.scenarios.estimates.with_alignment`) and its state at the end."""
    import pandas as pd

    from kilonet.scenarios.estimates import with_alignment

    roots = {r.root_key: i for i, r in enumerate(sim.robots) if r.is_root}
    rows = []
    for i, r in enumerate(sim.robots):
        located = r.in_frame
        role = "root" if r.is_root else "axis" if r.uid == r.spread.axis else "robot"
        rows.append(
            {
                "robot": i,
                "uid": r.uid,
                "role": role,
                "hops": r.hops,
                "est_x_mm": r.position[0] if located else math.nan,
                "est_y_mm": r.position[1] if located else math.nan,
                "frame": r.frame_label if located else "",
                "root_robot": roots.get(r.root_key, -1) if located else -1,
                "localized": located,
                "settled": r.termination.settled,
                "done": r.termination.done,
                "neighbours_heard": len(r.neighbours),
                "why_unplaced": ""
                if located or not sim.world.running[i]
                else why_unplaced(
                    sum(n.x_mm is not None for n in r.neighbours.known()),
                    island_closed=r.island.closed,
                ),
            }
        )
    return with_alignment(pd.DataFrame(rows), sim.world.positions_mm)


def _phase_times(sim: Simulation) -> dict[str, float]:
    events = sim.trace.events_frame()
    out: dict[str, float] = {}
    if not len(events):
        return out
    stage = events[events.event == "stage"]
    roots = stage[stage.data.str.contains('"root": true')]
    if len(roots):
        out["elected"] = round(float(roots.t_s.min()), 3)
    located = events[events.event == "located"]
    if len(located):
        out["last_located"] = round(float(located.t_s.max()), 3)
    done = events[events.event == "done"]
    if len(done):
        complete = done[done.data.str.contains('"complete"')]
        if len(complete):
            out["root_done"] = round(float(complete.t_s.min()), 3)
        # A robot that stays awake for an island after DONE is done when its island is.
        finished = events[events.event.isin(["done", "island_done"])]
        out["all_done"] = round(float(finished.t_s.max()), 3)
    return out


def _metrics(sim: Simulation) -> dict[str, Any]:
    from kilonet.scenarios.central import pooled_aligned_rmse
    from kilonet.scenarios.reference import largest_frame_mm, reference_metrics

    truth = sim.world.positions_mm
    n = sim.n_robots
    p = sim.params
    est = estimates_frame(sim)
    running = sim.world.running
    done = est[est.localized]
    codes = {label: k for k, label in enumerate(sorted(done.frame.unique()))}
    labels = np.full(n, -1)
    labels[done.robot.to_numpy()] = [codes[f] for f in done.frame]
    positions = est[["est_x_mm", "est_y_mm"]].to_numpy()
    rmse, aligned = pooled_aligned_rmse(np.nan_to_num(positions), truth, labels)
    error = np.hypot(*(aligned - truth).T)
    sizes = done.groupby("frame").size()
    # The links robots range: both ends' estimates within localize.neighbour_max_mm.
    ranged = trusted_links(sim, p.scenario.neighbour_max_mm).to_undirected(reciprocal=True)
    links = np.array(ranged.edges(), dtype=np.intp).reshape(-1, 2)
    i, j = links[:, 0], links[:, 1]
    out: dict[str, Any] = {
        "mean_neighbours": 2.0 * len(i) / n,
        "frames": len(sizes),
        "localized_fraction": len(done) / n,
        "largest_frame_fraction": float(sizes.max() / n) if len(sizes) else 0.0,
        "within_5mm_fraction": float(np.sum(error <= 5.0) / n),
        # Of the robots still running (a crashed robot is never done).
        "done_fraction": float(est.done[running].sum() / max(1, running.sum())),
        "rmse_mm": rmse,
        "max_error_mm": float(np.nanmax(error)) if len(done) else math.nan,
    }
    out.update(
        reference_metrics(
            sim,
            [r.neighbours for r in sim.robots],
            (i, j),
            rmse_mm=rmse,
            frame_mm=largest_frame_mm(positions, labels),
        )
    )
    hop_diameter = out["hop_diameter"]
    phases = _phase_times(sim)
    out["phase_times_s"] = phases
    # Done when the last robot declared itself done (the run itself stops at the next whole
    # second, when the scenario checks).
    out["done_s"] = phases.get("all_done", math.nan) if out["done_fraction"] == 1 else math.nan
    if hop_diameter:
        out["done_over_hop_limit"] = out["done_s"] / (hop_diameter * p.robot.tx_period_s)
    events = sim.trace.events_frame()
    out["id_redraws"] = int((events.event == "id").sum()) if len(events) else 0
    # Values the protocol could not send: never a crash, always counted.
    # Which robots a run leaves out, and which rule could not place them.
    left = est[est.why_unplaced != ""]
    counts = left.why_unplaced.value_counts().sort_index()
    out["unplaced_why"] = {k: int(v) for k, v in counts.items()}
    out["unplaced_robots"] = [int(i) for i in left.robot[:LISTED_ROBOTS]]
    out.update(_misplacements(events, est, truth, labels))
    out["unsendable_messages"] = int(sum(r.unsendable for r in sim.robots))
    out["out_of_frame_robots"] = (
        int(events.robot[events.event == "out_of_frame"].nunique()) if len(events) else 0
    )
    return out


def _misplacements(
    events: pd.DataFrame, est: pd.DataFrame, truth: np.ndarray, labels: np.ndarray
) -> dict[str, Any]:
    """``misplaced_fixes`` (per rule, the fixes more than
    :data:`~kilonet.scenarios.placement_audit.MISPLACED_MM` from where their references' truth puts
    them) and ``first_misplaced`` (the earliest: robot, rule, anchors, time, error; None if
    none), from :func:`~kilonet.scenarios.placement_audit.placement_errors`."""
    from kilonet.scenarios.placement_audit import MISPLACED_MM, frame_handedness, placement_errors

    positions = est[["est_x_mm", "est_y_mm"]].to_numpy()
    handedness = np.ones(len(truth), dtype=int)
    for label in np.unique(labels[labels >= 0]):
        members = labels == label
        if members.sum() >= 3:
            handedness[members] = frame_handedness(positions[members], truth[members])
    fixes = placement_errors(events, est.uid.to_numpy(), truth, handedness)
    wrong = fixes[fixes.error_mm > MISPLACED_MM]
    first = None
    if len(wrong):
        row = wrong.iloc[0]
        first = {
            "robot": int(row.robot),
            "rule": row.rule,
            "anchors": int(row.anchors),
            "t_s": round(float(row.t_s), 3),
            "error_mm": round(float(row.error_mm), 1),
        }
    counts = wrong.rule.value_counts().sort_index()
    return {"misplaced_fixes": {k: int(v) for k, v in counts.items()}, "first_misplaced": first}


def _outputs(result: RunResult, out_dir: Path) -> None:
    from kilonet.scenarios.figures import frames_figure

    sim, summary = result.sim, result.summary
    est = estimates_frame(sim)
    frames_figure(
        sim.world.positions_mm,
        est,
        est.robot[est.role == "root"].to_numpy(),
        "root",
        f"localize: {summary.get('frames', '?')} frame(s), RMSE "
        f"{_mm(summary.get('rmse_mm'))} mm (CRLB {_mm(summary.get('crlb_rmse_mm'))}, "
        f"central {_mm(summary.get('central_rmse_mm'))})",
        out_dir / "localize.png",
    )


def _mm(value: float | None) -> str:
    """A length for a title: two decimals, or "n/a" when there is none (no robot localized).

    >>> _mm(1.234), _mm(None), _mm(math.nan)
    ('1.23', 'n/a', 'n/a')
    """
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.2f}"


SCENARIO = Scenario(
    name="localize",
    summary="one global frame by root election, multilateration spreading outward and "
    "distributed refinement, ended by the swarm itself",
    setup=Setup(
        program=_program,
        section=LocalizeParams,
        robots=100,
        defaults={
            "duration_s": 600.0,
            "robot.hardware_uids": False,
            "robot.tx_period_s": 0.2,
            "placement.jitter_mm": 2.0,
        },
        supports={"medium.message_format": ("kilolib",), "robot.rx_distance": ("estimate",)},
        stop_when=_stop_when,
    ),
    reporting=Reporting(
        metrics=_metrics,
        robot_columns=estimates_frame,
    ),
    drawing=Drawing(
        figures=_outputs,
    ),
)
