"""The bound and the optimum beside a swarm's localization, for every localization scenario.

A localization run (``gcs``, ``localize``) reports, next to its own RMSE:

* ``crlb_rmse_mm``: the anchor-free Cramér–Rao bound of the communication graph with one
  reception per pair (:func:`kilonet.scenarios.bounds.crlb_rmse_mm`), each link's error the
  reception model's effective error at its length (``effective_sigma_mm`` of
  :mod:`kilonet.reception`'s models: the systematic part that averaging cannot remove, plus
  one reading's noise and rounding), and ``rmse_over_crlb``;
* ``crlb_received_rmse_mm``: the same bound for the receptions the robots actually averaged
  (each ordered pair with its number of samples: averaging shrinks the noise, not the
  systematic error), and ``rmse_over_crlb_received``;
* ``central_rmse_mm``, ``central_localized_fraction``: the centralized solver
  (:func:`kilonet.scenarios.central.central_reference`) on the run's own measured distances; a robot
  counts as localized by it when the solver places it right among its neighbours
  (within :data:`kilonet.scenarios.central.WITHIN_MM`);
* ``largest_frame_over_central``: the largest frame's size over the number of robots the
  solver localizes (a folded frame counts whole);
* ``at_optimum_over_central``: of the robots the solver localizes, the share the largest
  frame places at the optimum (:func:`kilonet.scenarios.central.optimum_agreement_mm` within
  ``WITHIN_MM``: the frame's estimates, polished to the nearest least-squares minimum, where
  the optimum of the same measurements puts them; a folded or bent part lies tens of
  millimetres off), and ``off_optimum_robots``, the frame's robots it does not place there
  (the first :data:`LISTED_ROBOTS` by index);
* ``in_optimum_basin``, ``basin_excess_over_central``, ``run_cost_excess_over_central``: the
  same question by cost
  (:func:`kilonet.scenarios.central.compare_with_optimum`): least squares from the largest
  frame's estimates ends within :data:`kilonet.scenarios.central.BASIN_EXCESS` noise units of
  the optimum's cost, that excess, and the estimates' own cost over the optimum's (how far
  short of the floor the refinement stopped); sound where the optimum's valley is so flat
  that two of its points lie more than ``WITHIN_MM`` apart at one cost (a long corridor);
* ``hop_diameter`` of the communication graph: ``hop_diameter × robot.tx_period_s`` is the
  time information needs to cross the swarm.

The measured distances (:func:`measured_distances`): for every ordered pair (i, j), the mean of
the distance estimates robot i received in j's messages, as i's neighbour record holds it at the
end, weighted by its number of samples. A record's ID is mapped to the robot holding that ID
among those i hears; IDs two of them share, and records marked ambiguous, are left out. Both
programs' neighbour tables offer the same record interface: ``by_id``, and per record
``mean_mm``, ``samples`` and ``ambiguous``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = [
    "LISTED_ROBOTS",
    "NeighbourRecords",
    "hop_diameter",
    "largest_frame_mm",
    "measured_distances",
    "reference_metrics",
]

#: Robots a summary lists by index where it names those a metric left out (the first ones).
LISTED_ROBOTS = 50


class _Record(Protocol):
    samples: int
    ambiguous: bool

    @property
    def mean_mm(self) -> float: ...


class NeighbourRecords(Protocol):
    """A robot's neighbour table as :func:`measured_distances` reads it."""

    @property
    def by_id(self) -> Mapping[int, _Record]: ...


