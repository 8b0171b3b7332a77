"""CPU time of the test kit's scripted tests (kilonet.testing), per test.

Three tests, each run ``--tests`` times per batch, ``--repeat`` batches, the fastest batch
reported (the least disturbed by the rest of the machine):

* ``single``: the ten-line gradient test of docs/testing.md, one robot in a scripted world
  (two scripted messages, ``eventually``, ``assert_sent``, and ``never`` over 5 s: 7.6
  simulated seconds in all);
* ``neighbours``: the page's test with two Replay neighbours in the real medium (5 s);
* ``swarm``: ``run_swarm`` of the gradient on a 19-robot hex lattice until every robot knows
  its value.

Figures are CPU seconds (``time.process_time``), not wall time, which is noisy on a shared
machine.

    python benchmarks/bench_testkit.py [--tests 200] [--repeat 5]
"""

from __future__ import annotations

import argparse
import time

from kilonet.message import Layout
from kilonet.robot import Kilobot
from kilonet.testing import Replay, ScriptedWorld, run_swarm

GRADIENT = Layout("gradient", type=1, fields=[("gradient", "H")])


class MyGradient(Kilobot):
    """The user's gradient program of docs/testing.md."""

    def __init__(self, source=False):
        self.value = 0 if source else None

    def message_rx(self, message, distance_mm):
        heard = GRADIENT.unpack(message).gradient
        if self.value is None or heard + 1 < self.value:
            self.value = heard + 1

    def message_tx(self):
        return None if self.value is None else GRADIENT.pack(gradient=self.value)


def single() -> None:
    world = ScriptedWorld(MyGradient(), layouts=[GRADIENT])
    world.hear(GRADIENT.pack(gradient=4), at_s=0.5, distance_mm=70, sender="far")
    world.hear(GRADIENT.pack(gradient=2), at_s=1.0, distance_mm=45, sender="near")
    world.advance(0.6)
    assert world.robot.value == 5
    world.eventually(lambda: world.robot.value == 3, within_s=1.0)
    world.assert_sent(GRADIENT, within_s=1.0, gradient=3)
    world.never(lambda: world.robot.value != 3, for_s=5.0)


def neighbours() -> None:
    world = ScriptedWorld(MyGradient(), layouts=[GRADIENT], seed=2)
    world.add_neighbour(Replay.every(GRADIENT.pack(gradient=4)), distance_mm=70)
    world.add_neighbour(
        Replay.every(GRADIENT.pack(gradient=1), from_s=3.0), distance_mm=40, bearing_deg=120
    )
    world.advance(2.9)
    assert world.robot.value == 5
    world.eventually(lambda: world.robot.value == 2, within_s=2.0)


def swarm() -> None:
    result = run_swarm(
        lambda i: MyGradient(source=i == 0),
        "hex",
        robots=19,
        stop_when=lambda robots: all(r.value is not None for r in robots),
    )
    assert result.stopped


def per_test_s(test, tests: int, repeat: int) -> float:
    """Fastest batch's CPU seconds per test."""
    test()  # warm up: imports, first allocations
    best = float("inf")
    for _ in range(repeat):
        start = time.process_time()
        for _ in range(tests):
            test()
        best = min(best, (time.process_time() - start) / tests)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tests", type=int, default=200, help="tests per batch")
    parser.add_argument("--repeat", type=int, default=5, help="batches; the fastest counts")
    args = parser.parse_args()
    print(f"CPU time per test, fastest of {args.repeat} batches of {args.tests} tests:")
    for name, test, tests in (
        ("single", single, args.tests),
        ("neighbours", neighbours, args.tests),
        ("swarm", swarm, max(1, args.tests // 10)),
    ):
        print(f"  {name:<11} {per_test_s(test, tests, args.repeat) * 1000:7.2f} ms")


if __name__ == "__main__":
    main()
