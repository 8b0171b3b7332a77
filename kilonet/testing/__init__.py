"""A test kit for Kilobot programs: unit tests on kilonet's own kernel.

Three ways to put a program to the test, each a real :class:`~kilonet.simulation.Simulation`
(the real robot runtime, clocks, transmit rules, receive modes and trace), never a stand-in:

* **One robot in a scripted world** (:class:`ScriptedWorld`): the program runs alone while
  the test decides what it hears (:meth:`~ScriptedWorld.hear`), and time moves only when the
  test says so (:meth:`~ScriptedWorld.advance`, :meth:`~ScriptedWorld.run_until`, in simulated
  seconds). The test reads back what it did: each message it sent, what it was handed, its LED
  colours and motor commands over time, the events it logged, its ``kilo_ticks``.
* **Scripted neighbours in a real medium** (:meth:`ScriptedWorld.add_neighbour` with
  :class:`Replay`, or any program): robots beside the one under test that talk through the
  medium, so its transmit periods, carrier sense, collisions, loss and distance noise apply.
* **A small swarm in one call** (:func:`run_swarm`): a program, a placement or named layout,
  parameters and a stop condition in; DataFrames and each robot's final state out.

**How a scripted message reaches the robot.** It is injected through the medium's own
reception path, :func:`kilonet.testing.outside.arrive`, from a sender outside the swarm,
rather than sent by a scripted robot standing on the table. A scripted robot would have to
wait for its transmit opportunities (the test could not choose the time to the millisecond),
its distance would come with ranging noise (the test could not choose the estimate), and its
body would stand in the way of a robot that drives. Through ``arrive`` the message still does
everything a reception does at the receiver: it must fit the payload limit, it occupies the
robot's channel for the airtime (the robot senses the carrier and defers its own message;
two scripted messages that overlap collide; one arriving while the robot transmits is lost),
a wrong CRC drops it, the medium's loss probability and the robot's battery and receiver
faults apply, and it reaches the program through its receive mode (``message_rx`` or the
polled buffer, the distance as an estimate or as raw readings), counted as any reception. The
robot's own side is observed through three small kernel seams (the medium's transmit source,
the simulation's reception listener, the motion's command listener), which never change what
the program does.

**Assertions that explain themselves.** :meth:`ScriptedWorld.eventually`,
:meth:`ScriptedWorld.never` and :meth:`ScriptedWorld.assert_sent` fail with the robot's last
states and the messages it heard and sent up to the deadline; :meth:`SwarmResult.assert_each`
names the robots that fail and their states. Misuse (time going backwards, a message too long
for the payload, an unknown robot) is a :class:`ScriptError` or a
:class:`~kilonet.message.PayloadError` that says what and where.

**Deterministic and fast.** A seed gives the same run; a single-robot scripted test takes a
few milliseconds (``python benchmarks/bench_testkit.py``).

The pytest plugin :mod:`kilonet.testing.plugin` (registered through the ``pytest11`` entry
point) provides the fixtures ``scripted_world`` and ``swarm``; Hypothesis strategies live in
:mod:`kilonet.testing.strategies`. ``docs/testing.md`` shows all three at work.

Examples
--------
A program that takes one more than the level it hears, beside a neighbour that keeps
announcing level 2 through the medium:

>>> from kilonet import Kilobot, Layout
>>> from kilonet.testing import Replay, ScriptedWorld
>>> LEVEL = Layout("level", type=1, fields=[("level", "B")])
>>> class Follow(Kilobot):
...     def message_rx(self, message, distance_mm):
...         self.level = LEVEL.unpack(message).level + 1
>>> world = ScriptedWorld(Follow())
>>> world.add_neighbour(Replay.every(LEVEL.pack(level=2)), distance_mm=60)
1
>>> t_s = world.eventually(lambda: getattr(world.robot, "level", None) == 3, within_s=1.0)
>>> world.heard()[0].sender, t_s < 0.51  # its first opportunity falls in the first 0.5 s
(1, True)
"""

from kilonet.lazy import lazy_exports

__all__ = [
    "Change",
    "Heard",
    "LoggedEvent",
    "Replay",
    "ScriptError",
    "ScriptedReception",
    "ScriptedWorld",
    "Sent",
    "SwarmResult",
    "build_params",
    "program_state",
    "run_swarm",
]

# Imported on first use: pytest imports kilonet.testing.plugin in every session.
__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        **dict.fromkeys(
            ["Change", "Heard", "LoggedEvent", "ScriptedReception", "Sent"],
            "kilonet.testing.record",
        ),
        "program_state": "kilonet.testing.record",
        "Replay": "kilonet.testing.replay",
        "ScriptError": "kilonet.testing.errors",
        "ScriptedWorld": "kilonet.testing.world",
        "SwarmResult": "kilonet.testing.swarm",
        "build_params": "kilonet.testing.world",
        "run_swarm": "kilonet.testing.swarm",
    },
    globals(),
)
