"""Phase 1 of ``localize``: one root per connected swarm, elected by flooding, and every
robot's hop count to it.

Each robot holds an election key, ``(255 - neighbours) << 24 | salt`` with a 24-bit random
salt, and floods the smallest key it knows with its hop count to that key's robot. Robots with
more neighbours win (an interior robot: a frame grows out of it in every direction, and its
neighbourhood offers good triangles to start from); ties go to the salt. A robot's key follows
its neighbour count for ``localize.listen_s`` and is fixed from then on.

The election ends by an echo over a tree rather than a window: every robot names a parent,
the neighbour one hop nearer K's robot it hears best
(:func:`~kilonet.protocols.localize.base.choose_parent`), and a robot's subtree is *complete* for
key K when every neighbour it has heard recently holds K and each neighbour that names it parent
reports complete (:func:`echo_complete`). Leaves are complete as soon as their neighbours hold
K; completeness climbs back to K's robot, which then knows that every robot of its swarm has
heard it — so a robot that only looked like the best (a smaller key had not reached it yet)
can never win: the robots next to the true best never complete its wave. The winner becomes
the root of the frame (:mod:`kilonet.protocols.localize.phase2_spread`); the others enter phase 2
when they first hear a phase-2 message. A robot holding the best key starts without the echo after
``localize.elect_timeout_s``.

IDs: a robot that hears its own ID from another robot draws a new one (while electing), so
IDs end up unique among neighbours.

Message (type 80 ELECT)::

    sender:uint16  key:uint32  hops:uint8 (bit 7: echo)  parent:uint16   9 bytes

Hop counts therefore end at :data:`MAX_HOPS` (126): a swarm whose robots lie farther from the
root than that saturates there and its convergecasts cannot finish (a robot still declares
itself done after ``localize.run_timeout_s``). After the election a robot sends ELECT again
only when its parent changes (a neighbour left, or joined late), so the new parent learns it.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from kilonet.message import Layout, Message
from kilonet.protocols.localize.base import (
    MAX_HOPS,
    NO_ID,
    Neighbour,
    children_complete,
    choose_parent,
)

if TYPE_CHECKING:
    from kilonet.protocols.localize.program import LocalizeRobot

__all__ = ["ELECT", "MAX_HOPS", "Election", "echo_complete", "election_key"]

ELECT = Layout(
    "elect",
    type=80,
    fields=[("sender", "H"), ("key", "I"), ("hops", "B"), ("parent", "H")],
)
#: Neighbour counts above this all rank alike in the key.
_MAX_COUNT = 255
#: ELECT's hops byte: the echo flag in the top bit, the hop count below it.
_ECHO_BIT = 0x80


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


def echo_complete(best_key: int, uid: int, neighbours: Iterable[Neighbour]) -> bool:
    """Whether the subtree of robot ``uid`` is complete for ``best_key``: every neighbour holds
    that key and each neighbour that names ``uid`` its parent reports its own subtree complete.

    Examples
    --------
    >>> a, b, c = Neighbour(1), Neighbour(2), Neighbour(3)
    >>> a.key = b.key = c.key = 9
    >>> b.parent = c.parent = 5
    >>> echo_complete(9, 5, [a, b, c])  # b and c report to robot 5, not complete yet
    False
    >>> b.echo = c.echo = True
    >>> echo_complete(9, 5, [a, b, c])
    True
    >>> c.key = 10  # c has not heard key 9 yet
    >>> echo_complete(9, 5, [a, b, c])
    False
    """
    neighbours = list(neighbours)
    return all(n.key == best_key for n in neighbours) and children_complete(uid, neighbours, _echo)


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
        hops = r.hops | (_ECHO_BIT if self.echo else 0)
        return ELECT.pack(sender=r.uid, key=r.root_key, hops=hops, parent=r.parent)

    @staticmethod
    def record(n: Neighbour, message: Message) -> bool:
        """Store what an ELECT says about its sender in ``n`` (key, hop count, echo, parent);
        return whether the key, echo or parent changed (news a convergecast waits for)."""
        m = ELECT.unpack(message)
        echo = m.hops >= _ECHO_BIT
        news = m.key != n.key or echo != n.echo or m.parent != n.parent
        n.key, n.hops, n.echo, n.parent = m.key, m.hops & ~_ECHO_BIT, echo, m.parent
        return news

    def message_rx(self, n: Neighbour, message: Message) -> bool:
        """Take in an ELECT (recorded in ``n``): a better key, or a shorter way to this one;
        return whether it brought news (:meth:`record`)."""
        news = self.record(n, message)
        r = self.robot
        if n.key < r.root_key:
            r.root_key, r.hops, self.echo = n.key, min(n.hops + 1, MAX_HOPS), False
        elif n.key == r.root_key and n.hops + 1 < r.hops:
            r.hops, self.echo = n.hops + 1, False
        return news

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
        if full:
            on_key = [n for n in fresh if n.key == r.root_key]
            r.parent = choose_parent(r.parent, r.hops, on_key)
        self.echo = echo_complete(r.root_key, r.uid, fresh)
        best = r.root_key == self.key
        if best and tick >= self.listen_until and (self.echo or tick >= self.timeout_tick):
            self.won = True
