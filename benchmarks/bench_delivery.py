"""End of airtime: the cost of delivering one transmission whose receptions partly failed.

A 300-robot hex lattice (40 mm spacing, about 47 receivers per sender) is built and run for a
simulated second, then one sender's transmission is delivered again and again by
``InfraredMedium._end_of_airtime`` with a fixed share of its receptions collided and two lost
to a random loss; the receivers' ``message_rx`` does nothing, so what is timed is the medium's
own work plus one Python call per delivered reception. ``--against REV`` times the same
method of ``kilonet/medium.py`` at git revision ``REV`` in the same process, interleaved with
the checked-out one (the machine's load then weighs on both alike).

    python benchmarks/bench_delivery.py [--collided 0.4 0.1] [--against HEAD~1]
"""

from __future__ import annotations

import argparse
import importlib.util
import random
import subprocess
import sys
import tempfile
import timeit
from pathlib import Path
from types import ModuleType

import numpy as np

from kilonet import medium
from kilonet.message import Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.scenarios.placement import hex_lattice
from kilonet.simulation import Simulation


class Silent(Kilobot):
    """Offers one fixed message at every opportunity; ignores what it hears."""

    def setup(self) -> None:
        self.message = Message(bytes(2), 1)

    def message_tx(self) -> Message:
        return self.message

    def message_rx(self, message: Message, distance_mm: int) -> None:
        pass


def medium_at(rev: str) -> ModuleType:
    """``kilonet/medium.py`` as it was at git revision ``rev``, imported as its own module."""
    root = Path(__file__).resolve().parent.parent
    text = subprocess.run(
        ["git", "show", f"{rev}:kilonet/medium.py"],
        cwd=root,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    path = Path(tempfile.mkdtemp()) / "medium_at_rev.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("medium_at_rev", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--collided", type=float, nargs="+", default=[0.4, 0.1])
    parser.add_argument("--against", metavar="REV", help="also time medium.py at this revision")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    positions = hex_lattice(300, spacing_mm=40.0, jitter_mm=3.0, rng=np.random.default_rng(3))
    params = Params(seed=1, duration_s=1.0).with_overrides({"battery.enabled": False})
    sim = Simulation(positions, Silent, params)
    sim.run()
    m, s = sim.medium, 150
    receivers = m._rx_r[s]
    n = len(receivers)
    versions = [("this checkout", medium.InfraredMedium._end_of_airtime)]
    if args.against:
        versions.append((args.against, medium_at(args.against).InfraredMedium._end_of_airtime))
    draw = random.Random(1)
    for share in args.collided:
        corrupted = set(draw.sample(receivers, round(share * n)))
        lost = sorted(draw.sample(range(n), 2))
        losses = bytes(1 if k in lost else 0 for k in range(n))

        def transmission(corrupted=corrupted, lost=lost, losses=losses) -> medium._Transmission:
            tx = medium._Transmission(
                s, sim.robots[s].message, receivers, m._rx_h[s], bytes(n), losses, lost, 0, []
            )
            tx.epoch = m._epoch
            tx.corrupted = set(corrupted)
            return tx

        best: dict[str, float] = {}
        for _ in range(args.repeat):  # interleaved: each version once per repeat
            for name, deliver in versions:
                batch = iter([transmission() for _ in range(2000)])
                took = timeit.timeit(lambda d=deliver, b=batch: d(m, next(b)), number=2000)
                best[name] = min(best.get(name, float("inf")), took / 2000)
        print(f"{n} receivers, {len(corrupted)} collided, {len(lost)} lost:")
        for name, seconds in best.items():
            print(f"  {name:<14} {seconds * 1e6:7.2f} us per transmission (best of {args.repeat})")


if __name__ == "__main__":
    sys.exit(main())
