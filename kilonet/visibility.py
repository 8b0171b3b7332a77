"""Who can hear whom: range and line of sight between robots on the table.

Pure functions over true positions; the medium precomputes them once for static swarms and
again only when a robot moves, crashes out of the table or is removed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import networkx as nx
    from scipy.spatial import cKDTree

__all__ = ["communication_graph", "visible_pairs"]


def visible_pairs(
    positions_mm: np.ndarray,
    range_mm: float,
    *,
    radius_mm: float = 16.5,
    line_of_sight: bool = True,
    present: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unordered pairs of robots within range whose line of sight no third disc blocks.

    Parameters
    ----------
    positions_mm : (N, 2) array
        True centres, mm.
    range_mm : float
        Reception range, centre to centre, mm (pairs at exactly this distance are in range).
    radius_mm : float
        Body radius, mm. A robot blocks the pair (i, j) when its centre lies closer than this
        to the segment between i and j.
    line_of_sight : bool
        Whether bodies block at all.
    present : (N,) bool array, optional
        Robots on the table; absent robots neither hear, speak nor block.

    Returns
    -------
    i, j : (E,) int arrays with ``i < j``, sorted lexicographically
    d : (E,) float array, true distance in mm

    Examples
    --------
    Three robots on a line 40 mm apart: the middle one blocks the outer pair.

    >>> pos = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    >>> i, j, d = visible_pairs(pos, 85.0)
    >>> list(zip(i.tolist(), j.tolist()))
    [(0, 1), (1, 2)]
    >>> i, j, d = visible_pairs(pos, 85.0, line_of_sight=False)
    >>> d.tolist()
    [40.0, 80.0, 40.0]
    """
    pos = np.asarray(positions_mm, dtype=float)
    idx = np.arange(len(pos)) if present is None else np.flatnonzero(present)
    if len(idx) < 2:
        empty = np.empty(0, dtype=np.intp)
        return empty, empty, np.empty(0)
    sub = pos[idx]
    from scipy.spatial import cKDTree

    tree = cKDTree(sub)
    pairs = tree.query_pairs(range_mm, output_type="ndarray")
    if len(pairs) == 0:
        empty = np.empty(0, dtype=np.intp)
        return empty, empty, np.empty(0)
    a, b = pairs[:, 0], pairs[:, 1]
    if line_of_sight:
        keep = ~_blocked(sub, a, b, radius_mm, tree)
        a, b = a[keep], b[keep]
    i, j = idx[a], idx[b]
    i, j = np.minimum(i, j), np.maximum(i, j)
    order = np.lexsort((j, i))
    i, j = i[order], j[order]
    d = np.hypot(*(pos[i] - pos[j]).T)
    return i, j, d


def _blocked(
    pos: np.ndarray, a: np.ndarray, b: np.ndarray, radius_mm: float, tree: cKDTree
) -> np.ndarray:
    """Whether some third disc crosses each segment a–b (vectorised over pairs)."""
    pa, pb = pos[a], pos[b]
    mid = (pa + pb) / 2
    half = np.hypot(*(pb - pa).T) / 2
    # Any blocker's centre lies within half-length + radius of the midpoint.
    candidates = tree.query_ball_point(mid, half + radius_mm, return_sorted=False)
    counts = np.fromiter((len(c) for c in candidates), dtype=np.intp, count=len(candidates))
    pair = np.repeat(np.arange(len(a)), counts)
    k = np.fromiter((x for c in candidates for x in c), dtype=np.intp, count=int(counts.sum()))
    other = (k != a[pair]) & (k != b[pair])
    pair, k = pair[other], k[other]
    seg = pb[pair] - pa[pair]
    rel = pos[k] - pa[pair]
    t = np.clip(np.einsum("ij,ij->i", rel, seg) / np.einsum("ij,ij->i", seg, seg), 0.0, 1.0)
    gap = np.hypot(*(rel - t[:, None] * seg).T)
    blocked = np.zeros(len(a), dtype=bool)
    blocked[pair[gap < radius_mm]] = True
    return blocked


def communication_graph(
    positions_mm: np.ndarray,
    range_mm: float,
    *,
    radius_mm: float = 16.5,
    line_of_sight: bool = True,
) -> nx.Graph:
    """The undirected line-of-sight communication graph; edges carry ``distance_mm``.

    Examples
    --------
    >>> g = communication_graph(np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]]), 85.0)
    >>> sorted(g.edges()), g.edges[0, 1]["distance_mm"]
    ([(0, 1), (1, 2)], 40.0)
    """
    i, j, d = visible_pairs(
        positions_mm, range_mm, radius_mm=radius_mm, line_of_sight=line_of_sight
    )
    import networkx as nx

    g = nx.Graph()
    g.add_nodes_from(range(len(positions_mm)))
    g.add_weighted_edges_from(
        zip(i.tolist(), j.tolist(), d.tolist(), strict=True), weight="distance_mm"
    )
    return g
