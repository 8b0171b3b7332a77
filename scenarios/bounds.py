"""The Cramér–Rao bound of a measured distance graph: how well any unbiased estimator could
place a swarm from its ranges, up to a rigid motion (anchor-free), mm.

Split from :mod:`kilonet.protocols.common.geometry`, whose fixes it bounds;
``kilonet.scenarios.reference`` puts it in every gcs and localize summary.
"""

from __future__ import annotations

import math

import numpy as np

from kilonet.protocols.common.geometry import GeometryError

__all__ = ["crlb_rmse_mm"]


# ----------------------------------------------------------------------- Cramér–Rao bound


def crlb_rmse_mm(
    positions_mm: np.ndarray,
    edges: np.ndarray,
    sigma_mm: float,
    *,
    weights: np.ndarray | None = None,
    require_rigid: bool = False,
) -> float:
    """Anchor-free Cramér–Rao bound on the RMS position error of a measured distance graph.

    Each edge (i, j) is one distance measurement with independent noise of standard
    deviation ``sigma_mm``. Its Fisher information on the 2N coordinates is
    ``u uᵀ / σ²`` on the (i, i) and (j, j) blocks and ``−u uᵀ / σ²`` on (i, j) and (j, i),
    u the unit vector from j to i. Distances cannot fix where the swarm is or how it is
    turned, so J is singular: for a rigid connected graph its null space is the 3 gauge
    freedoms (2 translations, 1 rotation), which the pseudo-inverse removes — the bound then
    applies to the error after the best rigid alignment to the truth, as the metrics measure
    it. The bound on the mean squared error per robot is ``trace(pinv(J)) / N``; its square
    root is returned.

    A disconnected or flexible graph has more null directions; the pseudo-inverse drops them
    as well (each component is then aligned on its own, flexes are not counted) unless
    ``require_rigid`` asks for an error.

    Parameters
    ----------
    positions_mm : (N, 2) array
        True positions, mm.
    edges : (E, 2) int array
        Measured pairs (row indices of ``positions_mm``); list a pair twice for two
        independent measurements of it (e.g. both directions).
    sigma_mm : float
        Standard deviation of one distance measurement, mm (positive).
    weights : (E,) array, optional
        Independent measurements each edge stands for (its information is that many times
        one measurement's, as if the edge were listed that many times); default 1 each.
    require_rigid : bool
        Raise when the null space is larger than the 3 gauge freedoms.

    Returns
    -------
    float
        Lower bound on ``sqrt(E[Σᵢ |p̂ᵢ − pᵢ|²] / N)`` for unbiased estimators, mm.

    Raises
    ------
    GeometryError
        If there are no edges, an edge joins coincident positions, or ``require_rigid`` is
        set and the graph is not rigid.
    ValueError
        If an edge index is out of range or a self-loop, ``sigma_mm`` is not positive, or the
        weights are not one non-negative finite number per edge.

    Notes
    -----
    O(N³) time and O(N²) memory: J is a dense 2N × 2N matrix. A rigid connected graph is
    handled by one Cholesky factorisation, other graphs by the slower eigen-decomposition
    (block ``math-speed`` of ``docs/results/math.md`` gives both at N = 1,000).

    Examples
    --------
    An equilateral triangle with its three sides measured: the bound is σ √5 / 3.

    >>> tri = np.array([[0.0, 0.0], [40.0, 0.0], [20.0, 20.0 * np.sqrt(3.0)]])
    >>> round(crlb_rmse_mm(tri, [(0, 1), (0, 2), (1, 2)], sigma_mm=1.0), 9)
    0.745355992
    >>> round(math.sqrt(5.0) / 3.0, 9)
    0.745355992

    Four measurements of each side halve it:

    >>> round(crlb_rmse_mm(tri, [(0, 1), (0, 2), (1, 2)], sigma_mm=1.0, weights=[4, 4, 4]), 9)
    0.372677996
    """
    from scipy.sparse import coo_matrix

    pos = np.asarray(positions_mm, dtype=float)
    pairs = np.asarray(edges, dtype=np.intp).reshape(-1, 2)
    n = len(pos)
    if not sigma_mm > 0:
        raise ValueError(f"sigma_mm must be positive; got {sigma_mm}")
    if len(pairs) == 0:
        raise GeometryError("no measured pairs: the bound is infinite")
    if pairs.min() < 0 or pairs.max() >= n:
        raise ValueError(f"edge index out of range 0..{n - 1}: {pairs.min()}..{pairs.max()}")
    i, j = pairs[:, 0], pairs[:, 1]
    if (i == j).any():
        raise ValueError(f"self-loop in edges at robot {int(i[i == j][0])}")
    diff = pos[i] - pos[j]
    dist = np.sqrt((diff * diff).sum(axis=1))
    if (dist <= 0).any():
        e = int(np.flatnonzero(dist <= 0)[0])
        raise GeometryError(f"edge ({int(i[e])}, {int(j[e])}) joins coincident positions")
    u = diff / dist[:, None]
    if weights is not None:
        w = np.asarray(weights, dtype=float).reshape(-1)
        if len(w) != len(pairs) or not (np.isfinite(w).all() and (w >= 0).all()):
            raise ValueError("weights must be one non-negative finite number per edge")
        u = u * np.sqrt(w)[:, None]
    rows = np.repeat(np.arange(len(pairs)), 4)
    cols = np.stack([2 * i, 2 * i + 1, 2 * j, 2 * j + 1], axis=1).ravel()
    vals = np.stack([u[:, 0], u[:, 1], -u[:, 0], -u[:, 1]], axis=1).ravel()
    rigidity = coo_matrix((vals, (rows, cols)), shape=(len(pairs), 2 * n)).tocsr()
    info = (rigidity.T @ rigidity).toarray() / sigma_mm**2
    total = _gauge_fixed_trace(info, pos, pairs)
    if total is None:
        eig = np.linalg.eigvalsh(info)
        determined = eig > _NULL_RTOL * eig[-1]
        null_dims = int((~determined).sum())
        if require_rigid and null_dims > 3:
            raise GeometryError(
                f"the measurement graph is not rigid: {null_dims} undetermined directions "
                "(3 are the rigid motions)"
            )
        total = float((1.0 / eig[determined]).sum())
    return math.sqrt(total / n)


