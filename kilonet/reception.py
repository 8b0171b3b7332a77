"""The reception model: how each clean reception turns out (its distance estimate, or its loss).

The medium decides *whether* a message reaches a receiver cleanly (range, occlusion, carrier
sense, collisions: :mod:`kilonet.visibility`, :mod:`kilonet.mac`); a reception model decides
what becomes of each reception that does: the distance estimate it carries, and whether it is
lost anyway, and to what cause. It draws the fate of a sender's next transmissions ahead, in a
block of rows (row ``k``: the ``k``-th next transmission, one entry per receiver), because
drawing per reception from NumPy costs about a microsecond and slicing a pre-drawn row costs
nothing. That is valid as long as the outcome of a reception depends only on what is fixed
while the sender's receiver list stands (the link's true distance and occlusion, each robot's
calibration and battery level): the medium throws the rows away whenever that list or a
receiver's loss share changes. A model whose outcomes depend on time itself would have to draw
one row per transmission (``rows`` = 1 makes that possible, at the cost of speed).

:class:`GaussianRanging` is the default: ``round(true distance + receiver bias + N(0, sigma))``
clipped to kilolib's uint8 ``[min_mm, max_mm]``, each receiver with a bias ``N(0,
bias_sigma_mm)`` drawn once, and independent losses with the per-link and per-receiver shares
the medium passes in. Subclass it and override :meth:`GaussianRanging.loss_probability` for a
distance-dependent loss, or :meth:`GaussianRanging.estimates` for another ranging model, and
pass an instance to :class:`kilonet.simulation.Simulation` (``reception=``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from kilonet.params import Params

__all__ = ["CAUSES", "GaussianRanging", "LossShares", "Outcomes", "ReceptionModel"]

#: Loss codes of an outcome row, by cause (0: delivered). The medium counts each cause per
#: receiving robot as ``lost_<cause>``.
CAUSES = {1: "random", 2: "occlusion", 3: "battery", 4: "fault"}
RANDOM, OCCLUSION, BATTERY, FAULT = 1, 2, 3, 4


@dataclass(frozen=True)
class LossShares:
    """What can lose a reception on the links of one sender, one entry per receiver.

    Attributes
    ----------
    random : float
        ``medium.loss_prob``: independent loss of every reception.
    occlusion : (R,) array
        Loss from bodies on each link's line of sight (:class:`kilonet.visibility.LinkModel`).
    battery, fault : (R,) arrays
        The receivers' own shares: a low battery, a faulty receiver.
    """

    random: float
    occlusion: np.ndarray
    battery: np.ndarray
    fault: np.ndarray


@dataclass(frozen=True)
class Outcomes:
    """The drawn fate of a sender's next ``rows`` transmissions.

    Attributes
    ----------
    estimates : (rows, R) uint8 array
        Distance estimate per reception, whole mm (kilolib's ``estimate_distance``).
    losses : (rows, R) uint8 array or None
        Loss code per reception (:data:`CAUSES`; 0 delivered), ``None`` if nothing is lost.
    """

    estimates: np.ndarray
    losses: np.ndarray | None


class ReceptionModel(ABC):
    """Interface of a reception model; see the module docstring."""

    @abstractmethod
    def draw(
        self,
        sender: int,
        receivers: np.ndarray,
        distance_mm: np.ndarray,
        shares: LossShares,
        rows: int,
    ) -> Outcomes:
        """Outcomes of ``sender``'s next ``rows`` transmissions to ``receivers`` (robot
        indices) at true ``distance_mm``; ``sender`` is -1 for a message from outside the
        swarm (:meth:`kilonet.medium.InfraredMedium.arrive`)."""


class GaussianRanging(ReceptionModel):
    """Distance estimates with Gaussian noise and a per-robot bias; independent losses.

    Parameters
    ----------
    params : Params
        The run's parameters (``ranging`` and ``medium.loss_prob``).
    n_robots : int
        Swarm size (one bias per robot).
    ranging_rng, loss_rng : numpy.random.Generator
        The run's ``ranging`` and ``medium`` streams.
    """

    def __init__(
        self,
        params: Params,
        n_robots: int,
        ranging_rng: np.random.Generator,
        loss_rng: np.random.Generator,
    ) -> None:
        self.ranging = params.ranging
        self._ranging_rng = ranging_rng
        self._loss_rng = loss_rng
        sigma = self.ranging.bias_sigma_mm
        #: Each robot's ranging bias as a receiver, mm.
        self.bias_mm = ranging_rng.normal(0.0, sigma, n_robots) if sigma else np.zeros(n_robots)

    def estimates(self, receivers: np.ndarray, distance_mm: np.ndarray, rows: int) -> np.ndarray:
        """Estimates (whole mm, uint8) of ``rows`` receptions per receiver."""
        rg = self.ranging
        est = self._ranging_rng.standard_normal((rows, len(receivers)))
        est *= rg.sigma_mm
        est += distance_mm + self.bias_mm[receivers] + 0.5  # + 0.5, then truncation: rounding
        np.clip(est, rg.min_mm, rg.max_mm + 0.5, out=est)
        return est.astype(np.uint8)

    def loss_probability(self, shares: LossShares, distance_mm: np.ndarray) -> np.ndarray:
        """Cumulative thresholds per receiver, one row per cause in :data:`CAUSES` order: a
        uniform draw below row ``c`` loses the reception to the first cause whose threshold it
        is under. Override to make the random share depend on distance."""
        random = np.full(len(distance_mm), shares.random)
        return np.cumsum([random, shares.occlusion, shares.battery, shares.fault], axis=0)

    def draw(
        self,
        sender: int,
        receivers: np.ndarray,
        distance_mm: np.ndarray,
        shares: LossShares,
        rows: int,
    ) -> Outcomes:
        estimates = self.estimates(receivers, distance_mm, rows)
        thresholds = self.loss_probability(shares, distance_mm)
        if not thresholds.any():
            return Outcomes(estimates, None)
        u = self._loss_rng.random((rows, len(receivers)))
        codes = np.zeros(u.shape, dtype=np.uint8)
        for code in range(len(thresholds), 0, -1):  # the first cause a draw falls under wins
            codes[u < thresholds[code - 1]] = code
        return Outcomes(estimates, codes)
