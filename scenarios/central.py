"""The centralized reference: every robot's position from all measured distances at once.

What a distributed localization is measured against. Given the distances the robots measured
(any number of measurements per pair, e.g. one mean per ordered pair of robots), the
maximum-likelihood positions under independent Gaussian range noise minimise the weighted
sum of squared range residuals ``Σ wₑ (|pᵢ − pⱼ| − dₑ)²``. :func:`solve_positions` finds them
with :func:`scipy.optimize.least_squares` (trust region reflective, sparse Jacobian, LSMR
steps), one connected component at a time, from two starts — small patches of a few hops,
each solved alone and stitched together (:func:`_patch_start`), and classical multidimensional
scaling of the shortest-path distances through the measured graph — keeping the fit of lower
cost. MDS alone bends non-convex and long shapes (a C's shortest paths run round its inside),
and least squares from a bent start stops in a local minimum. Distances fix positions only up to a
rigid motion and a reflection; :func:`central_reference` removes that freedom by aligning each
component to the truth (Procrustes) and reports the error, so the result is directly
comparable with a swarm's own estimates.

Pure functions on millimetres; no simulation, scenario or protocol knowledge.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from kilonet.protocols.common.alignment import procrustes_rmse, rigid_fit

__all__ = [
    "BASIN_EXCESS",
    "WITHIN_MM",
    "CentralResult",
    "OptimumComparison",
    "central_reference",
    "compare_with_optimum",
    "neighbourhood_errors",
    "optimum_agreement_mm",
    "pooled_aligned_rmse",
    "solve_positions",
]

#: Components with fewer robots are left unsolved: two robots and a distance fix no frame.
MIN_COMPONENT = 3

#: A position counts as right within this, mm: the solver's among its neighbours
#: (:func:`central_reference`), a swarm's against the optimum (:func:`optimum_agreement_mm`).
#: Above the few millimetres of a right position's relative error (one link's error on
#: kilolib's ranging is 1-3.5 mm), below a mirror image's offset (twice a robot's height above
#: its neighbours' line: 20 mm or more for any triangle the protocols accept).
WITHIN_MM = 5.0

#: A frame lies in the optimum's basin when least squares from its estimates ends at a cost
#: at most this many noise units above the optimum's (:func:`compare_with_optimum`): the
#: 95 % point of χ² with one degree of freedom, the likelihood-ratio test that the two
#: configurations fit the measurements equally well. A fold puts a robot tens of
#: millimetres off on each link it flipped, hundreds of units; two minima of a flat valley
#: differ by a fraction of one.
BASIN_EXCESS = 3.84

#: The least noise variance per unit weight a noise unit assumes, mm²: one whole-millimetre
#: reading's rounding (1/12 mm²). Without it, exact measurements (a fit of zero cost) would
#: make any rounding of the optimiser's last digits infinitely many noise units.
NOISE_FLOOR_MM2 = 1.0 / 12.0

#: A start of the caller's replaces the solver's own fit only when its cost is lower by
#: more than this fraction: least squares ending in the same minimum from two starts agrees
#: to about this many digits, and the solver's own answer should not change with its last.
_SAME_COST = 1e-6


def solve_positions(
    n: int,
    pairs: np.ndarray,
    distances_mm: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    starts: Sequence[np.ndarray] = (),
) -> np.ndarray:
    """Weighted least-squares positions of ``n`` robots from measured distances.

    Parameters
    ----------
    n : int
        Number of robots (row indices ``0 .. n-1``).
    pairs : (E, 2) int array
        The robots of each measurement; a pair may appear several times (e.g. once per
        direction) and its measurements then all count.
    distances_mm : (E,) array
        Measured distances, mm (positive).
    weights : (E,) array, optional
        Weight of each measurement (e.g. the number of receptions a mean distance averages:
        its inverse variance up to a constant); default 1 each.
    starts : sequence of (n, 2) arrays, optional
        More starts for least squares (e.g. a swarm's own estimates, in any frame; NaN where
        a robot has none), tried per component beside the solver's two when they hold at
        least three of its robots off one line; the robots a start lacks start where the
        MDS start, moved onto it, puts them. The fit of lowest cost is kept (the solver's
        own on a tie within ``_SAME_COST``). Along a long corridor the optimum lies in a
        valley so flat that least squares stops wherever it starts: a start nearer its floor
        reaches a lower cost.

    Returns
    -------
    (n, 2) array
        Positions in mm, each connected component of the measurement graph in a frame of its
        own (arbitrary rotation, shift and reflection); NaN for robots in components of fewer
        than three robots.

    Raises
    ------
    ValueError
        If shapes disagree, an index is out of range or a self-loop, a distance is not
        positive and finite, a weight is negative or not finite, or a start is not (n, 2).

    Notes
    -----
    Per component of m robots: the start is classical MDS of the m × m shortest-path matrix
    (O(m² log m) time, O(m²) memory); the refinement costs a few sparse LSMR solves over the
    measurements. A few seconds for 1,000 robots.

    Examples
    --------
    A unit square with both diagonals, measured exactly, is recovered exactly:

    >>> square = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0]])
    >>> pairs = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)])
    >>> d = np.hypot(*(square[pairs[:, 0]] - square[pairs[:, 1]]).T)
    >>> p = solve_positions(4, pairs, d)
    >>> round(procrustes_rmse(p, square)[0], 6)
    0.0
    """
    pairs, dist, w = _checked(n, pairs, distances_mm, weights)
    extra = [np.asarray(s, dtype=float) for s in starts]
    for start in extra:
        if start.shape != (n, 2):
            raise ValueError(f"a start must be ({n}, 2); got shape {start.shape}")
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    out = np.full((n, 2), np.nan)
    if len(pairs) == 0:
        return out
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    count, labels = connected_components(graph, directed=False)
    for label in range(count):
        members = np.flatnonzero(labels == label)
        if len(members) < MIN_COMPONENT:
            continue
        local = np.full(n, -1)
        local[members] = np.arange(len(members))
        keep = labels[pairs[:, 0]] == label
        sub = local[pairs[keep]]
        out[members] = _solve_component(
            len(members), sub, dist[keep], w[keep], [start[members] for start in extra]
        )
    return out


def _checked(n, pairs, distances_mm, weights):
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    dist = np.asarray(distances_mm, dtype=float).reshape(-1)
    w = np.ones(len(dist)) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    if len(dist) != len(pairs) or len(w) != len(pairs):
        raise ValueError(
            f"pairs ({len(pairs)}), distances_mm ({len(dist)}) and weights ({len(w)}) must "
            "have one entry per measurement"
        )
    if len(pairs) and (pairs.min() < 0 or pairs.max() >= n):
        raise ValueError(f"pair index out of range 0..{n - 1}: {pairs.min()}..{pairs.max()}")
    loops = pairs[:, 0] == pairs[:, 1]
    if loops.any():
        raise ValueError(f"self-loop in pairs at robot {int(pairs[loops, 0][0])}")
    if not (np.isfinite(dist).all() and (dist > 0).all()):
        raise ValueError("distances_mm must be positive and finite")
    if not (np.isfinite(w).all() and (w >= 0).all()):
        raise ValueError("weights must be non-negative and finite")
    return pairs, dist, w


def _solve_component(
    m: int, pairs: np.ndarray, dist: np.ndarray, w: np.ndarray, extra: list[np.ndarray]
) -> np.ndarray:
    """Positions (m, 2) of one connected component: least squares from two starts (stitched
    patches, MDS of shortest paths), the lower cost kept, then from each of ``extra`` (m, 2),
    kept only if lower by more than ``_SAME_COST``."""
    mds = _mds_start(m, pairs, dist)
    fits = [_least_squares(m, pairs, dist, w, mds)]
    stitched = _patch_start(m, pairs, dist, w)
    placed = np.isfinite(stitched[:, 0])
    if placed.sum() >= MIN_COMPONENT:
        # Robots no patch reached: the MDS start, moved onto the stitched ones.
        stitched[~placed] = _rigid_onto(mds, stitched, placed)[~placed]
        fits.append(_least_squares(m, pairs, dist, w, stitched))
    # The lower cost is the better optimum: the choice uses the measurements alone.
    best = min(fits, key=lambda f: f.cost)
    for start in extra:
        held = np.isfinite(start).all(axis=1)
        if held.sum() < MIN_COMPONENT or not _wide(start[held]):
            continue
        filled = start.copy()
        filled[~held] = _rigid_onto(mds, start, held)[~held]
        fit = _least_squares(m, pairs, dist, w, filled)
        if fit.cost < best.cost * (1.0 - _SAME_COST):
            best = fit
    return best.x.reshape(m, 2)


def _least_squares(m: int, pairs: np.ndarray, dist: np.ndarray, w: np.ndarray, start):
    """:func:`scipy.optimize.least_squares` of the weighted range residuals from ``start``
    (m, 2); returns scipy's result (``x``, ``cost``)."""
    from scipy.optimize import least_squares
    from scipy.sparse import csr_matrix

    i, j = pairs[:, 0], pairs[:, 1]
    sw = np.sqrt(w)
    e = len(pairs)
    rows = np.repeat(np.arange(e), 4)
    cols = np.stack([2 * i, 2 * i + 1, 2 * j, 2 * j + 1], axis=1).ravel()

    def residuals(x):
        p = x.reshape(m, 2)
        diff = p[i] - p[j]
        return sw * (np.sqrt((diff * diff).sum(axis=1)) - dist)

    def jacobian(x):
        p = x.reshape(m, 2)
        diff = p[i] - p[j]
        norm = np.maximum(np.sqrt((diff * diff).sum(axis=1)), 1e-9)
        u = diff * (sw / norm)[:, None]
        vals = np.stack([u[:, 0], u[:, 1], -u[:, 0], -u[:, 1]], axis=1).ravel()
        return csr_matrix((vals, (rows, cols)), shape=(e, 2 * m))

    return least_squares(
        residuals,
        np.asarray(start, dtype=float).ravel(),
        jac=jacobian,
        method="trf",
        tr_solver="lsmr",
        x_scale=float(np.median(dist)),
        xtol=1e-10,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=200,
    )


