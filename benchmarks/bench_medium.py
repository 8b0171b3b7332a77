"""Medium throughput: hex lattices of 100, 1,000 and 5,000 robots, each offering a message at
every transmit opportunity (every 200 ms ± 20 ms, as the global coordinate system's thesis
library does), for 60 simulated seconds.

Prints, per size: simulated seconds per wall second (the real-time factor), deliveries per wall
second, the mean number of receivers per transmission, and the share of those receptions a
collision destroyed. Each size runs ``--repeat`` times
and the fastest run is reported (the least disturbed by whatever else the machine does; the
spread between repeats here is 10-20 %).

    python benchmarks/bench_medium.py [--sizes 100 1000 5000] [--sim-s 60] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kilonet import Kilobot, Message, Params, Simulation
from kilonet.scenarios.placement import hex_lattice


class Chatter(Kilobot):
    """Offers the same 9-byte message at every opportunity and counts what it hears."""

    MESSAGE = Message(bytes(9), 1)

    def setup(self) -> None:
        self.heard = 0

    def message_tx(self) -> Message:
        return self.MESSAGE

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.heard += 1


def run_one(n: int, sim_s: float, seed: int = 1) -> dict[str, float]:
    """Run ``n`` chatting robots for ``sim_s`` simulated seconds; return the figures."""
    rng = np.random.default_rng(seed)
    positions = hex_lattice(n, spacing_mm=40.0, jitter_mm=3.0, rng=rng)
    params = Params(seed=seed, duration_s=sim_s).with_overrides(
        {"robot.tx_period_s": 0.2, "robot.tx_jitter_s": 0.02, "battery.enabled": False}
    )
    build_started = time.perf_counter()
    sim = Simulation(positions, Chatter, params)
    build_s = time.perf_counter() - build_started
    sim.run()
    s = sim.summary()
    wall = sim.wall_time_s
    return {
        "robots": n,
        "build_s": build_s,
        "wall_s": wall,
        "realtime_x": sim_s / wall,
        "deliveries_per_s": s["receptions_delivered"] / wall,
        "receivers_per_msg": (s["receptions_delivered"] + s["lost_collision"]) / s["messages_sent"],
        # of the receptions that reached a receiver, the share a collision destroyed (<= 100 %)
        "collision_share": s["lost_collision"]
        / max(1, s["receptions_delivered"] + s["lost_collision"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 5000])
    parser.add_argument("--sim-s", type=float, default=60.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rows = [
        min((run_one(n, args.sim_s) for _ in range(args.repeat)), key=lambda r: r["wall_s"])
        for n in args.sizes
    ]
    print(
        f"{'robots':>7} {'build s':>8} {'wall s':>8} {'x real time':>12} {'deliveries/s':>13} "
        f"{'rx/msg':>7} {'collided':>9}"
    )
    for r in rows:
        print(
            f"{r['robots']:>7} {r['build_s']:>8.2f} {r['wall_s']:>8.2f} {r['realtime_x']:>12.1f} "
            f"{r['deliveries_per_s']:>13,.0f} {r['receivers_per_msg']:>7.1f} "
            f"{r['collision_share']:>9.2%}"
        )
    by_n = {r["robots"]: r for r in rows}
    if 1000 in by_n and 5000 in by_n:
        ratio = by_n[5000]["wall_s"] / by_n[1000]["wall_s"]
        print(f"wall time 5,000 / 1,000 robots: {ratio:.2f}x (linear would be 5x)")


if __name__ == "__main__":
    main()
