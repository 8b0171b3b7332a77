"""kilonet against Kilombo (C) on Kilombo's own gradient example, side by side.

The workload is Kilombo's ``examples/gradient`` (the kilobotics gradient lab): robot 0 holds
gradient 0, every other robot keeps the smallest gradient it hears plus one, offers it once per
0.48 s, and sets its LED from it in ``loop()``, which runs 24 times a second (Kilombo's
``timeStep`` 0.0416666 s); hard 70 mm communication disc; 60 simulated seconds. kilonet runs it
with the channel modelled (carrier sense, collisions, airtime, per-robot clocks with 1 % rate
error); its battery is off, as Kilombo has none.

Placement: Kilombo's example scatters its robots at random and lets its collision step push
them apart; after 60 s at 1,000 robots there are 13.6 robots within 70 mm of each on average.
Here the robots are scattered and pushed apart the same way once, before the run (see
:func:`placement`), to the same density, and both simulators get the same positions (Kilombo
through its ``-b`` bot file), so Kilombo's collision step never moves a robot.

Each size prints one JSON line: kilonet's wall and CPU seconds (fastest of ``--repeat``),
the program's floor (``program_floor_cpu_s``: the CPU seconds the run's own calls into the
program take with no simulator around them, see :func:`program_floor`), and the ratio against
the reference:

* ``--kilombo DIR``: a Kilombo source tree (``git clone https://github.com/JIC-CSB/kilombo``;
  needs ``cmake``, ``libjansson-dev``, ``libsdl1.2-dev``; ``libsubunit-dev check`` for its own
  tests). The benchmark builds its headless library and the gradient example in
  ``DIR/build-bench`` and runs it headless on the same positions.
* otherwise: kilonet's own channel-off run of the same workload (no carrier sense, perfect
  clocks; collisions and airtime stay, they cannot be switched off).

    python benchmarks/bench_kilombo.py [--sizes 1000 5000] [--repeat 3] [--kilombo DIR]
"""

from __future__ import annotations

import argparse
import itertools
import json
import operator
import os
import resource
import subprocess
import tempfile
import time
from collections import deque
from pathlib import Path

import numpy as np

from kilonet import Kilobot, Message, Params, Simulation

#: Kilombo's body diameter (``bot->radius = 17``), mm; robots are placed at least this far apart.
KILOMBO_DIAMETER_MM = 34.0
#: Share of the start square the bodies cover before they are pushed apart: gives 13.6 robots
#: within 70 mm of each at 1,000 robots, as Kilombo's own final positions have (14.6 at 5,000).
PACKING = 0.86
RANGE_MM = 70.0
TX_PERIOD_S = 0.48
LOOP_HZ = 24.0
SIM_S = 60.0

# Kilombo's gradient.c colour table (kilolib RGB levels), indexed by gradient % 10.
_COLORS = [
    (0, 0, 0),
    (2, 0, 0),
    (2, 1, 0),
    (2, 2, 0),
    (1, 2, 0),
    (0, 2, 0),
    (0, 1, 1),
    (0, 0, 1),
    (1, 0, 1),
    (3, 3, 3),
]
_UNKNOWN = 0xFFFF


class KilomboGradient(Kilobot):
    """Kilombo's ``examples/gradient/gradient.c``, line for line."""

    def setup(self) -> None:
        self.gradient_value = 0 if self.kilo_uid == 0 else _UNKNOWN
        self.update_message()

    def update_message(self) -> None:
        g = self.gradient_value
        self.msg = Message(bytes((g & 0xFF, (g >> 8) & 0xFF)), 1)

    def message_rx(self, message: Message, distance: int) -> None:
        data = message.data
        received = data[0] | (data[1] << 8)
        if self.gradient_value > received + 1:
            self.gradient_value = received + 1
            self.update_message()

    def message_tx(self) -> Message | None:
        return self.msg if self.gradient_value != _UNKNOWN else None

    def loop(self) -> None:
        self.set_color(*_COLORS[self.gradient_value % 10])


