"""Medium access: carrier sense, and collisions where receptions overlap.

Per robot the channel state is until when it is busy (the latest reception to begin there, or
its own transmission: all messages share one airtime, so the latest to begin ends last) and that
latest reception, to mark it when another overlaps it.

* **Carrier sense.** A robot senses a carrier while some reception is in progress *at it*,
  from ``sense_delay_s`` after the first of a run of overlapping receptions began there (a
  receiver needs a few bit times to tell a message from noise, so two senders that start
  within that delay of each other collide); it cannot hear senders out of its own range, so
  hidden terminals exist.
* **Collisions.** Two receptions that overlap in time at a receiver corrupt each other *there*
  (both fail the CRC); the same message may arrive cleanly elsewhere.
* **Half duplex.** A robot that starts transmitting while receiving ruins that reception, and
  whatever starts arriving while it transmits is lost too.

Examples
--------
>>> mac = Channel(3)
>>> class Tx:  # what the medium passes: anything with a ``corrupted`` set or None
...     corrupted = None
>>> a, b = Tx(), Tx()
>>> mac.occupy(a, 0, [1], now=0.0, end=0.003)
>>> mac.occupy(b, 2, [1], now=0.001, end=0.004)  # robot 2 cannot hear robot 0: both collide
>>> sorted(a.corrupted), sorted(b.corrupted), mac.busy(1, 0.002), mac.busy(1, 0.005)
([1], [1], True, False)
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["Channel"]


class Channel:
    """The carrier-sense and collision state of every robot of one medium."""

    __slots__ = ("busy_until", "last_rx", "sense_delay_s", "sensed_from")

    def __init__(self, n_robots: int, sense_delay_s: float = 0.0) -> None:
        #: Per robot: until when (s) its channel is busy.
        self.busy_until: list[float] = [-math.inf] * n_robots
        #: Per robot: from when (s) it senses the carrier of its current busy period.
        self.sensed_from: list[float] = [-math.inf] * n_robots
        #: Per robot: the latest transmission to begin arriving there.
        self.last_rx: list[Any] = [None] * n_robots
        self.sense_delay_s = sense_delay_s

    def busy(self, robot: int, now_s: float) -> bool:
        """Whether ``robot`` senses a carrier at ``now_s``."""
        return self.busy_until[robot] > now_s >= self.sensed_from[robot]

    def occupy(self, tx: Any, sender: int, receivers: list[int], now: float, end: float) -> None:
        """Put ``tx`` on the air from ``sender`` to ``receivers`` until ``end``; mark every
        reception it overlaps, and its own receptions that overlap others, as corrupted."""
        busy, last, sensed = self.busy_until, self.last_rx, self.sensed_from
        if busy[sender] > now:  # half duplex: the sender's own reception in progress is ruined
            _corrupt(last[sender], sender)
        clashes = None
        sensed_at = now + self.sense_delay_s
        for r in receivers:
            if busy[r] > now:
                # Overlap at r: both receptions fail there. Earlier overlapping receptions at r
                # were marked when the second of them began, so only the latest needs marking
                # (_corrupt inline: this runs for nearly half of all receptions).
                other = last[r]
                if other is not None:
                    if other.corrupted is None:
                        other.corrupted = {r}
                    else:
                        other.corrupted.add(r)
                if clashes is None:
                    clashes = {r}
                else:
                    clashes.add(r)
            else:
                sensed[r] = sensed_at
            busy[r] = end
            last[r] = tx
        tx.corrupted = clashes
        # Half duplex the other way round: while the sender transmits, whatever starts arriving
        # at it overlaps its channel and is lost there.
        if end > busy[sender]:
            if busy[sender] <= now:
                sensed[sender] = now  # its own transmission: no delay
            busy[sender] = end


def _corrupt(tx: Any, receiver: int) -> None:
    """Mark the reception of ``tx`` at ``receiver`` as failing its CRC."""
    if tx is None:
        return
    if tx.corrupted is None:
        tx.corrupted = {receiver}
    else:
        tx.corrupted.add(receiver)
