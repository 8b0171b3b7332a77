"""The neighbourhood a ranging protocol sees: the medium's links whose estimates it trusts.

Real Kilobots hear each other farther than they can range
(:mod:`kilonet.protocols.common.ranging_limit`), so a protocol ignores receptions whose distance
estimate is above its ``neighbour_max_mm``. The
truth a scenario judges such a protocol by is then not every link of the medium but the links
whose estimates fall within that limit: :func:`trusted_links`, from each link's noise-free
estimate (its systematic error included), and those estimates by link:
:func:`held_estimates_mm`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import networkx as nx

    from kilonet.params import MediumParams
    from kilonet.reception import ReceptionModel
    from kilonet.simulation import Simulation

__all__ = [
    "RECEPTION_NOISE_MM",
    "held_estimates_mm",
    "held_estimates_of_links",
    "neighbourhood_mm",
    "noise_free_estimate_mm",
    "trusted_links",
]


def neighbourhood_mm(medium: MediumParams, max_mm: float) -> float:
    """How far a protocol's neighbours stand, as a radius, mm: as far as a median link reaches
    (the disc's ``medium.range_mm``, else the preset's median reach,
    :func:`kilonet.radio.reach_of`), but at most the protocol's ``max_mm``, beyond which it
    ignores what it hears.

    Examples
    --------
    >>> from kilonet.params import MediumParams
    >>> neighbourhood_mm(MediumParams(), 100.0), neighbourhood_mm(MediumParams(reach="disc"), 100.0)
    (100.0, 85.0)
    """
    from kilonet.radio import reach_of

    return min(reach_of(medium).median_mm, max_mm)


def noise_free_estimate_mm(
    sim: Simulation, sender: int, receiver: int, distance_mm: float
) -> float:
    """The estimate the link ``sender`` -> ``receiver`` gives at ``distance_mm`` without noise,
    mm: :meth:`kilonet.reception.TableRanging.systematic_mm`, the true distance plus the
    receiver's bias for :class:`~kilonet.reception.GaussianRanging`, else the true distance."""
    return _noise_free_of(sim.medium.reception, sender, receiver, distance_mm)


def _noise_free_of(model: ReceptionModel, sender: int, receiver: int, distance_mm: float) -> float:
    """:func:`noise_free_estimate_mm` under the reception ``model``, mm."""
    systematic = getattr(model, "systematic_mm", None)
    if systematic is not None:
        return float(systematic(sender, receiver, distance_mm))
    bias = getattr(model, "bias_mm", None)
    return float(distance_mm + (bias[receiver] if bias is not None else 0.0))


def trusted_links(sim: Simulation, max_mm: float, margin_mm: float = 0.0) -> nx.DiGraph:
    """The medium's links now, sender to receiver, whose noise-free estimate is at most
    ``max_mm - margin_mm`` (mm; a positive margin keeps only links that every reception's
    noise leaves within ``max_mm``), with their true ``distance_mm`` and noise-free
    ``estimate_mm``; every robot is a node."""
    import networkx as nx

    pos = sim.world.positions_mm
    graph = nx.DiGraph()
    graph.add_nodes_from(range(sim.n_robots))
    links = [(s, r) for s in range(sim.n_robots) for r in sim.medium.receivers_of(s)]
    distances = [float(np.hypot(*(pos[s] - pos[r]))) for s, r in links]
    estimates = _noise_free_links_mm(sim.medium.reception, links, np.array(distances))
    for (s, r), d, estimate in zip(links, distances, estimates.tolist(), strict=True):
        if estimate <= max_mm - margin_mm:
            graph.add_edge(s, r, distance_mm=d, estimate_mm=estimate)
    return graph