#: Hops from its centre a patch of the stitched start reaches, and its largest size.
_PATCH_HOPS = 2
_PATCH_ROBOTS = 30
#: Robots a patch shares with the stitched ones must lie at least this far off one line, mm.
_STITCH_MIN_WIDTH_MM = 10.0


def _patch_start(m: int, pairs: np.ndarray, dist: np.ndarray, w: np.ndarray) -> np.ndarray:
    """A start stitched from small patches, (m, 2) with NaN where no patch reached.

    Each patch is the robots within ``_PATCH_HOPS`` hops of a centre, at most
    ``_PATCH_ROBOTS`` (centres picked best-connected first, each outside the previous centres'
    one-hop neighbourhoods), solved
    on its own (MDS of its shortest paths, then least squares): so small a patch is nearly
    convex, and its shortest paths nearly straight. Patches are then joined one by one, the
    one sharing most robots with those placed first, by the rigid motion (reflection
    allowed) of the shared robots (at least three, not on one line). Shortest paths through a
    whole C shape or a zig-zagging corridor are longer than the straight distances, and MDS of
    them bends the shape; the patches never see more than a few hops.
    """
    from scipy.sparse import coo_matrix

    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m)).tocsr()
    graph = (graph + graph.T).tocsr()
    degree = np.diff(graph.indptr)
    covered = np.zeros(m, dtype=bool)
    patches: list[tuple[np.ndarray, np.ndarray]] = []
    for c in np.argsort(-degree, kind="stable"):
        if covered[c]:
            continue
        nbrs = graph.indices[graph.indptr[c] : graph.indptr[c + 1]]
        covered[c] = True
        covered[nbrs] = True
        members = _within_hops(graph, int(c), _PATCH_HOPS)
        if len(members) < MIN_COMPONENT:
            continue
        local = np.full(m, -1)
        local[members] = np.arange(len(members))
        keep = (local[pairs[:, 0]] >= 0) & (local[pairs[:, 1]] >= 0)
        sub = local[pairs[keep]]
        solved = _patch_fit(len(members), sub, dist[keep], w[keep])
        patches.append((members, solved))
    out = np.full((m, 2), np.nan)
    if not patches:
        return out
    first, xy = max(patches, key=lambda p: len(p[0]))
    out[first] = xy
    todo = [p for p in patches if p[0] is not first]
    while todo:
        best, best_shared = None, 0
        for k, (members, _) in enumerate(todo):
            shared = int(np.isfinite(out[members, 0]).sum())
            if shared > best_shared:
                best, best_shared = k, shared
        if best is None or best_shared < MIN_COMPONENT:
            break
        members, xy = todo.pop(best)
        shared = np.isfinite(out[members, 0])
        if shared.all():
            continue
        if not _wide(out[members[shared]]):
            continue
        moved = _rigid_onto(xy, out[members], shared)
        out[members[~shared]] = moved[~shared]
    return out