def measured_distances(
    sim: Simulation, tables: Sequence[NeighbourRecords]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distances the robots measured: ``(pairs (E, 2), mean_mm (E,), samples (E,))``, one
    row per ordered pair (receiver, sender); ``tables[i]`` is robot i's neighbour table and
    ``sim.robots[k].uid`` robot k's ID (see the module docstring)."""
    pairs, means, samples = [], [], []
    robots = sim.robots
    heard_by: dict[int, dict[int, int]] = {i: {} for i in range(sim.n_robots)}
    for s in range(sim.n_robots):
        uid = robots[s].uid
        for i in sim.medium.receivers_of(s):
            heard_by[i][uid] = s if uid not in heard_by[i] else -1
    for i, table in enumerate(tables):
        for uid, n in table.by_id.items():
            s = heard_by[i].get(uid, -1)
            if s < 0 or n.ambiguous or n.samples == 0:
                continue
            pairs.append((i, s))
            means.append(n.mean_mm)
            samples.append(n.samples)
    return (
        np.array(pairs, dtype=np.intp).reshape(-1, 2),
        np.array(means, dtype=float),
        np.array(samples, dtype=float),
    )


def hop_diameter(n: int, i: np.ndarray, j: np.ndarray) -> int:
    """Largest hop distance between two of ``n`` robots of one connected component of the
    graph with edges ``(i, j)``.

    Examples
    --------
    >>> hop_diameter(5, np.array([0, 1, 2]), np.array([1, 2, 3]))  # a path; robot 4 alone
    3
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import shortest_path

    if len(i) == 0:
        return 0
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    hops = shortest_path(graph, directed=False, unweighted=True)
    finite = hops[np.isfinite(hops)]
    return int(finite.max()) if len(finite) else 0


def largest_frame_mm(positions_mm: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """The estimates of the largest frame: ``positions_mm`` (n, 2) where ``labels`` (n,) names
    the frame with the most robots (label ``-1``: no frame; ties: the smallest label), NaN
    elsewhere.

    >>> largest_frame_mm(np.arange(8.0).reshape(4, 2), np.array([1, 0, 1, -1])).tolist()
    [[0.0, 1.0], [nan, nan], [4.0, 5.0], [nan, nan]]
    """
    out = np.full(np.shape(positions_mm), np.nan)
    framed = labels[labels >= 0]
    if len(framed):
        values, counts = np.unique(framed, return_counts=True)
        members = labels == values[np.argmax(counts)]
        out[members] = np.asarray(positions_mm)[members]
    return out


def reference_metrics(
    sim: Simulation,
    tables: Sequence[NeighbourRecords],
    links: tuple[np.ndarray, np.ndarray],
    *,
    rmse_mm: float,
    frame_mm: np.ndarray,
) -> dict[str, Any]:
    """The keys of the module docstring for a run whose swarm ended at ``rmse_mm``;
    ``frame_mm`` (n, 2) holds the estimates of its largest frame (NaN for robots outside it),
    ``links`` the communication graph's pairs ``(i, j)``. Keys whose inputs are missing (no
    link, no measurement, no noise) are left out, except ``crlb_rmse_mm`` (None without a
    link: the bound is infinite)."""
    from kilonet.scenarios.bounds import crlb_rmse_mm
    from kilonet.scenarios.central import WITHIN_MM, central_reference, compare_with_optimum

    truth = sim.world.positions_mm
    i, j = links
    out: dict[str, Any] = {"crlb_rmse_mm": None, "hop_diameter": hop_diameter(sim.n_robots, i, j)}
    pairs, means, samples = measured_distances(sim, tables)
    model = sim.medium.reception
    if len(i) and hasattr(model, "effective_sigma_mm"):

        def bound(edges: np.ndarray, n: np.ndarray | float) -> float:
            length = np.hypot(*(truth[edges[:, 0]] - truth[edges[:, 1]]).T)
            sigma = model.effective_sigma_mm(length, n)
            return crlb_rmse_mm(truth, edges, 1.0, weights=1.0 / sigma**2)

        out["crlb_rmse_mm"] = bound(np.column_stack([i, j]), 1.0)
        out["rmse_over_crlb"] = rmse_mm / out["crlb_rmse_mm"]
        if len(pairs):
            received = bound(pairs, samples)
            out["crlb_received_rmse_mm"] = received
            out["rmse_over_crlb_received"] = rmse_mm / received
    if len(pairs):
        # The frame's own estimates are one more start: where the optimum's valley is flat,
        # least squares stops wherever it starts, and the lower cost is the better optimum.
        central = central_reference(truth, pairs, means, samples, starts=[frame_mm])
        out["central_rmse_mm"] = central.rmse_mm
        out["central_localized_fraction"] = central.localized_fraction
        located = int(central.localized.sum())
        in_frame = np.isfinite(frame_mm).all(axis=1)
        compared = compare_with_optimum(frame_mm, central.aligned_mm, pairs, means, samples)
        agreement = compared.agreement_mm
        off = central.localized & in_frame & ~(agreement <= WITHIN_MM)
        at = central.localized & in_frame & ~off
        out["largest_frame_over_central"] = int(in_frame.sum()) / located if located else 0.0
        out["at_optimum_over_central"] = int(at.sum()) / located if located else 0.0
        out["off_optimum_robots"] = np.flatnonzero(off)[:LISTED_ROBOTS].tolist()
        out["in_optimum_basin"] = compared.in_basin
        # Thousandths of a noise unit: a frame in the basin polishes to the optimum's cost within
        # the solver's last digits, which vary from run to run of the same swarm.
        out["basin_excess_over_central"] = round(compared.basin_excess, 3) + 0.0  # no "-0.0"
        out["run_cost_excess_over_central"] = compared.run_excess
    return out
