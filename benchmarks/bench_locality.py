"""What this machine charges for touching robots in random order: the floor under the medium.

A transmission must reach each of its receivers' state (carrier sense: is it busy? mark it
busy) and call each receiver's handler, a bound method of a robot object. Senders follow each
other in time order, which is random in space, so their receivers' state is scattered over
the whole swarm's memory. This benchmark does exactly that work and nothing else (no SimPy, no
medium, no random draws): hex lattices of 1,000 and 5,000 robots at 40 mm spacing, receivers
within 85 mm (``scipy.spatial.cKDTree``), a million transmissions, senders drawn at random or
taken in index order. If the random-order cost per transmission grows with the swarm while the
in-order cost grows less, the growth is the memory hierarchy's, and it bounds from below how
linearly any simulator that keeps per-robot state in Python objects can scale here. (Index
order is ring by ring around the lattice's centre, so receivers are near each other in memory
but not side by side.) It also times SimPy's event queue alone: one reusable timer per robot,
each rescheduling itself every 200 ± 10 ms, the medium's offer pattern.

    python benchmarks/bench_locality.py [--sizes 1000 5000] [--transmissions 1000000]
                                        [--repeat 3] [--work both|busy|calls]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

from kilonet.clock import KernelEnvironment, Timer
from kilonet.scenarios.placement import hex_lattice


class Receiver:
    """A robot's receiving side, as small as a program's can be: it counts what it hears."""

    def __init__(self) -> None:
        self.heard = 0

    def message_rx(self, message: object, distance_mm: int) -> None:
        self.heard += 1


def cost_per_transmission_ns(
    n: int, transmissions: int, *, random_order: bool, busy: bool = True, calls: bool = True
) -> tuple[float, float]:
    """Wall ns per transmission (mark each receiver busy, call its handler; ``busy`` and
    ``calls`` leave out either) and the mean number of receivers per transmission."""
    rng = np.random.default_rng(1)
    positions = hex_lattice(n, spacing_mm=40.0, jitter_mm=3.0, rng=rng)
    tree = cKDTree(positions)
    receivers = [
        [j for j in near if j != i] for i, near in enumerate(tree.query_ball_tree(tree, 85.0))
    ]
    robots = [Receiver() for _ in range(n)]
    handlers = [[robots[j].message_rx for j in rs] for rs in receivers]
    busy_until = [0.0] * n
    marked = receivers if busy else [[] for _ in range(n)]
    called = handlers if calls else [[] for _ in range(n)]
    senders = (
        rng.integers(0, n, transmissions) if random_order else np.arange(transmissions) % n
    ).tolist()
    now, end = 1.0, 1.5
    started = time.perf_counter()
    for s in senders:
        for r in marked[s]:
            if busy_until[r] > now:  # the medium's carrier check and collision test
                pass
            busy_until[r] = end
        for handler in called[s]:
            handler(None, 40)
    wall_ns = (time.perf_counter() - started) / transmissions * 1e9
    return wall_ns, sum(map(len, receivers)) / n


def event_queue_ns(n: int, events: int) -> float:
    """Wall ns per event of the kernel's event queue holding one self-rescheduling timer per
    robot."""
    env = KernelEnvironment()
    delays = (0.19 + 0.02 * np.random.default_rng(1).random(events + n)).tolist()
    next_delay = iter(delays).__next__

    def reschedule(timer: Timer) -> None:
        timer.schedule(next_delay())

    for i in range(n):
        Timer(env, reschedule, i).schedule(next_delay())
    until = events * 0.2 / n
    started = time.perf_counter()
    env.run(until=until)
    return (time.perf_counter() - started) / events * 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000])
    parser.add_argument("--transmissions", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument(
        "--work",
        choices=["both", "busy", "calls"],
        default="both",
        help="per receiver: mark it busy and call its handler (both), or only one of them",
    )
    args = parser.parse_args()
    work = {"busy": args.work != "calls", "calls": args.work != "busy"}
    print(f"{'robots':>7} {'order':>8} {'ns / transmission':>18} {'receivers':>10}")
    best: dict[tuple[int, bool], float] = {}
    for random_order in (False, True):
        for n in args.sizes:
            best[n, random_order], receivers = min(
                cost_per_transmission_ns(n, args.transmissions, random_order=random_order, **work)
                for _ in range(args.repeat)
            )
            order = "random" if random_order else "in order"
            print(f"{n:>7} {order:>8} {best[n, random_order]:>18,.0f} {receivers:>10.1f}")
    queue = {
        n: min(event_queue_ns(n, args.transmissions) for _ in range(args.repeat))
        for n in args.sizes
    }
    for n in args.sizes:
        print(f"{n:>7} robots: SimPy event queue alone {queue[n]:,.0f} ns / event")
    if 1000 in args.sizes and 5000 in args.sizes:
        for random_order, order in ((False, "in order"), (True, "random")):
            ratio = 5 * best[5000, random_order] / best[1000, random_order]
            print(f"{order}: the same simulated time at 5,000 robots costs {ratio:.1f}x 1,000's")
        print(f"event queue: {5 * queue[5000] / queue[1000]:.1f}x")


if __name__ == "__main__":
    main()