def _noise_free_links_mm(
    model: ReceptionModel, links: list[tuple[int, int]], distance_mm: np.ndarray
) -> np.ndarray:
    """:func:`noise_free_estimate_mm` of many ``(sender, receiver)`` links under the reception
    ``model``, row ``k`` at ``distance_mm[k]`` (a row of distances per link, or one), in one
    call of the model's ``noise_free_mm`` where it has one, mm."""
    distance_mm = np.asarray(distance_mm, dtype=float)
    if not hasattr(model, "noise_free_mm") or not links:
        return np.array(
            [
                [_noise_free_of(model, s, r, d) for d in np.atleast_1d(row).tolist()]
                for (s, r), row in zip(links, distance_mm, strict=True)
            ]
        ).reshape(distance_mm.shape)
    per_link = distance_mm.size // len(links)
    senders, receivers = (np.repeat(side, per_link) for side in zip(*links, strict=True))
    flat = model.noise_free_mm(senders, receivers, distance_mm.ravel())
    return np.asarray(flat, dtype=float).reshape(distance_mm.shape)


#: How far a reception's noise moves a link's estimate at most, mm (ranging.intensity_noise
#: 1.5 %): a robot that hears a link hundreds of times finds some receptions within its limit
#: as long as the noise-free estimate is at most this far beyond it. Measured on the topology
#: sweep's medium: links 1 mm beyond the limit always entered the tables, 2 mm beyond 8 of 10,
#: 3 mm beyond 1 of 7.
RECEPTION_NOISE_MM = 2.0


#: Standard normal quantiles a link's receptions are averaged over (:func:`held_estimates_mm`).
_QUANTILES = (
    -1.53,
    -1.15,
    -0.89,
    -0.67,
    -0.49,
    -0.32,
    -0.16,
    0.0,
    0.16,
    0.32,
    0.49,
    0.67,
    0.89,
    1.15,
    1.53,
)


def held_estimates_mm(sim: Simulation, max_mm: float) -> np.ndarray:
    """The distances the robots' neighbour tables will hold, as an ``(n, n)`` matrix, mm:
    ``[sender, receiver]`` is the receiver's estimate of the sender, NaN where it will not
    hold one and on the diagonal.

    A table entry is the mean of a link's receptions within ``max_mm``. Kilolib's estimates
    come in whole millimetres, but the intensity noise dithers them, so that mean lies between
    the noise-free estimate's steps: it is taken here as the mean of the noise-free estimates
    at the distances the noise is worth (quantiles of a spread ``(25 mm + gap) / 2 *
    ranging.intensity_noise``, the inverse square law's sensitivity, as
    :meth:`kilonet.reception.TableRanging.effective_sigma_mm` has it) that are within the
    limit. A link whose noise-free estimate lies up to :data:`RECEPTION_NOISE_MM` beyond the
    limit is held too, at about the limit: the receptions the noise brings within it."""
    pos = sim.world.positions_mm
    links = [(s, r) for s in range(sim.n_robots) for r in sim.medium.receivers_of(s)]
    distances = [float(np.hypot(*(pos[s] - pos[r]))) for s, r in links]
    return held_estimates_of_links(
        sim.medium.reception,
        sim.params.ranging.intensity_noise,
        sim.n_robots,
        links,
        np.array(distances, dtype=float),
        max_mm,
    )


def held_estimates_of_links(
    model: ReceptionModel,
    intensity_noise: float,
    n_robots: int,
    links: list[tuple[int, int]],
    distance_mm: np.ndarray,
    max_mm: float,
) -> np.ndarray:
    """:func:`held_estimates_mm` of the links ``links[k] = (sender, receiver)`` at true
    distances ``distance_mm[k]`` (mm) under the reception ``model`` and
    ``ranging.intensity_noise``, for ``n_robots`` robots: the same estimates of links a caller
    drew itself (:mod:`kilonet.scenarios.link_draws`) rather than the medium's links now."""
    estimates = np.full((n_robots, n_robots), np.nan)
    noise_free = _noise_free_links_mm(model, links, distance_mm)
    kept = np.flatnonzero(noise_free <= max_mm + RECEPTION_NOISE_MM).tolist()
    edges = [links[k] for k in kept]
    d = np.asarray(distance_mm, dtype=float)[kept][:, None]
    sd = 0.5 * intensity_noise * (25.0 + np.maximum(d - 33.0, 0.0))
    readings = _noise_free_links_mm(model, edges, d + sd * np.array(_QUANTILES))
    for (s, r), row in zip(edges, readings, strict=True):
        within = row[row <= max_mm]
        estimates[s, r] = float(np.mean(within)) if len(within) else max_mm
    return estimates
