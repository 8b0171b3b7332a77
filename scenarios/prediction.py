"""Predicting the global coordinate system's outcome from the estimates and an election.

Given the distance estimates the robots will hold, the parameters and the seeds phase 2
elected, phases 3–5 are predicted as the robots will decide them: a robot's neighbours are the
robots it hears with an estimate within ``gcs.neighbour_max_mm``; each seed takes the reference
pair its rule would choose from the distances it will hold, and places its references as it
will (:func:`_frame_members`); robots join a seed's frame when they see the seed and at least two
robots already in that frame and the robots' own fix test, with their own estimates as ranges,
accepts those anchors where the seed's frame puts them (repeated until nothing changes, as
localization spreads); merging groups are found as the robots would find them, from the
positions the frames give them (:func:`kilonet.protocols.gcs.phase5_merging_groups.find_groups`).
The frame graph's components (:func:`kilonet.scenarios.topology.failure_cases`) are the global
frames merging can reach.

The estimates are what the robots' tables will hold
(:func:`kilonet.scenarios.neighbourhood.held_estimates_mm`): each link's noise-free estimate,
directed, since the receiver's calibration tables and the sender's emitter set a real Kilobot link's
systematic error (several mm, more toward the tables' saturation) and so differ between the two
directions of a link. The noise on top averages out over the receptions a table entry is the
mean of, but dithers that mean between kilolib's whole-mm steps, and lets links up to 2 mm
beyond ``gcs.neighbour_max_mm`` into the tables, at about the limit. True distances no longer
predict: on the topology sweep's real-Kilobot medium they matched the observed number of final
frames in 30 % of the runs, because a link of true length within the limit may be estimated
beyond it (or the reverse), and because a few millimetres of systematic error decide both which
thin triangle a seed takes as its references and whether a fix passes its mirror test. What is
left unpredicted is mostly which seeds find a merging group (in the runs checked, the
unlocalizable robots matched and isolated seeds differed), presumably because
``gcs.min_group_width_mm`` is then decided on noisy positions in the frames, or phase 4 is not
complete when phase 5 starts.

|BC| reaches the seed as the mean of B's and C's table entries, each B's (C's) held estimate
in whole millimetres (phase 3's TABLE carries ``d:uint8``), the pair accepted only if the two
agree as phase 3 requires (:func:`kilonet.protocols.gcs.phase3_local_frames.reference_candidates`).
That matters for nearly collinear references, which the thesis's largest-angle rule picks once
bodies no longer block the link between two robots on opposite sides of the seed: a few tenths
of a millimetre then decide whether the triangle exists at all, and how wide the seed's frame
makes it (``docs/gcs.md``, "On the robot model").

Used before a run (``kilonet analyze``) and after one (the ``gcs`` scenario reports the
prediction next to what it observed).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import networkx as nx
import numpy as np

from kilonet.params import Params
from kilonet.protocols.common.geometry import (
    GeometryError,
    choose_references_best_conditioned,
    choose_references_max_angle,
    multilaterate,
    place_references,
)
from kilonet.protocols.gcs.base import GcsParams
from kilonet.protocols.gcs.frame_keys import FrameKey
from kilonet.protocols.gcs.phase3_local_frames import reference_candidates
from kilonet.protocols.gcs.phase5_merging_groups import find_groups
from kilonet.scenarios.topology import failure_cases, rigidity_facts

__all__ = ["predict_from_seeds"]


def predict_from_seeds(
    estimates_mm: np.ndarray,
    params: Params,
    seeds: Sequence[int],
    frame_keys: Mapping[int, FrameKey] | None = None,
) -> dict[str, Any]:
    """The failure cases phases 3–6 will meet, predicted from the robots' distance estimates.

    Parameters
    ----------
    estimates_mm : (n, n) array
        ``[sender, receiver]``: the receiver's estimate of its distance to the sender, mm
        (noise-free, :func:`kilonet.scenarios.neighbourhood.held_estimates_mm`); NaN where the
        receiver does not hear the sender, and on the diagonal. Estimates above
        ``gcs.neighbour_max_mm`` are ignored, as the robots ignore them.
    params : Params
        The run's parameters (the ``gcs`` section's neighbourhood, reference rule, fix test and
        thinnest group).
    seeds : sequence of int
        Robot indices elected seeds in phase 2.
    frame_keys : mapping, optional
        Seed index → its frame key (:class:`kilonet.protocols.gcs.frame_keys.FrameKey`). A robot
        located in frames of several components reports the one of the smallest key (the merged
        frame's root, as :mod:`kilonet.protocols.gcs.phase6_merging` ranks elected seeds), an
        isolated seed's only if it has no other; without keys, the largest.

    Returns
    -------
    dict
        ``robots``, ``seeds``, ``located_in`` (robot → seeds whose frames it will be located
        in), the cases of :func:`kilonet.scenarios.topology.failure_cases` (``unlocalizable``,
        ``isolated_seeds``, ``frames``, ``split``) and the rigidity facts of the graph of links
        both ends trust; ``final_frame`` (robot → index into ``frames`` of the merged frame it
        will report, ``None`` if unlocalizable), ``final_frames`` (how many distinct ones
        robots report) and ``boundary`` (robots hearing a neighbour that reports another
        merged frame).
    """
    gcs = params.scenario
    n = len(estimates_mm)
    estimates = np.where(estimates_mm <= gcs.neighbour_max_mm, estimates_mm, np.nan)
    np.fill_diagonal(estimates, np.nan)
    # hears[r]: the robots in r's neighbour table.
    hears = [np.flatnonzero(~np.isnan(estimates[:, r])).tolist() for r in range(n)]
    members: dict[int, dict[int, tuple[float, float]]] = {}
    for s in seeds:
        inside = _frame_members(estimates, hears, s, gcs)
        if inside is not None:
            members[s] = inside
    located = {i: sorted(s for s, m in members.items() if i in m) for i in range(n)}
    groups = _groups(estimates, hears, members, gcs)
    cases = failure_cases(range(n), located, list(seeds), groups)
    final = _final_frames(cases["frames"], located, frame_keys, cases["isolated_seeds"])
    boundary = sorted(
        i
        for i in range(n)
        if final[i] is not None
        and any(final[j] is not None and final[j] != final[i] for j in hears[i])
    )
    mutual = nx.Graph()
    mutual.add_nodes_from(range(n))
    mutual.add_edges_from((s, r) for r in range(n) for s in hears[r] if s < r and r in hears[s])
    return {
        "robots": n,
        "seeds": list(seeds),
        "located_in": located,
        **cases,
        "final_frame": final,
        "final_frames": len({c for c in final.values() if c is not None}),
        "boundary": boundary,
        **rigidity_facts(mutual),
    }


def _frame_members(
    estimates: np.ndarray, hears: Sequence[Sequence[int]], seed: int, gcs: GcsParams
) -> dict[int, tuple[float, float]] | None:
    """The robots seed ``seed``'s frame will hold, with their positions in it, mm: the seed at
    the origin, the references its rule would choose, placed as the seed will place them, and
    every robot that sees the seed and passes the robots' own fix test with the frame's robots
    it hears, repeated until nothing changes (as localization spreads); ``None`` if no reference
    pair is usable.

    ``estimates[sender, receiver]`` (mm, NaN if unheard or ignored) and ``hears[r]`` (the
    robots in r's table) are the robots' own. The seed asks the neighbours in its table that
    hear it, takes its own estimates of them and their tables (their estimates of their
    neighbours in whole millimetres, :mod:`kilonet.protocols.gcs.phase3_local_frames`); a fix
    (:mod:`kilonet.protocols.gcs.phase4_localization`) ranges with the robot's estimates of the seed
    and of the anchors it hears, placed where the seed's frame puts them, so a frame the
    estimates have bent or widened admits the robots it will admit.
    """
    rule = (
        choose_references_max_angle
        if gcs.reference_rule == "max_angle"
        else choose_references_best_conditioned
    )
    asked = [b for b in hears[seed] if seed in hears[b]]
    tables = {b: {c: round(float(estimates[c, b])) for c in hears[b]} for b in asked}
    own = {b: float(estimates[b, seed]) for b in asked}
    candidates = reference_candidates(own, tables, tolerance_mm=4 * gcs.sigma_mm + 1.0)
    try:
        (b, c), _ = rule(candidates)
        placed_b, placed_c = place_references(*candidates[(b, c)])
    except GeometryError:  # no candidate, or every candidate triangle is degenerate
        return None
    inside = {seed: (0.0, 0.0), b: placed_b, c: placed_c}
    seen_by = [r for r in range(len(estimates)) if seed in hears[r]]
    changed = True
    while changed:  # localization spreads among robots that see the seed
        changed = False
        for robot in seen_by:
            anchors = [seed, *(a for a in hears[robot] if a in inside and a != seed)]
            if robot in inside or len(anchors) < 3:
                continue
            # The robot's own test (kilonet.protocols.gcs.phase4_localization): a fix from nearly
            # collinear anchors, or one with a mirror image, is rejected there too.
            fix = multilaterate(
                np.array([inside[a] for a in anchors]),
                estimates[anchors, robot],
                sigma_mm=gcs.sigma_mm,
                max_rmse_mm=gcs.max_rmse_mm,
            )
            if fix.ok:
                inside[robot] = (fix.x_mm, fix.y_mm)
                changed = True
    return inside


def _groups(
    estimates: np.ndarray,
    hears: Sequence[Sequence[int]],
    members: Mapping[int, Mapping[int, tuple[float, float]]],
    gcs: GcsParams,
) -> list[tuple[int, int]]:
    """The merging groups' frame pairs (seed indices), as the robots would find them: from
    their positions in the frames, the robots they hear, and as reach the farthest estimate
    in their table (:mod:`kilonet.protocols.gcs.phase5_merging_groups`)."""
    groups = []
    for i, near in enumerate(hears):
        own = {s: m[i] for s, m in members.items() if i in m}
        if len(own) < 2:
            continue
        announced = {s: dict(members[s]) for s in own}
        reach = max((float(estimates[j, i]) for j in near), default=0.0)
        groups.extend(find_groups(own, announced, set(near), reach, gcs.min_group_width_mm))
    return groups


def _final_frames(
    frames: list[list[int]],
    located: Mapping[int, list[int]],
    frame_keys: Mapping[int, FrameKey] | None,
    isolated: Sequence[int] = (),
) -> dict[int, int | None]:
    """Robot → index into ``frames`` (the frame graph's components) of the merged frame it will
    report: of the components its frames are in, the one whose smallest frame key is smallest
    (the root that wins), or without keys the first (largest); an ``isolated`` seed's frame
    only if it has no other (its root ranks last, :mod:`kilonet.protocols.gcs.phase6_merging`)."""
    component_of = {s: c for c, seeds in enumerate(frames) for s in seeds}
    alone = {component_of[s] for s in isolated}
    if frame_keys is None:
        order = {c: (c in alone, c) for c in range(len(frames))}  # largest first
    else:
        order = {
            c: (c in alone, min(frame_keys[s] for s in seeds)) for c, seeds in enumerate(frames)
        }
    return {
        i: min((component_of[s] for s in located[i]), key=order.__getitem__, default=None)
        for i in located
    }
