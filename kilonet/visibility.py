"""Who can hear whom: range and occlusion between robots on the table.

A Kilobot's infrared transmitter and receiver face the table, and a message reaches its
neighbours as light reflected off the table's surface. A third robot standing between two
others shadows part of that light. :class:`LinkModel` turns true positions into links:

* ``occlusion = "none"``: every pair within ``range_mm`` (centre to centre) is a link;
* ``"block"``: a pair is a link only if no third disc crosses the segment between the centres
  (the thesis: "provided that there are no objects between sender and receiver");
* ``"graded"``: each body that crosses the segment weakens the link: its reach shrinks by
  ``range_factor`` per body (a link over ``d`` mm crossed by ``k`` bodies exists if
  ``d <= range_mm * range_factor**k``) and each body loses ``loss_per_body`` of its receptions
  (``1 - (1 - loss_per_body)**k`` in all).

The default is ``"none"``: in real-robot measurements (25 Kilobots on a 5 cm grid, the ARGoS
project's validation runs) a link through one body at 100 mm succeeds as often as clear links
of that length, and ARGoS dropped its line-of-sight check in 2018 (``docs/model.md``; the
figures: block ``argos-occlusion`` of ``docs/results/model.md``).

A body crosses the segment when its centre lies closer than a body radius to it. The functions
are pure; the medium precomputes the links once for a static swarm and again only when a robot
moves, crashes out of the table or is removed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

if TYPE_CHECKING:
    import networkx as nx

    from kilonet.params import MediumParams

__all__ = ["LinkModel", "Links", "bodies_crossing", "communication_graph", "pairs_in_range"]

_EMPTY = np.empty(0, dtype=np.intp)


def pairs_in_range(
    positions_mm: np.ndarray, range_mm: float, *, present: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unordered pairs of present robots within ``range_mm`` of each other (inclusive).

    Returns ``i, j, d``: index arrays with ``i < j``, sorted lexicographically, and the true
    distances in mm.

    Examples
    --------
    >>> pos = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    >>> i, j, d = pairs_in_range(pos, 60.0)
    >>> list(zip(i.tolist(), j.tolist(), d.tolist()))
    [(0, 1, 40.0), (1, 2, 40.0)]
    """
    from scipy.spatial import cKDTree

    pos = np.asarray(positions_mm, dtype=float)
    idx = np.arange(len(pos)) if present is None else np.flatnonzero(present)
    if len(idx) < 2:
        return _EMPTY, _EMPTY, np.empty(0)
    pairs = cKDTree(pos[idx]).query_pairs(range_mm, output_type="ndarray")
    if len(pairs) == 0:
        return _EMPTY, _EMPTY, np.empty(0)
    i, j = idx[pairs[:, 0]], idx[pairs[:, 1]]
    i, j = np.minimum(i, j), np.maximum(i, j)
    order = np.lexsort((j, i))
    i, j = i[order], j[order]
    return i, j, np.hypot(*(pos[i] - pos[j]).T)


def bodies_crossing(
    positions_mm: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    radius_mm: float,
    *,
    present: np.ndarray | None = None,
) -> np.ndarray:
    """How many third bodies cross each segment between robots ``i[k]`` and ``j[k]``.

    A present robot other than the two crosses the segment when its centre lies closer than
    ``radius_mm`` to it (vectorised over pairs, with a k-d tree to find the candidates).

    Examples
    --------
    >>> pos = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0], [40.0, 30.0]])
    >>> bodies_crossing(pos, np.array([0, 0, 0]), np.array([2, 1, 3]), 16.5).tolist()
    [1, 0, 0]
    """
    from scipy.spatial import cKDTree

    pos = np.asarray(positions_mm, dtype=float)
    counts = np.zeros(len(i), dtype=np.intp)
    idx = np.arange(len(pos)) if present is None else np.flatnonzero(present)
    if len(i) == 0 or len(idx) < 3:
        return counts
    pa, pb = pos[i], pos[j]
    mid = (pa + pb) / 2
    half = np.hypot(*(pb - pa).T) / 2
    # Any crossing body's centre lies within half-length + radius of the midpoint.
    candidates = cKDTree(pos[idx]).query_ball_point(mid, half + radius_mm, return_sorted=False)
    sizes = np.fromiter((len(c) for c in candidates), dtype=np.intp, count=len(candidates))
    pair = np.repeat(np.arange(len(i)), sizes)
    k = idx[np.fromiter((x for c in candidates for x in c), dtype=np.intp, count=sizes.sum())]
    other = (k != i[pair]) & (k != j[pair])
    pair, k = pair[other], k[other]
    seg = pb[pair] - pa[pair]
    rel = pos[k] - pa[pair]
    t = np.clip(np.einsum("ij,ij->i", rel, seg) / np.einsum("ij,ij->i", seg, seg), 0.0, 1.0)
    gap = np.hypot(*(rel - t[:, None] * seg).T)
    return np.bincount(pair[gap < radius_mm], minlength=len(i))