#: Eigenvalues of the Fisher information below this fraction of the largest count as null.
_NULL_RTOL = 1e-9


def _gauge_fixed_trace(info: np.ndarray, pos: np.ndarray, pairs: np.ndarray) -> float | None:
    """trace(pinv(J)) by Cholesky when J's null space is exactly the 3 rigid motions, else None.

    With G an orthonormal basis of the rigid motions (the null space of a rigid connected
    graph's J) and c > 0, ``(J + c G Gᵀ)⁻¹ = pinv(J) + G Gᵀ / c``, so the trace follows from
    one Cholesky factor and a triangular inverse, cheaper than the full eigen-decomposition.
    Returns None (use the eigenvalues) when the graph is disconnected,
    when the factorisation fails (another null direction: a flexible graph) or when the
    result shows an eigenvalue the eigenvalue path would count as null.
    """
    from scipy.linalg import LinAlgError, cholesky, lapack
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(pos)
    adjacency = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    if connected_components(adjacency, directed=False)[0] != 1:
        return None
    centred = pos - pos.mean(axis=0)
    gauge = np.zeros((2 * n, 3))
    gauge[0::2, 0] = gauge[1::2, 1] = 1.0 / math.sqrt(n)
    gauge[0::2, 2], gauge[1::2, 2] = -centred[:, 1], centred[:, 0]
    gauge[:, 2] /= np.linalg.norm(gauge[:, 2])
    mean_eig = float(np.trace(info)) / (2 * n)
    try:
        factor = cholesky(info + mean_eig * (gauge @ gauge.T), lower=True)
    except LinAlgError:
        return None
    inverse, status = lapack.dtrtri(factor, lower=1)
    if status != 0:
        return None
    total = float((inverse * inverse).sum()) - 3.0 / mean_eig
    # Gershgorin: every eigenvalue is at most the largest absolute row sum.
    largest_eig = float(np.abs(info).sum(axis=1).max())
    if total > 1.0 / (_NULL_RTOL * largest_eig):
        return None
    return total
