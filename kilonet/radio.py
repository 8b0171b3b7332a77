"""Each robot's infrared transceiver: how strongly it emits, how well it hears, how far it reaches.

No two Kilobots are alike. Each has an emitter of its own strength and a receiver of its own
sensitivity, so each sender reaches its own distance and a link can work one way only. The
ARGoS project's validation data (25 real Kilobots on a 5 cm grid, each counting what it hears
from every other; ``tests/validation/data/argos``) show it: a sender's farthest receiver above
50 % lies anywhere from 112 to 180 mm, about 8 % of the links are asymmetric by more than half
their messages, and reception falls off near a link's edge instead of stopping at one radius.

The model (:class:`Transceivers`, :func:`reception_probability`):

* robot ``k`` emits with strength ``P_k = exp(tx_strength_sd * z)`` and hears with sensitivity
  ``S_k = exp(rx_sensitivity_sd * z')`` (``z, z'`` standard normal, clipped to ±3);
* far from the emitter the light reflected off the table falls as the inverse square of the
  distance, so the link from ``s`` to ``r`` reaches ``R_sr = reach_median_mm * sqrt(P_s) * S_r``;
* a reception on that link at distance ``d`` succeeds with probability
  ``1 / (1 + exp((d - R_sr) / edge_mm))``: the soft edge.

The emitter strength is also what biases the receiver's distance estimate
(:mod:`kilonet.reception`): a strong emitter looks near. Presets (:data:`REACH_PRESETS`) hold
values fitted to the data; ``disc`` is one hard radius (``medium.range_mm``) for every link, the
thesis's and Kilombo's model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from kilonet.params import MediumParams

__all__ = [
    "MIN_RECEPTION",
    "REACH_PRESETS",
    "Reach",
    "Transceivers",
    "farthest_mm",
    "reach_of",
    "reception_probability",
]

#: Links whose reception probability is below this are left out of the medium's receiver lists.
MIN_RECEPTION = 1e-3

#: Per-robot draws are clipped to this many standard deviations (no robot is infinitely strong).
_CLIP_SD = 3.0


@dataclass(frozen=True)
class Reach:
    """How far links reach: a median, a per-receiver spread and a soft edge.

    Attributes
    ----------
    median_mm : float
        Reach of a link between two median robots, centre to centre, mm.
    rx_sensitivity_sd : float
        Log-normal spread of the receivers' sensitivity (0: all alike).
    edge_mm : float
        Width of the soft edge, mm (0: a hard edge, reception 1 up to the reach, 0 beyond).
    per_robot : bool
        Whether each link's reach depends on its sender's strength and receiver's sensitivity
        (``False``: every link reaches ``median_mm``, the disc).
    """

    median_mm: float
    rx_sensitivity_sd: float
    edge_mm: float
    per_robot: bool = True


#: Reach fitted to the ARGoS validation data (``python -m kilonet.experiments.publish validation``
#: re-checks each against the data): ``argos``, the 40 runs of its two majority series;
#: ``argos-long``, the 10 runs of the long-reach series (same robots, another session).
REACH_PRESETS: dict[str, Reach] = {
    "argos": Reach(median_mm=148.0, rx_sensitivity_sd=0.02, edge_mm=1.0),
    "argos-long": Reach(median_mm=205.0, rx_sensitivity_sd=0.04, edge_mm=6.0),
}


def farthest_mm(medium: MediumParams) -> float:
    """The farthest any link can deliver :data:`MIN_RECEPTION` of its receptions under these
    ``medium`` parameters, whatever robots are drawn, mm.

    Examples
    --------
    >>> from kilonet.params import MediumParams
    >>> farthest_mm(MediumParams(reach="disc", range_mm=85.0))
    85.0
    """
    reach = reach_of(medium)
    if not reach.per_robot:
        return reach.median_mm
    spread = _CLIP_SD * (medium.tx_strength_sd / 2 + reach.rx_sensitivity_sd)
    return reach.median_mm * math.exp(spread) + reach.edge_mm * math.log(1 / MIN_RECEPTION - 1)


def reach_of(medium: MediumParams) -> Reach:
    """The reach a run's ``medium`` parameters describe: the preset ``medium.reach`` with any
    of ``medium.reach_median_mm``, ``rx_sensitivity_sd``, ``edge_mm`` that are set, or for
    ``disc`` one hard radius of ``medium.range_mm``."""
    if medium.reach == "disc":
        return Reach(medium.range_mm, 0.0, 0.0, per_robot=False)
    preset = REACH_PRESETS[medium.reach]
    return Reach(
        preset.median_mm if medium.reach_median_mm is None else medium.reach_median_mm,
        preset.rx_sensitivity_sd if medium.rx_sensitivity_sd is None else medium.rx_sensitivity_sd,
        preset.edge_mm if medium.edge_mm is None else medium.edge_mm,
    )


def reception_probability(
    distance_mm: np.ndarray, reach_mm: np.ndarray, edge_mm: float
) -> np.ndarray:
    """Share of receptions that a link of reach ``reach_mm`` delivers at ``distance_mm``.

    Examples
    --------
    >>> reception_probability(np.array([140.0, 150.0, 160.0]), np.full(3, 150.0), 3.0).round(3)
    array([0.966, 0.5  , 0.034])
    >>> reception_probability(np.array([85.0, 85.1]), np.full(2, 85.0), 0.0)
    array([1., 0.])
    """
    d = np.asarray(distance_mm, dtype=float)
    if edge_mm == 0:
        return (d <= reach_mm).astype(float)
    with np.errstate(over="ignore"):
        return 1.0 / (1.0 + np.exp((d - reach_mm) / edge_mm))


@dataclass(frozen=True)
class Transceivers:
    """The emitter strength and receiver sensitivity of every robot (relative, median 1).

    Attributes
    ----------
    strength : (N,) float array
        Emitted intensity relative to a median robot's.
    sensitivity : (N,) float array
        Receiver sensitivity relative to a median robot's.
    reach : Reach
        The links' median reach and soft edge.
    """

    strength: np.ndarray
    sensitivity: np.ndarray
    reach: Reach

    @classmethod
    def draw(
        cls, n: int, reach: Reach, tx_strength_sd: float, rng: np.random.Generator
    ) -> Transceivers:
        """Draw ``n`` robots' transceivers from ``rng`` (the run's ``radio`` stream).

        Examples
        --------
        >>> t = Transceivers.draw(3, Reach(150.0, 0.0, 3.0), 0.0, np.random.default_rng(1))
        >>> t.strength.tolist(), t.link_reach_mm(np.array([0]), np.array([1])).tolist()
        ([1.0, 1.0, 1.0], [150.0])
        """
        z = np.clip(rng.standard_normal((2, n)), -_CLIP_SD, _CLIP_SD)
        return cls(np.exp(tx_strength_sd * z[0]), np.exp(reach.rx_sensitivity_sd * z[1]), reach)

    def link_reach_mm(self, sender: np.ndarray, receiver: np.ndarray) -> np.ndarray:
        """Reach of each link from ``sender[k]`` to ``receiver[k]``, mm."""
        if not self.reach.per_robot:
            return np.full(len(sender), self.reach.median_mm)
        return self.reach.median_mm * np.sqrt(self.strength[sender]) * self.sensitivity[receiver]

    @property
    def max_distance_mm(self) -> float:
        """The farthest distance at which any link of this swarm still delivers
        :data:`MIN_RECEPTION` of its receptions, mm (the medium looks for links this far)."""
        if len(self.strength) == 0 or not self.reach.per_robot:
            return self.reach.median_mm
        longest = self.reach.median_mm * math.sqrt(self.strength.max()) * self.sensitivity.max()
        return longest + self.reach.edge_mm * math.log(1.0 / MIN_RECEPTION - 1.0)