def _patch_fit(k: int, pairs: np.ndarray, dist: np.ndarray, w: np.ndarray) -> np.ndarray:
    """One patch's positions (k, 2): MDS of its shortest paths, then least squares —
    Levenberg–Marquardt on a dense Jacobian (a patch is a few dozen robots; the sparse solver's
    overhead would dominate), or the sparse one when the patch has fewer measurements than
    coordinates."""
    from scipy.optimize import least_squares

    start = _mds_start(k, pairs, dist)
    e = len(pairs)
    if e < 2 * k:
        return _least_squares(k, pairs, dist, w, start).x.reshape(k, 2)
    a, b = pairs[:, 0], pairs[:, 1]
    sw = np.sqrt(w)
    rows = np.arange(e)

    def residuals(x):
        diff = x.reshape(k, 2)[a] - x.reshape(k, 2)[b]
        return sw * (np.sqrt((diff * diff).sum(axis=1)) - dist)

    def jacobian(x):
        diff = x.reshape(k, 2)[a] - x.reshape(k, 2)[b]
        u = diff * (sw / np.maximum(np.sqrt((diff * diff).sum(axis=1)), 1e-9))[:, None]
        jac = np.zeros((e, 2 * k))
        jac[rows, 2 * a], jac[rows, 2 * a + 1] = u[:, 0], u[:, 1]
        jac[rows, 2 * b], jac[rows, 2 * b + 1] = -u[:, 0], -u[:, 1]
        return jac

    # A start, not the answer: the whole component's least squares follows.
    fit = least_squares(
        residuals, start.ravel(), jac=jacobian, method="lm", xtol=1e-6, ftol=1e-8, max_nfev=50
    )
    return fit.x.reshape(k, 2)


