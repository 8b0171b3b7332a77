"""Messages from a sender outside the swarm: how :class:`~kilonet.testing.ScriptedWorld` makes a
robot hear what a test decides, through the medium's own reception path."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from kilonet.reception import CAUSES, RANDOM

if TYPE_CHECKING:
    from kilonet.message import Message
    from kilonet.simulation import Simulation

__all__ = ["arrive"]


def arrive(
    sim: Simulation,
    receiver: int,
    message: Message,
    distance_mm: float,
    *,
    estimate_mm: int | None = None,
    lose: bool = False,
) -> str | None:
    """A message from a sender outside the swarm begins arriving at ``receiver`` of ``sim`` now.

    The message goes through the same parts as any transmission, from ``receiver``'s side: it
    must fit the payload limit; it occupies the receiver's channel for the airtime (the
    receiver senses a carrier; it collides with whatever else arrives there meanwhile, and
    with the receiver's own transmission); the reception model gives its distance estimate at
    true ``distance_mm`` and whether it is lost, with the receiver's loss shares; a wrong CRC
    drops it. At the end of the airtime it reaches the receiver's port unless lost or
    collided, and the counters (and the trace, with sender -1) count it as any reception. A
    receiver that has stopped hears nothing.

    Parameters
    ----------
    sim : Simulation
        The run, started.
    receiver : int
        The robot that hears it.
    message : Message
        What arrives.
    distance_mm : float
        True centre-to-centre distance of the (imaginary) sender, mm.
    estimate_mm : int, optional
        The distance estimate the receiver gets (whole mm, 0-255) instead of the reception
        model's.
    lose : bool
        Lose the reception for sure (counted as ``lost_random``).

    Returns
    -------
    str or None
        ``"stopped"`` if the receiver has stopped; the cause the reception is lost to already
        (``"random"``, ``"crc"``, ...; see :data:`kilonet.counters.LOSS_CAUSES`); or ``None``:
        it is delivered at the end of the airtime unless it collides there.

    Raises
    ------
    kilonet.message.PayloadError
        If the message does not fit the payload limit.
    """
    medium = sim.medium
    medium.limit.check(message)
    if not sim.world.running[receiver]:
        return "stopped"
    outcome = medium.reception.draw(
        -1,
        np.array([receiver]),
        np.array([float(distance_mm)]),
        medium.outside_shares(receiver),
        1,
    )
    if not message.crc_ok:
        cause = "crc"
    elif lose:
        cause = CAUSES[RANDOM]
    else:
        code = 0 if outcome.losses is None else int(outcome.losses[0, 0])
        cause = CAUSES[code] if code else None
    estimate = int(outcome.estimates[0, 0]) if estimate_mm is None else estimate_mm
    medium.hear_from_outside(receiver, message, estimate, cause)
    return cause
