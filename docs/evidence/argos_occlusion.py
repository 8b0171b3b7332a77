"""Does a Kilobot between two others weaken their link? Real-robot data from the ARGoS project.

The ARGoS Kilobot plugin (github.com/ilpincy/argos3-kilobot) ships the results of its
communication validation: 25 Kilobots on a 5 cm grid, each counting the messages it sent and
received from every other (``src/validation/kilobots/results/comm_*_run*.dat``; 20 runs at each
of two transmit periods and 10 with no period, 50 in all). This script groups the pairs by
distance and by the bodies that cross their line of sight (kilonet's own
:func:`kilonet.visibility.bodies_crossing`) and prints the reception rate of each group, then
the per-body loss a link through one body at 100 mm shows against clear links interpolated to
that length.

Run it on a checkout (or an exported copy) of that folder, such as the one kilonet ships::

    python docs/evidence/argos_occlusion.py tests/validation/data/argos

``python -m kilonet.experiments.publish docs --block argos-occlusion`` tabulates it in
``docs/results/model.md``.
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


def occlusion(results: Path) -> tuple[list[tuple[float, int, float, int]], float, float, int]:
    """What the runs in ``results`` show: rows of (distance mm, bodies crossing, mean reception,
    pairs) up to 160 mm, the loss per body at 100 mm against clear links interpolated to that
    length (a fraction: negative when the link through a body does better) and its standard error,
    and the number of runs.

    Raises
    ------
    ValueError
        If ``results`` holds fewer than two ``comm_*_run*.dat`` files.
    """
    i, j = np.nonzero(~np.eye(25, dtype=bool))
    bodies = bodies_crossing(GRID_MM, i, j, 16.5)
    dist = np.hypot(*(GRID_MM[i] - GRID_MM[j]).T).round(1)
    files = sorted(results.glob("comm_*_run*.dat"))
    if len(files) < 2:
        raise ValueError(f"{results}: fewer than two comm_*_run*.dat files")
    groups: dict[tuple[float, int], list[float]] = collections.defaultdict(list)
    per_body = []
    for path in files:
        r = rates(path)[i, j]
        for d, k, value in zip(dist.tolist(), bodies.tolist(), r.tolist(), strict=True):
            groups[(d, k)].append(value)
        mean = {d: r[dist == d].mean() for d in (70.7, 100.0, 111.8)}
        clear = mean[70.7] + (mean[111.8] - mean[70.7]) * (100.0 - 70.7) / (111.8 - 70.7)
        per_body.append(1.0 - mean[100.0] / clear)
    rows = [
        (d, k, float(np.mean(values)), len(values))
        for (d, k), values in sorted(groups.items())
        if d <= 160
    ]
    q = np.array(per_body)
    return rows, float(q.mean()), float(q.std(ddof=1) / np.sqrt(len(q))), len(files)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="ARGoS's validation/kilobots/results folder")
    args = parser.parse_args()
    rows, loss, se, runs = occlusion(args.results)
    print(f"{runs} runs")
    print(" distance mm  bodies  reception (mean)  pairs")
    for d, k, reception, pairs in rows:
        print(f" {d:11.1f}  {k:6d}  {reception:16.3f}  {pairs:5d}")
    print(f"loss per body at 100 mm against clear links: {loss:+.4f} ± {se:.4f} (s.e.)")


if __name__ == "__main__":
    main()