def placement(n: int, seed: int = 1) -> np.ndarray:
    """``n`` robots packed as Kilombo's example leaves them, mm: centres uniform in a square
    whose area the bodies would cover to :data:`PACKING`, then overlapping pairs pushed apart
    along their centre line (as Kilombo's ``separate_clashing_bots``) until every two are
    :data:`KILOMBO_DIAMETER_MM` apart."""
    from scipy.spatial import cKDTree

    d = KILOMBO_DIAMETER_MM
    rng = np.random.default_rng(seed)
    side = np.sqrt(n * np.pi * (d / 2) ** 2 / PACKING)
    p = rng.uniform(-side / 2, side / 2, (n, 2))
    while True:
        pairs = cKDTree(p).query_pairs(d, output_type="ndarray")
        if len(pairs) == 0:
            return p
        i, j = pairs[:, 0], pairs[:, 1]
        v = p[j] - p[i]
        dist = np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-9)
        push = ((d * 1.001 - dist) / (2 * dist))[:, None] * v
        np.add.at(p, i, -push)
        np.add.at(p, j, push)


def params(*, channel: bool, seed: int = 1) -> Params:
    """The workload's parameters; ``channel=False``: no carrier sense, perfect clocks."""
    overrides = {
        "medium.range_mm": RANGE_MM,
        "medium.occlusion": "none",
        "medium.csma": channel,
        "robot.tx_period_s": TX_PERIOD_S,
        "robot.tx_jitter_s": 0.0,
        "robot.ticks_per_s": LOOP_HZ,
        "robot.loop_ticks": 1,
        "robot.clock_sd": 0.01 if channel else 0.0,
        "battery.enabled": False,
    }
    if "reach" in {f for f in Params().medium.__dataclass_fields__}:
        overrides["medium.reach"] = "disc"  # Kilombo's hard disc, not ARGoS's measured reach
    return Params(seed=seed, duration_s=SIM_S).with_overrides(overrides)


def _cpu_s() -> float:
    return time.process_time()


