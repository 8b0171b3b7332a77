"""Parallel speed-up of the sweep runner: one 40-run sweep with 1 worker, then with 2.

The sweep: the gradient scenario, 100 robots, 30 simulated seconds, message loss 0, 0.1, 0.2,
0.3 × seeds 1–10 (about 0.8 s of one core per run). Each measurement runs the whole sweep into a
fresh directory through :func:`kilonet.experiments.runner.run_sweep`, the function behind
``kilonet sweep``, with the worker pool started, the runs stored and the pool shut down inside
the timing. The forkserver the pool forks from is started once before the first measurement (a
one-off cost per ``kilonet sweep`` command, printed separately).

Prints, per worker count: wall seconds, runs per second, the speed-up over 1 worker and the
summed wall seconds of the runs inside their workers (the serial work); then, as a control, the
same runs through a bare process pool (no store, no progress bar), so that on a machine whose
cores other processes share, the runner's own cost can be told from the machine's; and the
load average.

    python benchmarks/bench_sweep.py [--workers 1 2] [--seeds 10] [--robots 100] [--sim-s 30]
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing
import os
import tempfile
import time
from pathlib import Path

from kilonet.experiments.runner import execute_run, run_sweep
from kilonet.experiments.store import ResultStore
from kilonet.experiments.sweep import parse_sweep

SWEEP = """
name = "bench"
scenario = "gradient"
seeds = {seeds}
[fixed]
duration_s = {sim_s}
"placement.robots" = {robots}
[grid]
"medium.loss_prob" = [0.0, 0.1, 0.2, 0.3]
"""


def measure(text: str, workers: int, root: Path) -> dict[str, float]:
    """Run the sweep ``text`` with ``workers`` local processes into a new directory under
    ``root``; return wall seconds, run count and the summed per-run wall seconds."""
    sweep = parse_sweep(text, name="bench")
    directory = root / f"workers-{workers}"
    started = time.perf_counter()
    outcome = run_sweep(sweep, directory, workers=workers, progress=False)
    wall = time.perf_counter() - started
    if outcome.failed or outcome.ok != outcome.total:
        raise RuntimeError(f"benchmark sweep did not finish cleanly: {outcome}")
    with ResultStore.open(directory) as store:
        run_s = float(store.frame()["wall_s"].sum())
    return {"workers": workers, "runs": outcome.total, "wall_s": wall, "run_s": run_s}


def bare_pool(text: str, workers: int) -> float:
    """Wall seconds to run the sweep's runs on a bare forkserver process pool."""
    runs = parse_sweep(text, name="bench").runs()
    context = multiprocessing.get_context("forkserver")
    started = time.perf_counter()
    with cf.ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        records = list(pool.map(execute_run, runs))
    wall = time.perf_counter() - started
    if any(r.status != "ok" for r in records):
        raise RuntimeError("a benchmark run failed")
    return wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seeds", type=int, default=10, help="seeds per loss value (4 values)")
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--sim-s", type=float, default=30.0)
    args = parser.parse_args()
    text = SWEEP.format(seeds=args.seeds, sim_s=args.sim_s, robots=args.robots)
    with tempfile.TemporaryDirectory(prefix="bench_sweep.") as tmp:
        root = Path(tmp)
        started = time.perf_counter()
        warm = text.replace(f"seeds = {args.seeds}", "seeds = 1").replace(
            f'"placement.robots" = {args.robots}', '"placement.robots" = 10'
        )
        run_sweep(parse_sweep(warm, name="warm"), root / "warm", workers=1, progress=False)
        print(f"forkserver start and a 4-run warm-up: {time.perf_counter() - started:.1f} s")
        results = [measure(text, w, root) for w in args.workers]
        bare = {w: bare_pool(text, w) for w in args.workers}
    base = next((r["wall_s"] for r in results if r["workers"] == 1), results[0]["wall_s"])
    bare_base = bare.get(1, bare[args.workers[0]])
    print(
        f"{'workers':>7} {'runs':>5} {'wall s':>8} {'runs/s':>7} {'speed-up':>8} {'run s':>7}"
        f" {'bare pool s':>11} {'bare speed-up':>13}"
    )
    for r in results:
        w = r["workers"]
        print(
            f"{w:>7} {r['runs']:>5} {r['wall_s']:>8.2f} {r['runs'] / r['wall_s']:>7.2f}"
            f" {base / r['wall_s']:>7.2f}x {r['run_s']:>7.1f}"
            f" {bare[w]:>11.2f} {bare_base / bare[w]:>12.2f}x"
        )
    print("load average (1, 5, 15 min):", " ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