@dataclass(frozen=True)
class Links:
    """The links of a swarm at one moment: unordered pairs and how good each is.

    Attributes
    ----------
    i, j : (E,) int arrays
        The two robots of each link, ``i < j``, sorted.
    distance_mm : (E,) float array
        True centre-to-centre distance.
    bodies : (E,) int array
        Bodies crossing the line of sight.
    loss : (E,) float array
        Share of receptions the occlusion loses on this link (0 without bodies).
    """

    i: np.ndarray
    j: np.ndarray
    distance_mm: np.ndarray
    bodies: np.ndarray
    loss: np.ndarray

    def __len__(self) -> int:
        return len(self.i)


@dataclass(frozen=True)
class LinkModel:
    """Range and occlusion: which robots hear each other, and how well.

    Parameters
    ----------
    range_mm : float
        Reach of an unobstructed link, centre to centre, mm.
    occlusion : {"graded", "block", "none"}
        What a body between sender and receiver does (see the module docstring).
    range_factor : float
        ``graded``: each body crossed scales the reach by this.
    loss_per_body : float
        ``graded``: each body crossed loses this share of receptions.
    radius_mm : float
        Body radius, mm.

    Examples
    --------
    Three robots on a line 40 mm apart, 85 mm range: the middle one sits on the outer pair's
    line of sight.

    >>> pos = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    >>> len(LinkModel(85.0, "block").links(pos)), len(LinkModel(85.0, "none").links(pos))
    (2, 3)
    >>> outer = LinkModel(85.0, "graded", range_factor=0.95, loss_per_body=0.2).links(pos)
    >>> outer.bodies.tolist(), outer.loss.round(2).tolist()
    ([0, 1, 0], [0.0, 0.2, 0.0])
    """

    range_mm: float
    occlusion: Literal["none", "graded", "block"] = "none"
    range_factor: float = 0.9
    loss_per_body: float = 0.1
    radius_mm: float = 16.5

    @classmethod
    def from_params(
        cls, medium: MediumParams, radius_mm: float = 16.5, *, range_mm: float | None = None
    ) -> LinkModel:
        """The link model a run's ``medium`` parameters describe; ``range_mm`` (default
        ``medium.range_mm``) is the farthest a link may reach (the medium passes its
        transceivers' :attr:`~kilonet.radio.Transceivers.max_distance_mm`)."""
        return cls(
            medium.range_mm if range_mm is None else range_mm,
            medium.occlusion,
            medium.occlusion_range_factor,
            medium.occlusion_loss,
            radius_mm,
        )

    def links(self, positions_mm: np.ndarray, present: np.ndarray | None = None) -> Links:
        """The links among the ``present`` robots at ``positions_mm``."""
        i, j, d = pairs_in_range(positions_mm, self.range_mm, present=present)
        if self.occlusion == "none":
            bodies = np.zeros(len(i), dtype=np.intp)
        else:
            bodies = bodies_crossing(positions_mm, i, j, self.radius_mm, present=present)
            if self.occlusion == "block":
                keep = bodies == 0
            else:
                keep = d <= self.range_mm * self.range_factor**bodies
            i, j, d, bodies = i[keep], j[keep], d[keep], bodies[keep]
        loss = (
            1.0 - (1.0 - self.loss_per_body) ** bodies
            if self.occlusion == "graded"
            else np.zeros(len(i))
        )
        return Links(i, j, d, bodies, loss)


def communication_graph(positions_mm: np.ndarray, model: LinkModel) -> nx.Graph:
    """The undirected communication graph of ``model``; edges carry ``distance_mm``, ``bodies``
    and ``loss``.

    Examples
    --------
    >>> g = communication_graph(np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]]),
    ...                         LinkModel(85.0, "block"))
    >>> sorted(g.edges()), g.edges[0, 1]["distance_mm"]
    ([(0, 1), (1, 2)], 40.0)
    """
    import networkx as nx

    links = model.links(positions_mm)
    g = nx.Graph()
    g.add_nodes_from(range(len(positions_mm)))
    g.add_edges_from(
        (a, b, {"distance_mm": d, "bodies": k, "loss": q})
        for a, b, d, k, q in zip(
            links.i.tolist(),
            links.j.tolist(),
            links.distance_mm.tolist(),
            links.bodies.tolist(),
            links.loss.tolist(),
            strict=True,
        )
    )
    return g