def program_floor(sim: Simulation, loops: int, receptions: int) -> float:
    """CPU seconds of the program's own calls after the run ``sim``, with no simulator around
    them: ``loops`` calls of the robots' ``loop()`` (robot after robot, as many rounds as
    that takes) and ``receptions`` calls of their ``message_rx`` with a message that changes
    nothing, by one C-level ``map`` as the medium delivers. A Python simulator of this workload
    cannot take less than this; Kilombo's C calls cost next to nothing."""
    robots = sim.robots
    rounds = -(-loops // len(robots))
    calls = [r.loop for r in robots] * rounds
    message = Message(bytes((0xFE, 0xFF)), 1)  # gradient 65534: never smaller than a robot's
    receivers = [r.message_rx for r in robots] * -(-receptions // len(robots))
    sink: deque = deque(maxlen=0)
    cpu = _cpu_s()
    for call in calls[:loops]:
        call()
    same = itertools.repeat
    sink.extend(map(operator.call, receivers[:receptions], same(message), same(RANGE_MM)))
    return _cpu_s() - cpu


def run_kilonet(positions: np.ndarray, *, channel: bool, repeat: int) -> dict[str, float]:
    """Fastest of ``repeat`` runs: wall and CPU seconds of ``Simulation.run``, counts, and the
    program's floor (:func:`program_floor`) of the fastest run's calls."""
    best: dict[str, float] | None = None
    for _ in range(repeat):
        sim = Simulation(positions, KilomboGradient, params(channel=channel))
        cpu, wall = _cpu_s(), time.perf_counter()
        sim.run()
        wall, cpu = time.perf_counter() - wall, _cpu_s() - cpu
        s = sim.summary()
        reached = sum(r.gradient_value != _UNKNOWN for r in sim.robots)
        figures = {
            "wall_s": round(wall, 3),
            "cpu_s": round(cpu, 3),
            "messages_sent": s["messages_sent"],
            "receptions": s["receptions_delivered"],
            "reached": reached,
        }
        if best is None or figures["wall_s"] < best["wall_s"]:
            best = figures
            best_sim = sim
    assert best is not None
    # Every robot's loop() runs once per tick of its own clock (they run within 1 % of
    # LOOP_HZ; counted by kilo_ticks at the end, the ticks it ran through).
    loops = sum(r.kilo_ticks for r in best_sim.robots)
    best["program_floor_cpu_s"] = round(program_floor(best_sim, loops, best["receptions"]), 3)
    return best


def build_kilombo(src: Path) -> Path:
    """Build Kilombo's headless library and its gradient example from ``src``; the binary."""
    build = src / "build-bench"
    include = build / "include"
    (include / "kilombo").mkdir(parents=True, exist_ok=True)
    for header in ("kilolib.h", "message.h", "message_crc.h", "params.h", "skilobot.h"):
        (include / "kilombo" / header).write_bytes((src / "src" / header).read_bytes())
    (include / "kilombo.h").write_bytes((src / "src" / "kilombo.h").read_bytes())
    # -fcommon: Kilombo defines its callback pointers in several files (GCC >= 10 refuses).
    subprocess.run(
        ["cmake", "-S", str(src), "-B", str(build), "-DCMAKE_C_FLAGS=-fcommon -O2"],
        check=True,
        capture_output=True,
    )
    subprocess.run(
        ["cmake", "--build", str(build), "--target", "headless"], check=True, capture_output=True
    )
    example = src / "examples" / "gradient"
    binary = build / "gradient"
    subprocess.run(
        [
            "gcc",
            "-O2",
            "-std=c99",
            "-fcommon",
            f"-I{include}",
            "-o",
            str(binary),
            str(example / "gradient.c"),
            str(example / "json_state.c"),
            f"-L{build / 'src'}",
            "-lheadless",
            "-lm",
            "-ljansson",
        ],
        check=True,
        capture_output=True,
    )
    return binary


def run_kilombo(binary: Path, src: Path, positions: np.ndarray, repeat: int) -> dict[str, float]:
    """Fastest of ``repeat`` headless runs of Kilombo's gradient on ``positions``: wall and
    CPU (user + system of the child) seconds, and the robots the gradient reached."""
    config = json.loads((src / "examples" / "gradient" / "kilombo.json").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        states = Path(tmp) / "states.json"
        config.update(
            nBots=len(positions),
            simulationTime=SIM_S,
            GUI=0,
            commsRadius=RANGE_MM,
            stateFileName=str(states),
            stateFileSteps=round(SIM_S * LOOP_HZ) - 1,
        )
        (Path(tmp) / "kilombo.json").write_text(json.dumps(config))
        bots = [
            {"ID": i, "direction": 0.0, "state": {}, "x_position": x, "y_position": y}
            for i, (x, y) in enumerate(positions.tolist())
        ]
        (Path(tmp) / "bots.json").write_text(json.dumps({"bot_states": bots}))
        best: dict[str, float] | None = None
        for _ in range(repeat):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            wall = time.perf_counter()
            subprocess.run(
                [str(binary), "-p", "kilombo.json", "-b", "bots.json"],
                cwd=tmp,
                check=True,
                capture_output=True,
            )
            wall = time.perf_counter() - wall
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            final = json.loads(states.read_text())[-1]["bot_states"]
            reached = sum(b["state"].get("gradient", _UNKNOWN) != _UNKNOWN for b in final)
            figures = {"wall_s": round(wall, 3), "cpu_s": round(cpu, 3), "reached": reached}
            if best is None or figures["wall_s"] < best["wall_s"]:
                best = figures
    assert best is not None
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--kilombo", type=Path, metavar="SRC_DIR", help="Kilombo source tree")
    args = parser.parse_args()
    binary = build_kilombo(args.kilombo) if args.kilombo else None
    for n in args.sizes:
        positions = placement(n)
        kilonet = run_kilonet(positions, channel=True, repeat=args.repeat)
        if binary is not None:
            reference_name = "kilombo"
            reference = run_kilombo(binary, args.kilombo, positions, args.repeat)
        else:
            reference_name = "kilonet_channel_off"
            reference = run_kilonet(positions, channel=False, repeat=args.repeat)
        line = {
            "robots": n,
            "kilonet": kilonet,
            reference_name: reference,
            "ratio_wall": round(kilonet["wall_s"] / reference["wall_s"], 2),
            "ratio_cpu": round(kilonet["cpu_s"] / max(reference["cpu_s"], 1e-9), 2),
            "load_average_1min": round(os.getloadavg()[0], 2),
        }
        print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
