"""Topology analyses of the global coordinate system's failure cases (thesis §7), as graphs.

Plain functions on networkx graphs and plain mappings, so they serve a finished run (what the
robots built) as well as a prediction (what a placement and an election allow):

* :func:`frame_graph` — frames as nodes, merging groups as edges; its connected components
  are the global frames that merging can produce.
* :func:`failure_cases` — the thesis's three cases: robots located in no frame, seeds that can
  join no merging group, and several "global" frames.
* :func:`rigidity_facts` — facts of the communication graph that explain them: articulation
  points, bridges, and robots with fewer than three neighbours.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping
from typing import Any

import networkx as nx

__all__ = ["failure_cases", "frame_graph", "rigidity_facts"]


def frame_graph(
    frames: Iterable[Hashable], groups: Iterable[tuple[Hashable, Hashable]]
) -> nx.Graph:
    """Frames as nodes, one edge per pair of frames that share a merging group.

    Parameters
    ----------
    frames : iterable
        Every frame (e.g. its seed), including frames no group joins.
    groups : iterable of (frame, frame)
        The pair of frames of each merging group (repeats are fine).

    Examples
    --------
    >>> g = frame_graph(["A", "B", "C", "D"], [("A", "B"), ("B", "A"), ("C", "D")])
    >>> sorted(sorted(c) for c in nx.connected_components(g))
    [['A', 'B'], ['C', 'D']]
    """
    graph = nx.Graph()
    graph.add_nodes_from(frames)
    graph.add_edges_from((a, b) for a, b in groups if a != b)
    return graph


def failure_cases(
    robots: Iterable[Hashable],
    located_in: Mapping[Hashable, Iterable[Hashable]],
    seeds: Iterable[Hashable],
    groups: Iterable[tuple[Hashable, Hashable]],
) -> dict[str, Any]:
    """The thesis's three failure cases for one swarm.

    Parameters
    ----------
    robots : iterable
        Every robot.
    located_in : mapping
        Robot → the frames (seeds) it is located in; missing robots are located nowhere.
    seeds : iterable
        The seeds (each names its own frame).
    groups : iterable of (frame, frame)
        The frame pairs of the merging groups.

    Returns
    -------
    dict
        ``unlocalizable`` (robots in no frame), ``isolated_seeds`` (seeds in no merging group),
        ``frames`` (the components of the frame graph, largest first, each sorted) and
        ``split`` (whether there is more than one).

    Examples
    --------
    >>> cases = failure_cases(
    ...     robots=[1, 2, 3, 4, 5],
    ...     located_in={1: ["A"], 2: ["A", "B"], 3: ["B"], 4: ["C"]},
    ...     seeds=["A", "B", "C"],
    ...     groups=[("A", "B")],
    ... )
    >>> cases["unlocalizable"], cases["isolated_seeds"], cases["frames"], cases["split"]
    ([5], ['C'], [['A', 'B'], ['C']], True)
    """
    seeds = list(seeds)
    graph = frame_graph(seeds, groups)
    components = sorted(
        (sorted(c, key=str) for c in nx.connected_components(graph)), key=lambda c: -len(c)
    )
    return {
        "unlocalizable": sorted(r for r in robots if not list(located_in.get(r, ()))),
        "isolated_seeds": sorted((s for s in seeds if graph.degree(s) == 0), key=str),
        "frames": components,
        "split": len(components) > 1,
    }


def rigidity_facts(graph: nx.Graph) -> dict[str, list]:
    """Facts of a communication graph that explain failures.

    Returns ``articulation_points`` (robots whose loss disconnects the swarm), ``bridges``
    (links whose loss does) and ``low_degree`` (robots with fewer than three neighbours: they
    cannot be trilaterated from neighbours alone).

    Examples
    --------
    >>> g = nx.path_graph(4)
    >>> rigidity_facts(g)
    {'articulation_points': [1, 2], 'bridges': [(0, 1), (1, 2), (2, 3)], 'low_degree': [0, 1, 2, 3]}
    """
    return {
        "articulation_points": sorted(nx.articulation_points(graph)),
        "bridges": sorted(tuple(sorted(e)) for e in nx.bridges(graph)),
        "low_degree": sorted(n for n, d in graph.degree() if d < 3),
    }