def _within_hops(graph, centre: int, hops: int) -> np.ndarray:
    """A patch: ``centre``, its neighbours, and the robots up to ``hops`` hops away while the
    patch stays within ``_PATCH_ROBOTS`` (of a farther ring, those with the most links into
    the patch first, ties by index), in the CSR ``graph``."""
    indptr, indices = graph.indptr, graph.indices
    members = [centre, *indices[indptr[centre] : indptr[centre + 1]].tolist()]
    seen = set(members)
    frontier = members[1:]
    for _ in range(hops - 1):
        links: dict[int, int] = {}
        for u in frontier:
            for v in indices[indptr[u] : indptr[u + 1]].tolist():
                if v not in seen:
                    links[v] = links.get(v, 0) + 1
        room = _PATCH_ROBOTS - len(members)
        if room <= 0 or not links:
            break
        ring = sorted(links, key=lambda v: (-links[v], v))[:room]
        members += ring
        seen.update(ring)
        frontier = ring
    return np.array(members, dtype=np.intp)


def _wide(points: np.ndarray) -> bool:
    """Whether ``points`` (k, 2) lie at least ``_STITCH_MIN_WIDTH_MM`` off their best line."""
    if len(points) < MIN_COMPONENT:
        return False
    spread = points - points.mean(axis=0)
    normal = np.linalg.svd(spread, full_matrices=False)[2][-1]
    return bool(np.abs(spread @ normal).max() >= _STITCH_MIN_WIDTH_MM)


def _rigid_onto(source: np.ndarray, target: np.ndarray, common: np.ndarray) -> np.ndarray:
    """``source`` moved by the rigid motion (reflection allowed) that best maps its
    ``common`` rows onto ``target``'s (:func:`~kilonet.protocols.common.alignment.rigid_fit`)."""
    q, shift = rigid_fit(source[common], target[common])
    return source @ q.T + shift


