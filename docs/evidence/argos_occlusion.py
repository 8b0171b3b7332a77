"""Does a Kilobot between two others weaken their link? Real-robot data from the ARGoS project.

The ARGoS Kilobot plugin (github.com/ilpincy/argos3-kilobot) ships the results of its
communication validation: 25 Kilobots on a 5 cm grid, each counting the messages it sent and
received from every other (``src/validation/kilobots/results/comm_*_run*.dat``; 20 runs at each
of two transmit periods and 10 with no period, 50 in all). This script groups the pairs by
distance and by the bodies that cross their line of sight (kilonet's own
:func:`kilonet.visibility.bodies_crossing`) and prints the reception rate of each group, then
the per-body loss a link through one body at 100 mm shows against clear links interpolated to
that length.

Run it on a checkout (or an exported copy) of that folder::

    python docs/evidence/argos_occlusion.py PATH/TO/argos3-kilobot/src/validation/kilobots/results
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path

import numpy as np

from kilonet.visibility import bodies_crossing

GRID_MM = np.array([[50.0 * (j % 5), 50.0 * (j // 5)] for j in range(25)])


def rates(path: Path) -> np.ndarray:
    """``rate[i, j]``: the share of robot j's messages that robot i received."""
    data = np.loadtxt(path)
    if data.shape[1] == 26:  # some files lead with the robot's ID
        data = data[:, 1:]
    return data / np.diagonal(data)[None, :]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="ARGoS's validation/kilobots/results folder")
    args = parser.parse_args()
    i, j = np.nonzero(~np.eye(25, dtype=bool))
    bodies = bodies_crossing(GRID_MM, i, j, 16.5)
    dist = np.hypot(*(GRID_MM[i] - GRID_MM[j]).T).round(1)
    files = sorted(args.results.glob("comm_*_run*.dat"))
    groups: dict[tuple[float, int], list[float]] = collections.defaultdict(list)
    per_body = []
    for path in files:
        r = rates(path)[i, j]
        for d, k, value in zip(dist.tolist(), bodies.tolist(), r.tolist(), strict=True):
            groups[(d, k)].append(value)
        mean = {d: r[dist == d].mean() for d in (70.7, 100.0, 111.8)}
        clear = mean[70.7] + (mean[111.8] - mean[70.7]) * (100.0 - 70.7) / (111.8 - 70.7)
        per_body.append(1.0 - mean[100.0] / clear)
    print(f"{len(files)} runs")
    print(" distance mm  bodies  reception (mean)  pairs")
    for (d, k), values in sorted(groups.items()):
        if d <= 160:
            print(f" {d:11.1f}  {k:6d}  {np.mean(values):16.3f}  {len(values):5d}")
    q = np.array(per_body)
    se = q.std(ddof=1) / np.sqrt(len(q))
    print(f"loss per body at 100 mm against clear links: {q.mean():+.4f} ± {se:.4f} (s.e.)")


if __name__ == "__main__":
    main()
