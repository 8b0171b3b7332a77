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

Two models come with kilonet (``ranging.model``):

* :class:`TableRanging` (``tables``, the default): each reception's intensity is the sender's
  emitter strength (:mod:`kilonet.radio`) times the receiver's gain times the intensity at the
  true distance, with relative noise ``ranging.intensity_noise``; the receiver turns its ADC
  readings into millimetres with kilolib's ``estimate_distance`` on its own calibration tables
  (:mod:`kilonet.ranging`). So every link has its own systematic error (a strong emitter looks
  near), repeated readings scatter under a millimetre, and estimates saturate beyond the tables
  as on the robot.
* :class:`GaussianRanging` (``gaussian``): ``round(true distance + receiver bias + N(0,
  sigma))``, each receiver with a bias ``N(0, bias_sigma_mm)`` drawn once: independent errors
  that averaging removes.

Both clip to kilolib's uint8 ``[min_mm, max_mm]`` and lose receptions independently with the
per-link and per-receiver shares the medium passes in. Subclass one and override
:meth:`GaussianRanging.loss_probability` for another loss, or :meth:`GaussianRanging.estimates`
for another ranging model. Name it in ``ranging.model`` as ``"package.module:Class"`` (the
class's :meth:`~GaussianRanging.from_context` builds it from the run's parameters, size and
random streams, so it works from ``kilonet run``, TOML files and sweeps, seeded like the rest),
or pass an instance to :class:`kilonet.simulation.Simulation` (``reception=``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from kilonet.params import Params
    from kilonet.radio import Transceivers
    from kilonet.ranging import CalibrationTables, ReadingLookup, TableLookup

__all__ = [
    "CAUSES",
    "GaussianRanging",
    "LossShares",
    "ModelContext",
    "Outcomes",
    "ReceptionModel",
    "TableRanging",
    "reception_model",
]

#: Loss codes of an outcome row, by cause (0: delivered). The medium counts each cause per
#: receiving robot as ``lost_<cause>``; ``signal`` is a reception too weak to decode, near the
#: edge of its link's reach (:mod:`kilonet.radio`).
CAUSES = {1: "random", 2: "occlusion", 3: "battery", 4: "fault", 5: "signal"}
RANDOM, OCCLUSION, BATTERY, FAULT, SIGNAL = 1, 2, 3, 4, 5


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
    signal : (R,) array
        Receptions too weak to decode: ``1 -`` the link's reception probability at its
        distance (:func:`kilonet.radio.reception_probability`).
    """

    random: float
    occlusion: np.ndarray
    battery: np.ndarray
    fault: np.ndarray
    signal: np.ndarray


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


@dataclass(frozen=True)
class ModelContext:
    """What a reception model may be built from: the run's parameters and size, its own random
    streams, and the robots' hardware.

    Attributes
    ----------
    params : Params
        The run's parameters.
    n_robots : int
        Swarm size.
    ranging_rng, loss_rng : numpy.random.Generator
        The run's ``ranging`` and ``medium`` streams.
    tables : list of CalibrationTables
        Each robot's calibration tables (``kilo_irhigh``, ``kilo_irlow``) and receiver gain.
    transceivers : Transceivers
        Each robot's emitter strength and receiver sensitivity.
    """

    params: Params
    n_robots: int
    ranging_rng: np.random.Generator
    loss_rng: np.random.Generator
    tables: list[CalibrationTables]
    transceivers: Transceivers


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
        swarm (:func:`kilonet.testing.outside.arrive`)."""


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
        # sender -> (shares, distances, thresholds or None) as last computed
        self._loss_cache: dict[int, tuple[LossShares, np.ndarray, np.ndarray | None]] = {}

    @classmethod
    def from_context(cls, context: ModelContext) -> GaussianRanging:
        """The model for a run (how ``ranging.model`` builds it)."""
        return cls(context.params, context.n_robots, context.ranging_rng, context.loss_rng)

    def effective_sigma_mm(
        self, distance_mm: np.ndarray, samples: np.ndarray | float = 1.0
    ) -> np.ndarray:
        """The error of a link's distance estimate averaged over ``samples`` receptions, as a
        standard deviation over links at ``distance_mm`` (mm): what averaging cannot remove
        (here the receiver's bias) plus the per-reception noise and rounding divided by the
        samples. The scenarios' Cramér–Rao bounds use it.

        Examples
        --------
        >>> from kilonet.params import Params
        >>> rng = np.random.default_rng(0)
        >>> p = Params().with_overrides({"ranging.sigma_mm": 1.0, "ranging.bias_sigma_mm": 2.0})
        >>> GaussianRanging(p, 2, rng, rng).effective_sigma_mm(np.array([50.0]), 4).round(3)
        array([2.067])
        """
        d = np.atleast_1d(np.asarray(distance_mm, dtype=float))
        per_reading = self.ranging.sigma_mm**2 + 1 / 12
        variance = self.ranging.bias_sigma_mm**2 + per_reading / np.asarray(samples, dtype=float)
        return np.sqrt(np.broadcast_to(variance, d.shape))

    def estimates(
        self, sender: int, receivers: np.ndarray, distance_mm: np.ndarray, rows: int
    ) -> np.ndarray:
        """Estimates (whole mm, uint8) of ``rows`` receptions per receiver of ``sender``
        (-1: a sender outside the swarm)."""
        rg = self.ranging
        est = self._ranging_rng.standard_normal((rows, len(receivers)))
        est *= rg.sigma_mm
        est += distance_mm + self.bias_mm[receivers] + 0.5  # + 0.5, then truncation: rounding
        np.clip(est, rg.min_mm, rg.max_mm + 0.5, out=est)
        return est.astype(np.uint8)

    def noise_free_mm(
        self, senders: np.ndarray, receivers: np.ndarray, distance_mm: np.ndarray
    ) -> np.ndarray:
        """The estimates links ``senders[k]`` -> ``receivers[k]`` give at true
        ``distance_mm[k]`` without noise, mm: here the true distance plus the receiver's bias
        (neither rounded nor clipped). Scenarios judge protocols by it, for many links at once.
        """
        return np.asarray(distance_mm, dtype=float) + self.bias_mm[receivers]

    def loss_probability(self, shares: LossShares, distance_mm: np.ndarray) -> np.ndarray:
        """Cumulative thresholds per receiver, one row per cause in :data:`CAUSES` order: a
        uniform draw below row ``c`` loses the reception to the first cause whose threshold it
        is under. Override to make the random share depend on distance."""
        random = np.full(len(distance_mm), shares.random)
        return np.cumsum(
            [random, shares.occlusion, shares.battery, shares.fault, shares.signal], axis=0
        )

    def _thresholds(
        self, sender: int, shares: LossShares, distance_mm: np.ndarray
    ) -> np.ndarray | None:
        """:meth:`loss_probability` of ``sender``'s links, or ``None`` if nothing can be lost;
        computed again only when the medium passes other shares or distances (it passes the
        same objects while a sender's receiver list and loss shares stand)."""
        cached = self._loss_cache.get(sender)
        if cached is not None and cached[0] is shares and cached[1] is distance_mm:
            return cached[2]
        thresholds = self.loss_probability(shares, distance_mm)
        if not thresholds.any():
            thresholds = None
        self._loss_cache[sender] = (shares, distance_mm, thresholds)
        return thresholds

    def draw(
        self,
        sender: int,
        receivers: np.ndarray,
        distance_mm: np.ndarray,
        shares: LossShares,
        rows: int,
    ) -> Outcomes:
        estimates = self.estimates(sender, receivers, distance_mm, rows)
        thresholds = self._thresholds(sender, shares, distance_mm)
        if thresholds is None:
            return Outcomes(estimates, None)
        u = self._loss_rng.random((rows, len(receivers)))
        codes = np.zeros(u.shape, dtype=np.uint8)
        for code in range(len(thresholds), 0, -1):  # the first cause a draw falls under wins
            codes[u < thresholds[code - 1]] = code
        return Outcomes(estimates, codes)


class TableRanging(GaussianRanging):
    """kilolib's distance estimate from each reception's intensity, on the receiver's tables.

    Parameters
    ----------
    params, n_robots, ranging_rng, loss_rng
        As :class:`GaussianRanging` (whose losses it shares).
    tables : list of CalibrationTables
        Each robot's calibration tables and receiver gain.
    strength : (N,) array
        Each robot's emitter strength, relative (:class:`kilonet.radio.Transceivers`); a sender
        outside the swarm emits at 1.
    """

    def __init__(
        self,
        params: Params,
        n_robots: int,
        ranging_rng: np.random.Generator,
        loss_rng: np.random.Generator,
        *,
        tables: list[CalibrationTables],
        strength: np.ndarray,
    ) -> None:
        super().__init__(params, n_robots, ranging_rng, loss_rng)
        self._irhigh = np.array([t.irhigh for t in tables], dtype=np.int64)
        self._irlow = np.array([t.irlow for t in tables], dtype=np.int64)
        self._lookup: TableLookup | None = None  # built at the first draw
        # the clipped estimate of each robot's reading pairs, built at the first draw
        self._readings: ReadingLookup | None = None
        # sender -> (receivers, distances, mean intensity per link) as last computed
        self._mean_cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._gain = np.array([t.gain for t in tables])
        self._strength = np.asarray(strength, dtype=float)
        self._strength_sd = params.medium.tx_strength_sd

    @classmethod
    def from_context(cls, context: ModelContext) -> TableRanging:
        return cls(
            context.params,
            context.n_robots,
            context.ranging_rng,
            context.loss_rng,
            tables=context.tables,
            strength=context.transceivers.strength,
        )

    def estimates(
        self, sender: int, receivers: np.ndarray, distance_mm: np.ndarray, rows: int
    ) -> np.ndarray:
        from kilonet.ranging import intensity, readings

        rg = self.ranging
        cached = self._mean_cache.get(sender)
        if cached is not None and cached[0] is receivers and cached[1] is distance_mm:
            mean = cached[2]
        else:
            strength = 1.0 if sender < 0 else self._strength[sender]
            gap = np.maximum(distance_mm - 33.0, 0.0)
            mean = strength * self._gain[receivers] * intensity(gap)
            self._mean_cache[sender] = (receivers, distance_mm, mean)
        noise = self._ranging_rng.standard_normal((rows, len(receivers)))
        noise *= rg.intensity_noise
        noise += 1.0
        high, low = readings(np.maximum(noise * mean, 0.0))
        if self._readings is None:
            from kilonet.ranging import ReadingLookup

            self._readings = ReadingLookup(self._table_lookup(), rg.min_mm, rg.max_mm)
        return self._readings.estimates(np.rint(high), np.rint(low), receivers)

    def _table_lookup(self) -> TableLookup:
        """The swarm's tables as a look-up (:class:`kilonet.ranging.TableLookup`), built at the
        first use."""
        from kilonet.ranging import TableLookup

        if self._lookup is None:
            self._lookup = TableLookup(self._irhigh, self._irlow)
        return self._lookup

    def systematic_mm(self, sender: int, receiver: int, distance_mm: float) -> float:
        """The estimate the link from ``sender`` to ``receiver`` gives at ``distance_mm``
        without noise, mm: its systematic error is this minus the true distance."""
        est = self.noise_free_mm(np.array([sender]), np.array([receiver]), [float(distance_mm)])
        return float(est[0])

    def noise_free_mm(
        self, senders: np.ndarray, receivers: np.ndarray, distance_mm: np.ndarray
    ) -> np.ndarray:
        """:meth:`systematic_mm` of many links at once: links ``senders[k]`` ->
        ``receivers[k]`` at true ``distance_mm[k]``, mm (each the same as on its own: the
        arithmetic is element by element)."""
        return self._noiseless(
            self._strength[senders], receivers, np.asarray(distance_mm, dtype=float)
        )

    def _noiseless(
        self, strength: np.ndarray, receivers: np.ndarray, distance_mm: np.ndarray
    ) -> np.ndarray:
        """Estimates without intensity noise of links of emitter ``strength[k]`` to receiver
        ``receivers[k]`` at ``distance_mm[k]``, mm (clipped like every estimate)."""
        from kilonet.ranging import intensity, readings

        gap = np.maximum(distance_mm - 33.0, 0.0)
        high, low = readings(strength * self._gain[receivers] * intensity(gap))
        est = self._table_lookup().estimates(np.rint(high), np.rint(low), receivers)
        return np.clip(est, self.ranging.min_mm, self.ranging.max_mm).astype(float)

    def effective_sigma_mm(
        self, distance_mm: np.ndarray, samples: np.ndarray | float = 1.0
    ) -> np.ndarray:
        """As :meth:`GaussianRanging.effective_sigma_mm`. The systematic part is the rms error
        of noiseless estimates over emitters of the model's strength spread and this swarm's
        receivers (a fixed sample of 256 links per distance, drawn apart from the run's
        streams); the noise part is ``(25 mm + gap) / 2 * intensity_noise`` (the inverse
        square law's sensitivity, inside the tables) and rounding, divided by the samples."""
        d = np.atleast_1d(np.asarray(distance_mm, dtype=float))
        rng = np.random.default_rng(0)
        strength = np.exp(self._strength_sd * rng.standard_normal(256))
        receivers = rng.integers(len(self._gain), size=256)
        grid, where = np.unique(np.round(d), return_inverse=True)
        rms = np.array(
            [
                np.sqrt(np.mean((self._noiseless(strength, receivers, np.full(256, g)) - g) ** 2))
                for g in grid
            ]
        )
        noise = (25.0 + np.maximum(d - 33.0, 0.0)) / 2 * self.ranging.intensity_noise
        return np.sqrt(rms[where] ** 2 + (noise**2 + 1 / 12) / np.asarray(samples))


#: The reception models ``ranging.model`` names.
BUILTIN_MODELS: dict[str, type[GaussianRanging]] = {
    "tables": TableRanging,
    "gaussian": GaussianRanging,
}


def reception_model(context: ModelContext) -> ReceptionModel:
    """The reception model ``ranging.model`` names, built for a run: a built-in name, or
    ``"package.module:Name"`` for a class (or function) taking a :class:`ModelContext`
    through ``from_context`` (or as its one argument).

    Raises
    ------
    kilonet.params.ParamError
        If the name cannot be imported or does not give a :class:`ReceptionModel`.
    """
    name = context.params.ranging.model
    if name in BUILTIN_MODELS:
        return BUILTIN_MODELS[name].from_context(context)
    from kilonet.params import ParamError, load_object

    factory = load_object(name, "ranging.model")
    build = getattr(factory, "from_context", factory)
    model = build(context)
    if not isinstance(model, ReceptionModel):
        raise ParamError(
            f"ranging.model = {name!r} gave {type(model).__name__}, not a ReceptionModel"
        )
    return model