def _mds_start(m: int, pairs: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Classical MDS of the shortest-path distances through the measured pairs, (m, 2)."""
    from scipy.linalg import eigh
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import shortest_path

    # Several measurements of one pair: the shortest path takes the smallest; use their mean.
    a, b = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    key = a * m + b
    unique, inverse = np.unique(key, return_inverse=True)
    mean = np.bincount(inverse, weights=dist) / np.bincount(inverse)
    graph = coo_matrix((mean, (unique // m, unique % m)), shape=(m, m)).tocsr()
    sp = shortest_path(graph, method="D", directed=False)
    sq = sp * sp
    centred = sq - sq.mean(axis=0) - sq.mean(axis=1)[:, None] + sq.mean()
    values, vectors = eigh(-0.5 * centred, subset_by_index=[m - 2, m - 1])
    return vectors * np.sqrt(np.maximum(values, 0.0))


@dataclass(frozen=True)
class CentralResult:
    """The centralized reference of one run.

    Attributes
    ----------
    rmse_mm : float
        RMS position error after aligning each solved component to the truth, pooled over
        every robot in a solved component, mm (NaN if none was solved).
    localized_fraction : float
        Share of all robots the solver places right among their neighbours: within
        ``within_mm`` of where their neighbours' truth puts them (``local_error_mm``).
    localized : (n,) bool array
        Which robots those are.
    aligned_mm : (n, 2) array
        The solved positions after alignment, mm (NaN where unsolved).
    local_error_mm : (n,) array
        :func:`neighbourhood_errors` of the aligned positions, mm (NaN where unsolved or
        with fewer than two solved neighbours).
    """

    rmse_mm: float
    localized_fraction: float
    localized: np.ndarray
    aligned_mm: np.ndarray
    local_error_mm: np.ndarray


def central_reference(
    truth_mm: np.ndarray,
    pairs: np.ndarray,
    distances_mm: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    within_mm: float = WITHIN_MM,
    starts: Sequence[np.ndarray] = (),
) -> CentralResult:
    """Solve the positions from the measured distances and score them against the truth.

    A robot counts as localized when the solver places it right among its neighbours
    (:func:`neighbourhood_errors` at most ``within_mm``), not when it lies near the truth after
    one alignment of the whole swarm: on a long or bent shape the measurements' own errors
    bend the optimum itself by more than any local test (on a corridor the Cramér–Rao bound
    itself grows to the order of the RMSE), and the whole-swarm test would then call robots
    unlocalized that the solver placed exactly where the measurements put them.

    Parameters
    ----------
    truth_mm : (n, 2) array
        True positions, mm (only used to align and score, never to solve).
    pairs, distances_mm, weights
        The measurements, as in :func:`solve_positions`.
    within_mm : float
        A robot counts as localized when its local error is at most this, mm.
    starts : sequence of (n, 2) arrays, optional
        More starts for the solver (:func:`solve_positions`), chosen between by cost alone.

    Returns
    -------
    CentralResult

    Raises
    ------
    ValueError
        As :func:`solve_positions`, or if ``truth_mm`` is not (n, 2) and finite.

    Examples
    --------
    A square with both diagonals measured exactly, and a fifth robot that measured nothing:

    >>> pos = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0], [300.0, 0.0]])
    >>> pairs = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)])
    >>> d = np.hypot(*(pos[pairs[:, 0]] - pos[pairs[:, 1]]).T)
    >>> ref = central_reference(pos, pairs, d)
    >>> round(ref.rmse_mm, 6), ref.localized_fraction, ref.localized.tolist()
    (0.0, 0.8, [True, True, True, True, False])
    """
    truth = np.asarray(truth_mm, dtype=float)
    if truth.ndim != 2 or truth.shape[1] != 2 or not np.isfinite(truth).all():
        raise ValueError(f"truth_mm must be a finite (n, 2) array; got shape {truth.shape}")
    n = len(truth)
    solved = solve_positions(n, pairs, distances_mm, weights, starts=starts)
    pairs_arr = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    labels = np.where(np.isfinite(solved[:, 0]), _components(n, pairs_arr), -1)
    rmse, aligned = pooled_aligned_rmse(solved, truth, labels)
    local = neighbourhood_errors(aligned, truth, pairs_arr)
    localized = np.isfinite(local) & (local <= within_mm)
    return CentralResult(
        rmse_mm=rmse,
        localized_fraction=float(localized.sum() / n) if n else 0.0,
        localized=localized,
        aligned_mm=aligned,
        local_error_mm=local,
    )


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Each of ``n`` robots' connected component in the graph of ``pairs`` (E, 2)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if not len(pairs):
        return np.arange(n)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def neighbourhood_errors(
    positions_mm: np.ndarray, truth_mm: np.ndarray, pairs: np.ndarray, *, handedness: int = 1
) -> np.ndarray:
    """Each robot's error among its neighbours, mm.

    For robot i: the rigid motion of ``handedness``
    (:func:`~kilonet.protocols.common.alignment.rigid_fit`) that best maps its neighbours' positions
    (the robots it shares a pair with) onto their
    truth, and the distance from i's true position to its own position moved by it. A
    position right among its neighbours scores their relative errors, however far the whole
    shape has bent; a robot on the mirror side of its neighbours, or in a region mirrored
    against the frame's handedness, scores tens of millimetres.

    Parameters
    ----------
    positions_mm, truth_mm : (n, 2) arrays
        Positions in one frame (NaN where a robot has none) and the truth, mm.
    pairs : (E, 2) int array
        Who neighbours whom (either order; repeats are harmless).
    handedness : int
        +1 when ``positions_mm`` is turned like the truth (aligned to it, reflection
        allowed), -1 when it is its mirror image.

    Returns
    -------
    (n,) array
        The errors, mm; NaN for a robot without a position or with fewer than two
        neighbours that have one.

    Examples
    --------
    A straight row of 21 robots placed on an arc of 2 m radius: 13 mm off after the best
    alignment of the whole row, but each robot within a millimetre of where its neighbours put
    it. Robot 4 of a square, placed on the mirror side of its two neighbours, is not:

    >>> k = np.arange(21)
    >>> row = np.column_stack([40.0 * k, np.zeros(21)])
    >>> arc = 2000.0 * np.column_stack([np.sin(k / 50), 1 - np.cos(k / 50)])
    >>> pairs = np.array([(i, i + 1) for i in range(20)] + [(i, i + 2) for i in range(19)])
    >>> local = neighbourhood_errors(arc, row, pairs)
    >>> round(procrustes_rmse(arc, row)[0], 1), round(float(local.max()), 1)
    (13.1, 1.0)
    >>> sq = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0], [25.0, 25.0]])
    >>> flipped = sq.copy()
    >>> flipped[4] = [25.0, -25.0]
    >>> pairs = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (4, 0), (4, 1)])
    >>> round(float(neighbourhood_errors(flipped, sq, pairs)[4]), 6)
    50.0
    """
    pos = np.asarray(positions_mm, dtype=float)
    truth = np.asarray(truth_mm, dtype=float)
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    from scipy.sparse import coo_matrix

    n = len(truth)
    has = np.isfinite(pos).all(axis=1)
    keep = has[pairs[:, 0]] & has[pairs[:, 1]]
    a, b = pairs[keep, 0], pairs[keep, 1]
    graph = coo_matrix((np.ones(2 * len(a)), (np.r_[a, b], np.r_[b, a])), shape=(n, n)).tocsr()
    out = np.full(n, np.nan)
    for i in np.flatnonzero(has):
        nbrs = np.unique(graph.indices[graph.indptr[i] : graph.indptr[i + 1]])
        if len(nbrs) < 2:
            continue
        q, shift = rigid_fit(pos[nbrs], truth[nbrs], handedness=handedness)
        out[i] = float(np.hypot(*(pos[i] @ q.T + shift - truth[i])))
    return out


@dataclass(frozen=True)
class OptimumComparison:
    """A frame's estimates against the optimum of the same measurements
    (:func:`compare_with_optimum`).

    Attributes
    ----------
    agreement_mm : (n,) array
        Per robot, how far the estimates polished to their nearest minimum lie from the
        optimum after alignment, mm (NaN without both positions, or in a connected part of
        fewer than three robots).
    in_basin : bool
        Whether least squares from the estimates ends at the optimum's cost, within
        ``basin_excess`` noise units: the estimates lie in the optimum's basin.
    basin_excess : float
        The cost least squares from the estimates ends at, above the optimum's, in noise
        units (NaN without three robots that have both positions and a measurement).
    run_excess : float
        The estimates' own cost above the optimum's, in noise units: how far short of the
        floor the swarm stopped (NaN as ``basin_excess``).
    noise_mm2 : float
        The noise unit: the optimum's weighted squared residuals per degree of freedom
        (measurements less 2 per robot plus 3 per connected part), at least
        :data:`NOISE_FLOOR_MM2`, mm² per unit weight.
    """

    agreement_mm: np.ndarray
    in_basin: bool
    basin_excess: float
    run_excess: float
    noise_mm2: float


def compare_with_optimum(
    estimates_mm: np.ndarray,
    optimum_mm: np.ndarray,
    pairs: np.ndarray,
    distances_mm: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    within_mm: float = WITHIN_MM,
    max_excess: float = BASIN_EXCESS,
) -> OptimumComparison:
    """Whether a swarm's estimates lie at the optimum of the same measurements: by position
    and by cost.

    A distributed refinement stops short of the optimum, by more the longer and thinner the
    shape; a frame that folded or bent stops in another minimum altogether. Both are polished
    on the robots that have an estimate and an optimum position: least squares over the
    measurements among them (:func:`solve_positions`' objective) from the estimates, which
    ends at the minimum nearest them, and from the optimum, which ends at the optimum of
    these robots' measurements.

    *By position* (``agreement_mm``): each connected part of the first is aligned onto the
    second (rigid, reflection allowed) on the robots that agree within ``within_mm`` (so a
    folded part does not drag the rest). Estimates in the optimum's basin agree to a
    fraction of a millimetre; the robots of a folded or bent part lie tens of millimetres
    off. On a long corridor this fails: its optimum lies in a valley so flat along its bend
    that least squares stops wherever it starts, and two points of the valley lie more than
    ``within_mm`` apart at the same cost.

    *By cost* (``in_basin``): the polished estimates' cost against the optimum's, in units
    of the noise the optimum's residuals show. A point of the same flat valley costs what
    the optimum costs; a fold costs every flipped link's error squared. The cost needs no
    alignment (it is the same in every frame), and only the measurements judge it.

    Parameters
    ----------
    estimates_mm : (n, 2) array
        One frame's estimates, mm (NaN where a robot has none).
    optimum_mm : (n, 2) array
        The centralized optimum (:func:`solve_positions`, or :class:`CentralResult`'s
        ``aligned_mm``), mm (NaN where unsolved).
    pairs, distances_mm, weights
        The measurements, as in :func:`solve_positions`.
    within_mm : float
        The agreement the alignment is fitted to, mm.
    max_excess : float
        The largest ``basin_excess`` that counts as in the basin, noise units.

    Returns
    -------
    OptimumComparison

    Raises
    ------
    ValueError
        As :func:`solve_positions` for bad measurements.

    Examples
    --------
    A row of 21 robots 40 mm apart, measured exactly between neighbours and next-neighbours,
    bent along an arc of 1 m radius: by position it lies up to 55 mm from the straight
    optimum after the best alignment (least squares from it barely moves), by cost it is
    the optimum:

    >>> k = np.arange(21)
    >>> row = np.column_stack([40.0 * k, np.zeros(21)])
    >>> arc = 1000.0 * np.column_stack([np.sin(k / 25), 1 - np.cos(k / 25)])
    >>> pairs = np.array([(i, i + 1) for i in range(20)] + [(i, i + 2) for i in range(19)])
    >>> d = np.hypot(*(row[pairs[:, 0]] - row[pairs[:, 1]]).T)
    >>> result = compare_with_optimum(arc, row, pairs, d)
    >>> round(float(np.nanmax(result.agreement_mm))), result.in_basin
    (55, True)
    """
    est = np.asarray(estimates_mm, dtype=float)
    opt = np.asarray(optimum_mm, dtype=float)
    pairs, dist, w = _checked(len(est), pairs, distances_mm, weights)
    both = np.flatnonzero(np.isfinite(est).all(axis=1) & np.isfinite(opt).all(axis=1))
    out = np.full(len(est), np.nan)
    local = np.full(len(est), -1)
    local[both] = np.arange(len(both))
    keep = (local[pairs[:, 0]] >= 0) & (local[pairs[:, 1]] >= 0)
    if not keep.any():
        return OptimumComparison(out, False, math.nan, math.nan, math.nan)
    sub, m, dist, w = local[pairs[keep]], len(both), dist[keep], w[keep]
    polished_fit = _least_squares(m, sub, dist, w, est[both])
    optimum_fit = _least_squares(m, sub, dist, w, opt[both])
    polished, optimum = polished_fit.x.reshape(m, 2), optimum_fit.x.reshape(m, 2)
    labels = _components(m, sub)
    parts = 0
    for label in np.unique(labels):
        part = np.flatnonzero(labels == label)
        if len(part) >= MIN_COMPONENT:
            parts += 1
            moved = _aligned_on_agreement(polished[part], optimum[part], within_mm)
            out[both[part]] = np.hypot(*(moved - optimum[part]).T)
    if not parts:
        return OptimumComparison(out, False, math.nan, math.nan, math.nan)
    freedom = max(1, len(dist) - 2 * m + 3 * parts)
    noise = max(NOISE_FLOOR_MM2, 2.0 * float(optimum_fit.cost) / freedom)
    # scipy's cost is half the weighted sum of squares: twice its difference over the noise
    # per unit weight is the likelihood-ratio statistic.
    run_cost = 0.5 * float(
        np.sum(w * (np.hypot(*(est[both][sub[:, 0]] - est[both][sub[:, 1]]).T) - dist) ** 2)
    )
    basin = 2.0 * (polished_fit.cost - optimum_fit.cost) / noise
    return OptimumComparison(
        agreement_mm=out,
        in_basin=bool(basin <= max_excess),
        basin_excess=float(basin),
        run_excess=2.0 * (run_cost - float(optimum_fit.cost)) / noise,
        noise_mm2=noise,
    )


def optimum_agreement_mm(
    estimates_mm: np.ndarray,
    optimum_mm: np.ndarray,
    pairs: np.ndarray,
    distances_mm: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    within_mm: float = WITHIN_MM,
) -> np.ndarray:
    """How far a swarm's estimates lie from the optimum of the same measurements, mm:
    :func:`compare_with_optimum`'s ``agreement_mm``.

    Examples
    --------
    A square with its diagonals and a fifth robot tied to two corners: placed on the mirror
    side of them, it sits in a minimum of its own, 40 mm from the optimum's position:

    >>> sq = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0], [25.0, -20.0]])
    >>> pairs = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3), (4, 0), (4, 1)])
    >>> d = np.hypot(*(sq[pairs[:, 0]] - sq[pairs[:, 1]]).T)
    >>> folded = sq.copy()
    >>> folded[4] = [25.0, 20.0]
    >>> np.round(optimum_agreement_mm(folded + 3.0, sq, pairs, d), 6).tolist()
    [0.0, 0.0, 0.0, 0.0, 40.0]
    """
    return compare_with_optimum(
        estimates_mm, optimum_mm, pairs, distances_mm, weights, within_mm=within_mm
    ).agreement_mm


def _aligned_on_agreement(source: np.ndarray, target: np.ndarray, within_mm: float) -> np.ndarray:
    """``source`` (k, 2) moved onto ``target`` by the rigid motion (reflection allowed) fitted
    to the rows that agree: all at first, then those within ``within_mm`` or the median
    distance, whichever is larger, until they stop changing (at most 10 fits). A fit to every
    row would spread a folded part's offset over the robots that are right."""
    agree = np.ones(len(source), dtype=bool)
    for _ in range(10):
        q, shift = rigid_fit(source[agree], target[agree])
        moved = source @ q.T + shift
        dist = np.hypot(*(moved - target).T)
        now = dist <= max(within_mm, float(np.median(dist)))
        if (now == agree).all() or now.sum() < MIN_COMPONENT:
            break
        agree = now
    return moved


