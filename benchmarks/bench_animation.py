"""Animation speed: a 1,000-robot, 10-minute run rendered as a 20 s GIF (and an HTML replay).

By default the run directory is built synthetically (in a temporary directory) so the figure
does not wait for a 10-minute simulation: a jittered hex lattice of ``--robots`` robots, LED
changes as a Poisson process of ``--led-rate`` changes per robot per second for ``--sim-s``
seconds, ``--movers`` robots orbiting the swarm at 10 mm/s with a pose every 50 ms, a few
crashes and removals, six ``phase`` events and, with ``--messages``, one transmission per robot
every 200 ms. ``--run DIR`` renders an existing run directory instead (e.g. from
``kilonet run gradient --robots 1000 --duration 600 --out DIR``).

Prints the wall and CPU time of loading plus rendering (the machine is shared: CPU time is the
figure that does not depend on other load), the frames, the file sizes and the time per frame.

    python benchmarks/bench_animation.py [--run DIR] [--robots 1000] [--sim-s 600]
        [--video-s 20] [--fps 10] [--overlay NAME ...] [--messages] [--html]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from kilonet.scenarios.placement import hex_lattice
from kilonet.viz.animation import animate_run, frame_times, load_run


def synthetic_run(
    out_dir: Path,
    *,
    robots: int = 1000,
    sim_s: float = 600.0,
    led_rate_per_s: float = 0.5,
    movers: int = 10,
    messages: bool = False,
    seed: int = 1,
) -> dict[str, int]:
    """Write a run directory shaped like ``kilonet.scenarios.write_outputs``; returns table
    sizes."""
    rng = np.random.default_rng(seed)
    pos = hex_lattice(robots, spacing_mm=40.0, jitter_mm=2.0, rng=rng)
    start = pos.copy()
    # Movers orbit just outside the swarm so that they never sit on another robot.
    ring_mm = np.hypot(*pos.T).max() + 60.0
    mover_ids = np.arange(robots - movers, robots)
    phase0 = 2 * np.pi * np.arange(movers) / max(movers, 1)
    start[mover_ids] = ring_mm * np.column_stack([np.cos(phase0), np.sin(phase0)])
    t_pose = np.arange(0.05, sim_s + 1e-9, 0.05)
    omega = 10.0 / ring_mm  # 10 mm/s along the ring
    poses = pd.DataFrame(
        {
            "t_s": np.tile(t_pose, movers),
            "robot": np.repeat(mover_ids, len(t_pose)),
            "x_mm": (ring_mm * np.cos(phase0[:, None] + omega * t_pose)).ravel(),
            "y_mm": (ring_mm * np.sin(phase0[:, None] + omega * t_pose)).ravel(),
            "heading_rad": ((phase0[:, None] + omega * t_pose + np.pi / 2) % (2 * np.pi)).ravel(),
        }
    )
    n_led = rng.poisson(led_rate_per_s * sim_s * robots)
    led = pd.DataFrame(
        {
            "t_s": np.sort(rng.uniform(0, sim_s, n_led)),
            "robot": rng.integers(0, robots, n_led),
            "r": rng.integers(0, 4, n_led),
            "g": rng.integers(0, 4, n_led),
            "b": rng.integers(0, 4, n_led),
        }
    )
    stopped = rng.choice(robots - movers, 10, replace=False)
    stops = pd.DataFrame(
        {
            "t_s": np.sort(rng.uniform(0, sim_s, 10)),
            "robot": stopped,
            "cause": ["crash"] * 5 + ["removed"] * 5,
        }
    )
    names = ["ids", "election", "frames", "localization", "groups", "merging"]
    events = pd.DataFrame(
        {
            "t_s": np.linspace(0, sim_s, len(names), endpoint=False),
            "robot": 0,
            "event": "phase",
            "data": [json.dumps({"phase": p}) for p in names],
        }
    )
    if messages:
        t_tx = np.arange(0.0, sim_s, 0.2)
        t_msg = (t_tx[:, None] + rng.uniform(0, 0.2, (len(t_tx), robots))).ravel()
        order = np.argsort(t_msg, kind="stable")
        msg = pd.DataFrame(
            {
                "t_s": t_msg[order],
                "sender": np.tile(np.arange(robots), len(t_tx))[order],
                "receivers": 6,
                "delivered": 5,
            }
        )
    else:
        msg = pd.DataFrame({"t_s": [], "sender": [], "receivers": [], "delivered": []})
    final = start.copy()
    final[mover_ids] = poses.groupby("robot")[["x_mm", "y_mm"]].last().to_numpy()
    robots_table = pd.DataFrame(
        {
            "robot": np.arange(robots),
            "x0_mm": start[:, 0],
            "y0_mm": start[:, 1],
            "x_mm": final[:, 0],
            "y_mm": final[:, 1],
        }
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    tables = {
        "robots": robots_table,
        "led": led,
        "poses": poses,
        "stops": stops,
        "events": events,
        "messages": msg,
    }
    for name, table in tables.items():
        table.to_csv(out_dir / f"{name}.csv", index=False)
    params = {
        "seed": seed,
        "duration_s": sim_s,
        "medium.range_mm": 85.0,
        "medium.occlusion": "block",
        "robot.tx_period_s": 0.2,
        "motion.step_s": 0.05,
        "trace.messages": messages,
    }
    (out_dir / "params.json").write_text(json.dumps(params, indent=2))
    summary = {"scenario": "synthetic", "robots": robots, "sim_time_s": sim_s}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return {name: len(table) for name, table in tables.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, help="render this run directory instead")
    parser.add_argument("--robots", type=int, default=1000)
    parser.add_argument("--sim-s", type=float, default=600.0)
    parser.add_argument("--led-rate", type=float, default=0.5, help="changes per robot per s")
    parser.add_argument("--movers", type=int, default=10)
    parser.add_argument("--messages", action="store_true", help="trace every transmission")
    parser.add_argument("--video-s", type=float, default=20.0, help="length of the GIF (s)")
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--overlay", nargs="*", default=None, help="overlays (default: auto)")
    parser.add_argument("--html", action="store_true", help="also time the HTML replay")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_animation.") as tmp:
        run_dir = args.run
        if run_dir is None:
            run_dir = Path(tmp) / "run"
            started = time.perf_counter()
            sizes = synthetic_run(
                run_dir,
                robots=args.robots,
                sim_s=args.sim_s,
                led_rate_per_s=args.led_rate,
                movers=args.movers,
                messages=args.messages,
            )
            rows = ", ".join(f"{k} {v:,}" for k, v in sizes.items())
            print(f"synthetic run written in {time.perf_counter() - started:.1f} s: {rows}")
        started = time.perf_counter()
        run = load_run(run_dir)
        load_s = time.perf_counter() - started
        sim_s = run.duration_s
        speed = sim_s / args.video_s
        n_frames = len(frame_times(0.0, sim_s, args.fps, speed))
        gif = Path(tmp) / "bench.gif"
        started, cpu_started = time.perf_counter(), time.process_time()
        animate_run(run_dir, gif, fps=args.fps, speed=speed, overlays=args.overlay)
        gif_s = time.perf_counter() - started
        gif_cpu_s = time.process_time() - cpu_started
        print(
            f"{run.n_robots} robots, {sim_s:g} simulated s -> {args.video_s:g} s GIF at "
            f"{args.fps:g} fps (speed {speed:g}): {n_frames} frames"
        )
        print(f"  load tables          {load_s:8.2f} s")
        print(
            f"  GIF (load + render)  {gif_s:8.2f} s wall, {gif_cpu_s:6.2f} s CPU   "
            f"{1000 * gif_s / n_frames:6.1f} ms/frame   {gif.stat().st_size / 1e6:6.2f} MB"
        )
        if args.html:
            html = Path(tmp) / "bench.html"
            started = time.perf_counter()
            animate_run(run_dir, html, fps=args.fps, speed=speed, overlays=args.overlay)
            html_s = time.perf_counter() - started
            print(f"  HTML (load + write)  {html_s:8.2f} s   {html.stat().st_size / 1e6:6.2f} MB")


if __name__ == "__main__":
    main()
