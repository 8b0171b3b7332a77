"""The measured figures of ``docs/results/follower.md``: how often the follower reaches its
goal, and how fast, over generated starts (:func:`kilonet.scenarios.follower.run_many`).

Each condition runs the same seeds; a run counts as reached when the follower declared arrival
and stands within ``follower.success_mm`` (8 mm) of the true centroid. About a minute of CPU
for all of them on this machine's cores (one process).
"""

from __future__ import annotations

import time
from typing import Any

__all__ = ["CONDITIONS", "SEEDS", "success_block"]

#: Seeds of every condition.
SEEDS = range(1, 101)
#: Label, overrides of each measured condition.
CONDITIONS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("real-robot medium (ranging to 100 mm), no loss", {}),
    ("real-robot medium, 10 % message loss", {"medium.loss_prob": 0.1}),
    (
        "what-if: 300 mm disc, iid ranging, start 120-250 mm away, 10 % loss",
        {
            "medium.reach": "disc",
            "ranging.model": "gaussian",
            "medium.range_mm": 300,
            "follower.neighbour_max_mm": 255,
            "follower.start_min_mm": 120,
            "follower.start_max_mm": 250,
            "medium.loss_prob": 0.1,
        },
    ),
)


def success_block() -> str:
    """The table of ``<!-- publish:follower-success -->``: per condition, the share of runs
    that reached the goal, the handedness verdicts, and the median steps, simulated time and
    path length over straight line of the runs that reached it."""
    from kilonet.scenarios.follower import run_many

    rows = []
    cpu_start = time.process_time()
    for label, overrides in CONDITIONS:
        table = run_many(SEEDS, overrides)
        ok = (table["outcome"] == "reached") & table["reached"]
        done = table[ok]
        right = (table["mirrored_frame"] == table["mirrored_frame_true"]) & table[
            "handedness_settled"
        ]
        ratio = (done["path_length_mm"] / done["straight_line_mm"]).median()
        rows.append(
            f"| {label} | {len(table)} | {ok.mean():.0%} | {right.mean():.0%} "
            f"| {done['steps'].median():.0f} | {done['finish_time_s'].median():.0f} "
            f"| {ratio:.2f} | {(table['outcome'] == 'gave_up').sum()} "
            f"| {(table['outcome'] == 'timeout').sum()} |"
        )
    cpu_s = time.process_time() - cpu_start
    header = [
        "| condition | runs | reached | handedness right | median steps | median time (s) "
        "| median path / straight line | gave up | timed out |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    note = (
        f"Seeds {SEEDS.start}-{SEEDS.stop - 1} of the generated placements (sides 60-80 mm, "
        "robot 3 on a random side, the follower at least 20 mm from the goal); medians over the "
        f"runs that reached it; {cpu_s:.0f} s CPU for the table."
    )
    return "\n".join([*header, *rows, "", note]) + "\n"
