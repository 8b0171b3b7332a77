"""The global coordinate system end to end: phases 1-6 on jittered hex lattices.

Prints, per size: wall time, CPU time, simulated time (and each phase's share), merging rounds
(all seeds together and the most any seed ran), final frames, localized share, RMSE after the
best rigid alignment and the Cramér-Rao bound for the same measurement graph. Issue 5's target:
1,000 robots in at most 60 s of wall time on the 2-core development machine.

With ``--floor``, each gcs run is followed by three runs of the same placement, parameters and
simulated time whose robots do only what every robot of the gcs program must do, each adding
one thing to the previous: ``medium`` (the robots offer a message at the share of transmit
opportunities the gcs run used and count what they hear), ``loop`` (plus an empty ``loop()``
at the scenario's loop period) and ``table`` (plus reading the sender's ID from every
reception into a :class:`~kilonet.protocols.common.neighbours.NeighbourTable`, as ``GcsRobot``
does). The gcs run's CPU time beyond ``table`` is what the six phases' logic costs.

    python benchmarks/bench_gcs.py [--sizes 100 1000] [--seed 1] [--set key=value ...] [--floor]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time

from kilonet import Kilobot, Message, scenarios
from kilonet.protocols.common.neighbours import NeighbourTable
from kilonet.protocols.gcs.base import gcs_layout, sender_of
from kilonet.scenarios.base import build_params

FIELDS = (
    "robots",
    "messages_sent",
    "receptions_delivered",
    "wall_time_s",
    "sim_time_s",
    "merge_rounds",
    "merge_rounds_max_per_seed",
    "seeds",
    "frames",
    "localized_fraction",
    "rmse_mm",
    "crlb_rmse_mm",
    "phase_times_s",
)


def run_one(n: int, seed: int, overrides: dict[str, str]) -> dict:
    """One gcs run of ``n`` robots; the summary's headline figures, the CPU time it took (less
    disturbed than wall time by other work on the machine) and the load average."""
    cpu = time.process_time()
    result = scenarios.run(
        scenarios.get("gcs"), {"placement.robots": n, **overrides}, seed=seed, progress=True
    )
    figures = {key: result.summary.get(key) for key in FIELDS}
    figures["cpu_time_s"] = round(time.process_time() - cpu, 1)
    figures["load_average_1min"] = os.getloadavg()[0]
    return figures


#: What the floor robots send: their ID first, as every gcs message (4 bytes).
FLOOR = gcs_layout("floor", type=20, fields=[("padding", "H")], register=None)


class TrafficFloor(Kilobot):
    """Offers a :data:`FLOOR` message at ``tx_share`` of its transmit opportunities, spread
    evenly, and counts what it hears."""

    tx_share = 1.0

    def setup(self) -> None:
        self.message = FLOOR.pack(sender=self._kindex, padding=0)
        self.opportunities = 0
        self.heard = 0

    def message_tx(self) -> Message | None:
        self.opportunities += 1
        share = self.tx_share
        return self.message if (self.opportunities * share) % 1 < share else None

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.heard += 1


class LoopFloor(TrafficFloor):
    """:class:`TrafficFloor` with an empty ``loop()`` (which the simulation then schedules)."""

    def loop(self) -> None:
        pass


class TableFloor(LoopFloor):
    """:class:`LoopFloor` that also keeps a neighbour table from every reception's sender ID
    and distance, as ``GcsRobot.message_rx`` does."""

    def setup(self) -> None:
        super().setup()
        self.table = NeighbourTable()

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.table.heard(sender_of(message), distance_mm)


def run_floors(n: int, seed: int, overrides: dict[str, str], gcs: dict) -> list[dict]:
    """The three floor runs (see the module docstring) for the gcs run ``gcs`` of ``n`` robots:
    the same placement, parameters and simulated time, and the share of transmit opportunities
    it used (messages sent over robots × simulated time / ``robot.tx_period_s``)."""
    gcs_scenario = scenarios.get("gcs")
    params = build_params(gcs_scenario, overrides)
    opportunities = n * gcs["sim_time_s"] / params.robot.tx_period_s
    share = min(1.0, gcs["messages_sent"] / opportunities)
    rows = []
    for name, program in (("medium", TrafficFloor), ("loop", LoopFloor), ("table", TableFloor)):
        floor = type(program.__name__, (program,), {"tx_share": share})
        scenario = dataclasses.replace(
            gcs_scenario,
            setup=dataclasses.replace(
                gcs_scenario.setup,
                program=lambda _params, _positions, floor=floor: floor,
                stop_when=None,
            ),
            reporting=dataclasses.replace(gcs_scenario.reporting, metrics=None),
        )
        cpu = time.process_time()
        result = scenarios.run(
            scenario,
            {"placement.robots": n, **overrides, "duration_s": gcs["sim_time_s"]},
            seed=seed,
        )
        s = result.summary
        rows.append(
            {
                "floor": name,
                "robots": n,
                "sim_time_s": s["sim_time_s"],
                "tx_share": round(share, 4),
                "messages_sent": s["messages_sent"],
                "receptions_delivered": s["receptions_delivered"],
                "cpu_time_s": round(time.process_time() - cpu, 1),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument(
        "--floor", action="store_true", help="follow each run with its floor runs (see above)"
    )
    args = parser.parse_args()
    overrides = dict(item.split("=", 1) for item in args.set)
    for n in args.sizes:
        figures = run_one(n, args.seed, overrides)
        print(json.dumps(figures), flush=True)
        if args.floor:
            for row in run_floors(n, args.seed, overrides, figures):
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
