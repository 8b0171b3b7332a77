"""The links a placement's robots may have: drawn as the medium draws them, many times.

A run's links are not a function of the placement alone. Each Kilobot has its own emitter
strength and receiver sensitivity (so its own reach, and links that work one way only), its own
calibration tables (so every link has its own ranging bias), and near the edge of a link's reach
only a share of the receptions arrive (:mod:`kilonet.radio`). A run draws these once from its
seed; real robots nobody has measured are one more draw. :func:`draw_held_estimates` draws them
again, with the kernel's own functions and the run's parameters, and gives the distances the
robots' neighbour tables would hold under that draw
(:func:`kilonet.scenarios.neighbourhood.held_estimates_of_links`), which
:func:`kilonet.scenarios.prediction.predict_from_seeds` turns into a prediction.

What one draw draws:

* each robot's transceiver (:meth:`kilonet.radio.Transceivers.draw`): every directed link's
  reach, shortened by the bodies on its line of sight under ``medium.occlusion = "graded"``;
* each robot's calibration tables (:func:`kilonet.ranging.calibration_tables`; kept as they are
  when ``ranging.calibration_file`` names the robots' own), and from them and the emitters the
  reception model (:func:`kilonet.reception.reception_model`), whose noise-free estimates are
  each link's systematic error;
* whether each directed link is in the receiver's table: a message on it arrives with
  probability ``q``, one less the loss the reception model draws it against
  (:meth:`kilonet.reception.GaussianRanging.loss_probability` of the soft edge's share,
  :func:`kilonet.radio.reception_probability`, occlusion and ``medium.loss_prob``), and the
  link is there if any of the ``k`` messages the sender offers before phase 3
  (:func:`messages_before_frames`) arrives: ``1 - (1 - q)**k``.

Collisions are not drawn (they thin the messages a link carries but take none away for good),
nor is the phase-2 election: the seeds are those of the run the caller simulated.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from kilonet.medium import directed_links
from kilonet.radio import MIN_RECEPTION, Transceivers, reach_of, reception_probability
from kilonet.ranging import calibration_tables, read_calibration
from kilonet.reception import LossShares, ModelContext, reception_model
from kilonet.scenarios.neighbourhood import held_estimates_of_links
from kilonet.visibility import LinkModel

if TYPE_CHECKING:
    from kilonet.params import Params

__all__ = ["draw_held_estimates", "link_present_probability", "messages_before_frames"]


def messages_before_frames(params: Params) -> int:
    """How many messages a robot offers before phase 3 starts, at least 1: phases 1 and 2's
    windows (``gcs.ids_s``, the elections and checks) over ``robot.tx_period_s``. Phase 3's
    seeds ask for the tables as they stand then, and the references and first fixes are
    decided from them."""
    from kilonet.protocols.gcs.phase1_unique_ids import UniqueIds
    from kilonet.protocols.gcs.phase2_seed_election import SeedElection

    gcs = params.scenario
    window_s = UniqueIds.window_s(gcs) + SeedElection.window_s(gcs)
    return max(1, int(window_s / params.robot.tx_period_s))


def link_present_probability(delivered: np.ndarray, messages: int) -> np.ndarray:
    """The probability that a link which delivers each message with probability
    ``delivered`` is heard at least once in ``messages`` messages: ``1 - (1 - delivered) **
    messages``.

    Examples
    --------
    >>> link_present_probability(np.array([0.0, 0.05, 0.5, 1.0]), 40).round(3).tolist()
    [0.0, 0.871, 1.0, 1.0]
    """
    return 1.0 - (1.0 - np.asarray(delivered, dtype=float)) ** messages


def draw_held_estimates(
    positions_mm: np.ndarray,
    params: Params,
    rng: np.random.Generator,
    *,
    radius_mm: float,
    messages: int,
) -> np.ndarray:
    """One draw of the distances the robots at ``positions_mm`` (mm) would hold in their
    neighbour tables, an ``(n, n)`` matrix as
    :func:`kilonet.scenarios.neighbourhood.held_estimates_mm` gives it (``[sender,
    receiver]``, mm, NaN where not held), with new robots drawn from ``rng``.

    ``params`` are the run's (``medium``, ``ranging`` and ``gcs.neighbour_max_mm``),
    ``radius_mm`` the robots' body radius (occlusion), ``messages`` the messages each link has
    to be heard (:func:`messages_before_frames`).

    Raises
    ------
    kilonet.params.ParamError
        If ``ranging.model`` or ``ranging.calibration_file`` cannot be used (as a run would).
    """
    n = len(positions_mm)
    medium = params.medium
    radio = Transceivers.draw(n, reach_of(medium), medium.tx_strength_sd, rng)
    tables = calibration_tables(n, rng)
    if params.ranging.calibration_file:
        tables = read_calibration(params.ranging.calibration_file, n)
    model = reception_model(ModelContext(params, n, rng, rng, tables, radio))
    link_model = LinkModel.from_params(medium, radius_mm, range_mm=radio.max_distance_mm)
    sender, receiver, distance, reach, loss = directed_links(link_model, radio, positions_mm)
    signal = reception_probability(distance, reach, radio.reach.edge_mm)
    none = np.zeros(len(sender))
    shares = LossShares(medium.loss_prob, loss, none, none, 1.0 - signal)
    lost = model.loss_probability(shares, distance)[-1] if len(sender) else none
    delivered = np.clip(1.0 - lost, 0.0, 1.0)
    heard = (signal >= MIN_RECEPTION) & (
        rng.random(len(sender)) < link_present_probability(delivered, messages)
    )
    return held_estimates_of_links(
        model,
        params.ranging.intensity_noise,
        n,
        list(zip(sender[heard].tolist(), receiver[heard].tolist(), strict=True)),
        distance[heard],
        params.scenario.neighbour_max_mm,
    )