def pooled_aligned_rmse(
    estimated_mm: np.ndarray, truth_mm: np.ndarray, labels: np.ndarray
) -> tuple[float, np.ndarray]:
    """RMS error of estimates in several frames, each frame aligned to the truth on its own.

    Parameters
    ----------
    estimated_mm, truth_mm : (n, 2) arrays
        Estimates (each in its frame) and true positions, mm.
    labels : (n,) array
        Each robot's frame; robots labelled ``-1`` have no estimate.

    Returns
    -------
    rmse_mm : float
        ``sqrt(mean |aligned − true|²)`` over every robot of a frame with at least three
        robots, after the best rigid alignment of each such frame (reflection allowed); NaN if
        there is none.
    aligned_mm : (n, 2) array
        The aligned estimates; NaN for robots without one or in smaller frames.

    Examples
    --------
    >>> truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0], [90.0, 0.0]])
    >>> est = truth * [-1.0, 1.0] + [5.0, 5.0]
    >>> rmse, aligned = pooled_aligned_rmse(est, truth, np.array([0, 0, 0, -1]))
    >>> round(rmse, 9), bool(np.isnan(aligned[3]).all())
    (0.0, True)
    """
    est = np.asarray(estimated_mm, dtype=float)
    truth = np.asarray(truth_mm, dtype=float)
    labels = np.asarray(labels)
    aligned = np.full(truth.shape, np.nan)
    squared, count = 0.0, 0
    for label in np.unique(labels[labels != -1]):
        members = np.flatnonzero(labels == label)
        if len(members) < MIN_COMPONENT:
            continue
        rmse, _, moved = procrustes_rmse(est[members], truth[members])
        aligned[members] = moved
        squared += rmse**2 * len(members)
        count += len(members)
    return (math.sqrt(squared / count) if count else math.nan), aligned
