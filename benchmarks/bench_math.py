"""The figures behind ``docs/math.md``: what the hand-written math costs against scipy, how
precise the packed quaternion is, and how often a gcs run calls each function.

Prints a stamp (date, machine, library versions), then one row per function: its CPU time per
call (``time.process_time``, the best of ``--repeat`` rounds) and that of the scipy or numpy
route it stands for; the quaternion encoding's largest round-trip error, and the plainer encoding's;
the Cramér–Rao bound's two paths at ``--crlb-robots`` robots. With ``--calls``, also runs
``kilonet run gcs --seed 1`` under cProfile and prints how many times each function ran.

Run it with one BLAS thread: OpenBLAS's idle threads spin, and ``process_time`` counts them.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_math.py [--repeat 5] [--crlb-robots N] [--calls]
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import datetime
import io
import math
import platform
import pstats
import tempfile
import time
import timeit
from unittest import mock

import numpy as np
import scipy
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation, Slerp

import kilonet.scenarios.bounds
from kilonet.protocols.common.alignment import (
    QUATERNION_MAX_ANGLE_ERROR_RAD,
    half_map,
    level_matrix,
    pack_quaternion,
    unpack_quaternion,
    words_matrix,
)
from kilonet.protocols.common.geometry import collinear, multilaterate, trilaterate_linear
from kilonet.scenarios.bounds import crlb_rmse_mm
from kilonet.scenarios.placement import hex_lattice
from kilonet.visibility import pairs_in_range

#: The functions --calls counts: name -> the file that defines it.
COUNTED = {
    **dict.fromkeys(
        ("half_map", "level_matrix", "pack_quaternion", "unpack_quaternion", "words_matrix"),
        "protocols/common/alignment.py",
    ),
    **dict.fromkeys(
        ("collinear", "multilaterate", "place_references", "trilaterate_linear"),
        "protocols/common/geometry.py",
    ),
}


def cpu_us(stmt, repeat: int, number: int) -> float:
    """Best CPU time of one call of ``stmt`` (a callable), µs."""
    timer = timeit.Timer(stmt, timer=time.process_time)
    return min(timer.repeat(repeat=repeat, number=number)) / number * 1e6


# --------------------------------------------------------------------------- the scipy routes


def scipy_half_map(points_i: np.ndarray, points_k: np.ndarray, fraction: float = 0.5):
    """half_map through scipy: Kabsch (align_vectors), Slerp from the identity, the shift."""
    c_i, c_k = points_i.mean(axis=0), points_k.mean(axis=0)
    full, _ = Rotation.align_vectors(points_k - c_k, points_i - c_i)
    partial = Slerp([0.0, 1.0], Rotation.concatenate([Rotation.identity(), full]))([fraction])[0]
    shift = c_i + fraction * (c_k - c_i) - partial.apply(c_i)
    disagreement = np.linalg.norm(full.apply(points_i - c_i) + c_k - points_i, axis=1).max()
    return partial, shift, disagreement


_UP = np.array([0.26726124191242440, 0.53452248382484879, 0.80178372573727319])


def scipy_level_matrix(matrix: np.ndarray) -> np.ndarray:
    """level_matrix through Rotation: the turn about n × e_z by the angle between n and e_z."""
    normal = matrix[:, 2] if matrix[:, 2] @ _UP >= 0 else -matrix[:, 2]
    axis = np.cross(normal, [0.0, 0.0, 1.0])
    sin = np.linalg.norm(axis)
    if sin == 0.0:
        return np.eye(3)
    return Rotation.from_rotvec(axis / sin * math.atan2(sin, normal[2])).as_matrix()


def scipy_multilaterate(anchors: np.ndarray, ranges: np.ndarray, start: np.ndarray):
    def residuals(p):
        return np.hypot(*(p - anchors).T) - ranges

    return least_squares(residuals, start, method="lm").x


def svd_width(points: np.ndarray) -> float:
    """collinear's width through numpy: the largest distance from the SVD's principal axis."""
    points = np.asarray(points, dtype=float)
    centred = points - points.mean(axis=0)
    _, _, axes = np.linalg.svd(centred)
    across = centred @ axes[1:].T
    return float(np.sqrt((across * across).sum(axis=1)).max())


def plain_quaternion_error(rotations: Rotation) -> float:
    """Largest round-trip angle of the plainer encoding: x, y, z as int16, w ≥ 0 recomputed."""
    worst = 0.0
    for rot in rotations:
        q = rot.as_quat()
        q = -q if q[3] < 0 else q
        xyz = np.round(q[:3] * 32767) / 32767
        w = math.sqrt(max(0.0, 1.0 - float(xyz @ xyz)))
        back = Rotation.from_quat([*xyz, w])
        worst = max(worst, (back.inv() * rot).magnitude())
    return worst


# ------------------------------------------------------------------------------- the figures


def costs(repeat: int) -> list[tuple[str, float, float | None]]:
    rng = np.random.default_rng(1)
    group = rng.uniform(-60.0, 60.0, (3, 3))  # a merging group's three members, tilted
    rotation = Rotation.from_rotvec([0.3, -1.2, 2.0])
    turned = rotation.apply(group) + np.array([40.0, -10.0, 5.0])
    matrix = rotation.as_matrix()
    words = pack_quaternion(rotation)
    rows: list[tuple[str, float, float | None]] = [
        (
            "half_map (3 members)",
            cpu_us(lambda: half_map(group, turned), repeat, 2000),
            cpu_us(lambda: scipy_half_map(group, turned), repeat, 500),
        ),
        (
            "level_matrix",
            cpu_us(lambda: level_matrix(matrix), repeat, 20000),
            cpu_us(lambda: scipy_level_matrix(matrix), repeat, 2000),
        ),
        (
            "words_matrix",
            cpu_us(lambda: words_matrix(words), repeat, 20000),
            cpu_us(lambda: unpack_quaternion(words).as_matrix(), repeat, 5000),
        ),
        ("pack_quaternion", cpu_us(lambda: pack_quaternion(rotation), repeat, 20000), None),
        ("unpack_quaternion", cpu_us(lambda: unpack_quaternion(words), repeat, 20000), None),
    ]
    for k in (3, 6):
        angles = 2.0 * math.pi * np.arange(k) / k + 0.1
        anchors = 60.0 * np.column_stack([np.cos(angles), np.sin(angles)])
        truth = np.array([10.0, -5.0])
        ranges = np.hypot(*(anchors - truth).T) + rng.normal(0.0, 1.0, k)
        start = truth + 3.0
        rows.append(
            (
                f"multilaterate ({k} anchors)",
                cpu_us(lambda a=anchors, r=ranges: multilaterate(a, r), repeat, 1000),
                cpu_us(
                    lambda a=anchors, r=ranges, s=start: scipy_multilaterate(a, r, s), repeat, 200
                ),
            )
        )
    frame = [(0.0, 0.0), (60.0, 0.0), (20.0, 50.0)]
    rows.append(
        (
            "trilaterate_linear",
            cpu_us(lambda: trilaterate_linear(frame, [40.0, 45.0, 30.0]), repeat, 5000),
            None,
        )
    )
    for name, points in (
        ("collinear (3 points, 2-D)", np.array(frame)),
        ("collinear (3-D)", group),
    ):
        rows.append(
            (
                name,
                cpu_us(lambda p=points: collinear(p, min_width_mm=1.0), repeat, 5000),
                cpu_us(lambda p=points: svd_width(p) < 1.0, repeat, 5000),
            )
        )
    return rows


def crlb_seconds(n: int) -> tuple[float, float]:
    """CPU seconds of the bound on a jittered hex lattice of ``n`` robots (85 mm range):
    the Cholesky path, then the eigen-decomposition path it falls back on."""
    rng = np.random.default_rng(1)
    pos = hex_lattice(n, spacing_mm=40.0, jitter_mm=3.0, rng=rng)
    i, j, _ = pairs_in_range(pos, 85.0)
    edges = np.column_stack([i, j])
    started = time.process_time()
    crlb_rmse_mm(pos, edges, 1.0)
    cholesky_s = time.process_time() - started
    with mock.patch.object(kilonet.scenarios.bounds, "_gauge_fixed_trace", return_value=None):
        started = time.process_time()
        crlb_rmse_mm(pos, edges, 1.0)
        eig_s = time.process_time() - started
    return cholesky_s, eig_s


def gcs_argv(robots: int | None = None) -> list[str]:
    """The gcs run whose calls are counted: ``kilonet run gcs --seed 1``, on ``robots`` robots
    when given (else the scenario's default)."""
    return ["run", "gcs", "--seed", "1", *([] if robots is None else ["--robots", str(robots)])]


def gcs_calls(robots: int | None = None) -> dict[str, int]:
    """How many times the run :func:`gcs_argv` names calls each counted function."""
    from kilonet.app.cli import main

    profile = cProfile.Profile()
    quiet = contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO())
    with tempfile.TemporaryDirectory() as out, quiet[0], quiet[1]:
        profile.runcall(main, [*gcs_argv(robots), "--out", out])
    return {
        name: calls
        for (path, _, name), (_, calls, *_) in pstats.Stats(profile).stats.items()
        if path.endswith(COUNTED.get(name, "\0"))
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--crlb-robots", type=int, default=1000)
    parser.add_argument("--calls", action="store_true")
    args = parser.parse_args()

    print(
        f"# {datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z} on {platform.node()}: "
        f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}; CPU time (process_time)"
    )
    print(f"{'function':28s} {'fast us':>10s} {'library us':>10s} {'ratio':>7s}")
    for name, fast, slow in costs(args.repeat):
        ratio = f"{slow / fast:7.1f}" if slow else f"{'':7s}"
        slow_text = f"{slow:10.1f}" if slow else f"{'':10s}"
        print(f"{name:28s} {fast:10.1f} {slow_text} {ratio}")

    rots = Rotation.random(20000, random_state=np.random.default_rng(9))
    axes = np.random.default_rng(10).normal(size=(2000, 3))
    flips = Rotation.from_rotvec(axes / np.linalg.norm(axes, axis=1)[:, None] * math.pi)
    near_flips = Rotation.from_rotvec(
        axes / np.linalg.norm(axes, axis=1)[:, None] * (math.pi - 1e-3)
    )
    packed = max(
        (unpack_quaternion(pack_quaternion(r)).inv() * r).magnitude()
        for batch in (rots, flips)
        for r in batch
    )
    plain = max(plain_quaternion_error(flips), plain_quaternion_error(near_flips))
    print(
        f"pack_quaternion round trip: at most {packed:.2e} rad over 20,000 random rotations "
        f"and 2,000 half turns (bound {QUATERNION_MAX_ANGLE_ERROR_RAD:.2e} rad); "
        f"x, y, z int16 with w recomputed: {math.degrees(plain):.2f} deg near half turns"
    )

    cholesky_s, eig_s = crlb_seconds(args.crlb_robots)
    print(
        f"crlb_rmse_mm, {args.crlb_robots} robots: {cholesky_s:.2f} s by Cholesky, "
        f"{eig_s:.2f} s by the eigen-decomposition ({eig_s / cholesky_s:.1f} x)"
    )

    if args.calls:
        for name, calls in sorted(gcs_calls().items()):
            print(f"calls in kilonet run gcs --seed 1: {name:20s} {calls:8d}")


if __name__ == "__main__":
    main()
