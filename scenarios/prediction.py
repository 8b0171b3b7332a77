"""Predicting the global coordinate system's outcome from the geometry and an election.

Given true positions, the parameters and the seeds phase 2 elected, phases 3–5 are predicted
from the geometry alone: each seed takes the reference pair its rule would choose from the
distances it will hold, and places its references as it will (:func:`_frame_members`); robots
join a seed's frame when they see the seed and at least two robots already in that frame and
the robots' own fix test accepts those anchors where the seed's frame puts them (repeated until
nothing changes, as localization spreads); merging groups are found as the robots would find
them (:func:`protocols.gcs.phase5_merging_groups.find_groups`). The frame graph's components
(:func:`scenarios.topology.failure_cases`) are the global frames merging can reach.

The distances a seed holds are true ones but for |BC|, which reaches it in whole millimetres
(phase 3's TABLE carries ``d:uint8``). That matters for nearly collinear references, which the
thesis's largest-angle rule picks once bodies no longer block the link between two robots on
opposite sides of the seed: a few tenths of a millimetre then decide whether the triangle
exists at all, and how wide the seed's frame makes it (``docs/gcs.md``, "On the robot model").

Used before a run (``kilonet analyze``) and after one (the ``gcs`` scenario reports the
prediction next to what it observed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import networkx as nx
import numpy as np

from kilonet.geometry import (
    GeometryError,
    choose_references_best_conditioned,
    choose_references_max_angle,
    multilaterate,
    place_references,
)
from kilonet.params import Params
from kilonet.visibility import LinkModel, communication_graph
from protocols.gcs.base import GcsParams
from protocols.gcs.frame_keys import FrameKey
from protocols.gcs.phase5_merging_groups import find_groups
from scenarios.topology import failure_cases, rigidity_facts

__all__ = ["predict_from_seeds"]


def predict_from_seeds(
    pos: np.ndarray,
    params: Params,
    seeds: Sequence[int],
    frame_keys: Mapping[int, FrameKey] | None = None,
) -> dict[str, Any]:
    """The failure cases phases 3–6 will meet, predicted from geometry.

    Parameters
    ----------
    pos : (n, 2) array
        True positions, mm.
    params : Params
        The run's parameters (range, line of sight, the ``gcs`` section's reference rule and
        thinnest group).
    seeds : sequence of int
        Robot indices elected seeds in phase 2.
    frame_keys : mapping, optional
        Seed index → its frame key (:class:`protocols.gcs.frame_keys.FrameKey`). A robot located in
        frames of several components reports the one of the smallest key (the merged frame's
        root, as :mod:`protocols.gcs.phase6_merging` ranks elected seeds), an isolated seed's only
        if it has no other; without keys, the largest.

    Returns
    -------
    dict
        ``robots``, ``seeds``, ``located_in`` (robot → seeds whose frames it will be located
        in), the cases of :func:`scenarios.topology.failure_cases` (``unlocalizable``,
        ``isolated_seeds``, ``frames``, ``split``) and the rigidity facts of the communication
        graph; ``final_frame`` (robot → index into ``frames`` of the merged frame it will
        report, ``None`` if unlocalizable), ``final_frames`` (how many distinct ones robots
        report) and ``boundary`` (robots with a neighbour reporting another merged frame).
    """
    p = params
    n = len(pos)
    from scenarios.neighbourhood import neighbourhood_mm

    # The protocol's neighbours: the robots it hears, within gcs.neighbour_max_mm.
    reach_mm = neighbourhood_mm(p.medium, p.scenario.neighbour_max_mm)
    graph = communication_graph(pos, LinkModel.from_params(p.medium, range_mm=reach_mm))
    members: dict[int, dict[int, tuple[float, float]]] = {}
    for s in seeds:
        inside = _frame_members(pos, graph, s, p.scenario)
        if inside is not None:
            members[s] = inside
    located = {i: sorted(s for s, m in members.items() if i in m) for i in range(n)}
    groups = _groups(pos, graph, located, members, reach_mm, p.scenario)
    cases = failure_cases(range(n), located, list(seeds), groups)
    final = _final_frames(cases["frames"], located, frame_keys, cases["isolated_seeds"])
    boundary = sorted(
        i
        for i in range(n)
        if final[i] is not None
        and any(final[j] is not None and final[j] != final[i] for j in graph[i])
    )
    return {
        "robots": n,
        "seeds": list(seeds),
        "located_in": located,
        **cases,
        "final_frame": final,
        "final_frames": len({c for c in final.values() if c is not None}),
        "boundary": boundary,
        **rigidity_facts(graph),
    }


def _frame_members(
    pos: np.ndarray, graph: nx.Graph, seed: int, gcs: GcsParams
) -> dict[int, tuple[float, float]] | None:
    """The robots seed ``seed``'s frame will hold, with their positions in it, mm: the seed at
    the origin, the references its rule would choose, placed as the seed will place them, and
    every robot that sees the seed and passes the robots' own fix test with the frame's robots
    it sees, repeated until nothing changes (as localization spreads); ``None`` if no reference
    pair is usable.

    The seed's distances to its neighbours are true; |BC| is rounded to whole millimetres, as
    the neighbours' tables carry it (:mod:`protocols.gcs.phase3_local_frames`). A fix uses true
    ranges and the anchors' positions in the frame, so a frame the rounding has bent or widened
    admits the robots it will admit.
    """
    rule = (
        choose_references_max_angle
        if gcs.reference_rule == "max_angle"
        else choose_references_best_conditioned
    )
    near = sorted(graph[seed])
    candidates = {
        (b, c): (
            math.dist(pos[seed], pos[b]),
            math.dist(pos[seed], pos[c]),
            float(round(math.dist(pos[b], pos[c]))),
        )
        for k, b in enumerate(near)
        for c in near[k + 1 :]
        if graph.has_edge(b, c)
    }
    try:
        (b, c), _ = rule(candidates)
    except GeometryError:
        return None
    placed_b, placed_c = place_references(*candidates[(b, c)])
    inside = {seed: (0.0, 0.0), b: placed_b, c: placed_c}
    changed = True
    while changed:  # localization spreads among robots that see the seed
        changed = False
        for robot in near:
            anchors = sorted(set(inside) & set(graph[robot]))
            if robot in inside or len(anchors) < 3:
                continue
            # The robot's own test (protocols.gcs.phase4_localization): a fix from nearly collinear
            # anchors, or one with a mirror image, is rejected there too.
            fix = multilaterate(
                np.array([inside[a] for a in anchors]),
                np.linalg.norm(pos[anchors] - pos[robot], axis=1),
                sigma_mm=gcs.sigma_mm,
                max_rmse_mm=gcs.max_rmse_mm,
            )
            if fix.ok:
                inside[robot] = (fix.x_mm, fix.y_mm)
                changed = True
    return inside


def _groups(
    pos: np.ndarray,
    graph: nx.Graph,
    located: Mapping[int, list[int]],
    members: Mapping[int, Mapping[int, tuple[float, float]]],
    reach_mm: float,
    gcs: GcsParams,
) -> list[tuple[int, int]]:
    """The merging groups' frame pairs (seed indices), as the robots would find them."""
    groups = []
    for i in range(len(pos)):
        own = {s: tuple(pos[i]) for s in located[i]}
        announced = {s: {j: tuple(pos[j]) for j in members[s]} for s in located[i]}
        groups.extend(find_groups(own, announced, set(graph[i]), reach_mm, gcs.min_group_width_mm))
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
    only if it has no other (its root ranks last, :mod:`protocols.gcs.phase6_merging`)."""
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
