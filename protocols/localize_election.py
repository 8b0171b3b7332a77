"""Phase 1 of ``localize``: one root per connected swarm, elected by flooding, and every
robot's hop count to it.

Each robot holds an election key, ``(255 - neighbours) << 24 | salt`` with a 24-bit random
salt, and floods the smallest key it knows with its hop count to that key's robot. Robots with
more neighbours win (an interior robot: a frame grows out of it in every direction, and its
neighbourhood offers good triangles to start from); ties go to the salt. A robot's key follows
its neighbour count for ``localize.listen_s`` and is fixed from then on.

The election ends by an echo over the hop structure rather than a window: a robot's
subtree is *complete* for key K when every neighbour it has heard recently holds K and each
neighbour one hop farther from K's robot reports complete (:func:`echo_complete`). Leaves are
complete as soon as their neighbours hold K; completeness climbs back to K's robot, which then
knows that every robot of its swarm has heard it — so a robot that only looked like the best
(a smaller key had not reached it yet) can never win: the robots next to the true best never
complete its wave. The winner becomes the root of the frame (:mod:`protocols.localize_spread`);
the others enter phase 2 when they first hear a phase-2 message. A robot holding the best key
starts without the echo after ``localize.elect_timeout_s``.

IDs: a robot that hears its own ID from another robot draws a new one (while electing), so
IDs end up unique among neighbours.

Message (type 80 ELECT)::

    sender:uint16  key:uint32  hops:uint8  echo:uint8 (0/1)   8 bytes
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from kilonet.message import Layout, Message
from protocols.localize_base import NO_ID, Neighbour, children_complete

if TYPE_CHECKING:
    from protocols.localize import LocalizeRobot

__all__ = ["ELECT", "MAX_HOPS", "Election", "echo_complete", "election_key"]

ELECT = Layout(
    "elect", type=80, fields=[("sender", "H"), ("key", "I"), ("hops", "B"), ("echo", "B")]
)
#: Neighbour counts above this all rank alike in the key.
_MAX_COUNT = 255
#: Hop counts saturate here (a uint8 field; 255 means unknown).
MAX_HOPS = 254


def election_key(neighbours: int, salt: int) -> int:
    """The election key of a robot with ``neighbours`` neighbours and a 24-bit ``salt``;
    the smallest key wins.

    Examples
    --------
    >>> election_key(12, 5) < election_key(11, 0)
    True
    >>> hex(election_key(0, 0xABCDEF))
    '0xffabcdef'
    """
    return ((_MAX_COUNT - min(neighbours, _MAX_COUNT)) << 24) | (salt & 0xFFFFFF)


def echo_complete(best_key: int, hops: int, neighbours: Iterable[Neighbour]) -> bool:
    """Whether a robot's subtree is complete for ``best_key``: every neighbour holds that key
    and each neighbour one hop farther out (``hops + 1``) reports its own subtree complete.

    Examples
    --------
    >>> a, b, c = Neighbour(1), Neighbour(2), Neighbour(3)
    >>> a.key = b.key = c.key = 9
    >>> a.hops, b.hops, c.hops = 0, 2, 2
    >>> echo_complete(9, 1, [a, b, c])  # b and c are farther out and not complete yet
    False
    >>> b.echo = c.echo = True
    >>> echo_complete(9, 1, [a, b, c])
    True
    >>> c.key = 10  # c has not heard key 9 yet
    >>> echo_complete(9, 1, [a, b, c])
    False
    """
    neighbours = list(neighbours)
    return all(n.key == best_key for n in neighbours) and children_complete(hops, neighbours, _echo)


def _echo(n: Neighbour) -> bool:
    return n.echo


class Election:
    """Phase 1 on one robot: its key, the best key it knows, and the echo.

    The robot's hop count (``robot.hops``) and the best key (``robot.root_key``) live on the
    robot: later phases use them.
    """

    name = "election"

    def __init__(self, robot: LocalizeRobot) -> None:
        self.robot = robot
        self.salt = int(robot.rand.integers(1 << 24))
        self.key = election_key(0, self.salt)
        self.echo = False
        self.won = False
        p = robot.params
        tps = robot.ticks_per_s
        self.listen_until = p.listen_s * tps
        self.timeout_tick = p.elect_timeout_s * tps
        robot.root_key = self.key
        robot.hops = 0

    def message_tx(self) -> Message:
        r = self.robot
        return ELECT.pack(sender=r.uid, key=r.root_key, hops=r.hops, echo=int(self.echo))

    def message_rx(self, n: Neighbour, message: Message) -> None:
        m = ELECT.unpack(message)
        n.key, n.hops, n.echo = m.key, m.hops, bool(m.echo)
        r = self.robot
        if m.key < r.root_key:
            r.root_key, r.hops, self.echo = m.key, min(m.hops + 1, MAX_HOPS), False
        elif m.key == r.root_key and m.hops + 1 < r.hops:
            r.hops, self.echo = m.hops + 1, False

    def heard_own_id(self) -> None:
        """Another robot uses this robot's ID: draw a new one."""
        r = self.robot
        old = r.uid
        while r.uid in (old, NO_ID) or r.uid in r.neighbours:
            r.uid = int(r.rand.integers(NO_ID))
        r.log("id", old=old, new=r.uid)

    def round(self, tick: int, fresh: list[Neighbour], *, full: bool = True) -> None:
        """Update the key (in a ``full`` round), the echo and whether this robot has won."""
        r = self.robot
        if full and tick < self.listen_until:
            self.key = min(self.key, election_key(len(fresh), self.salt))
        if self.key < r.root_key or (self.key == r.root_key and r.hops != 0):
            r.root_key, r.hops, self.echo = self.key, 0, False
        self.echo = echo_complete(r.root_key, r.hops, fresh)
        best = r.root_key == self.key
        if best and tick >= self.listen_until and (self.echo or tick >= self.timeout_tick):
            self.won = True
