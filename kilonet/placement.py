"""Robot placements: true centres of 33 mm disc robots on the table, in millimetres.

The generators of placements (lattices, random discs, corridors) are the scenarios'
(:mod:`kilonet.scenarios.placement`); here are the body size, :func:`load_csv` and
:func:`save_csv`, which read and write an (N, 2) float array of centres as a CSV file with the
columns ``x_mm,y_mm``, and the check every placement goes through:
:func:`validate_positions`, which refuses bad input with a one-line :class:`PlacementError`
naming the source, the row and the reason, e.g.::

    placement.csv line 4: x_mm is not a number ('abc')
    placement.csv lines 3 and 7: robots 3.0 mm apart, closer than the 33 mm body diameter
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from kilonet.errors import UserError, read_text

__all__ = [
    "MAX_COORDINATE_MM",
    "ROBOT_DIAMETER_MM",
    "PlacementError",
    "PlacementFile",
    "load_csv",
    "read_placement",
    "save_csv",
    "validate_positions",
]

ROBOT_DIAMETER_MM = 33.0
"""Body diameter of a Kilobot, mm; no two centres may be closer than this."""

MAX_COORDINATE_MM = 1e6
"""Largest coordinate accepted, mm (1 km): far beyond any table, and far enough below the
float range that squared distances between robots cannot overflow."""

_COLUMNS = ("x_mm", "y_mm")
_MAX_LISTED = 5  # overlapping pairs spelled out in one error message


class PlacementError(UserError, ValueError):
    """A placement given by the user is unusable; ``str()`` is one line: source, row, reason."""


def validate_positions(
    positions,
    *,
    diameter_mm: float = ROBOT_DIAMETER_MM,
    source: str = "placement",
    row_offset: int | None = None,
    min_robots: int = 1,
) -> np.ndarray:
    """Check a placement and return it as a new float64 (N, 2) array of centres in mm.

    Parameters
    ----------
    positions : array_like, shape (N, 2)
        Robot centres, mm.
    diameter_mm : float
        Body diameter, mm. Centres closer than this overlap (touching bodies are fine).
    source : str
        Where the positions come from, first word of every error message.
    row_offset : int, optional
        If given, robot ``i`` is reported as ``line i + row_offset`` (2 for a file whose
        header is line 1); otherwise as ``robot i (0-based index)``.
    min_robots : int
        Fewest robots accepted (a :class:`~kilonet.Simulation` runs a robot alone, and so does
        ``kilonet run --placement``).

    Returns
    -------
    (N, 2) float64 ndarray
        A copy of the positions.

    Raises
    ------
    PlacementError
        If the shape is not (N, 2), a coordinate is not a finite number or lies beyond
        :data:`MAX_COORDINATE_MM`, N < `min_robots`, or two centres are closer than
        `diameter_mm` (up to five such pairs are listed).

    Examples
    --------
    >>> validate_positions([[0, 0], [40, 0]]).tolist()
    [[0.0, 0.0], [40.0, 0.0]]
    >>> try:
    ...     validate_positions([[0, 0], [40, 0], [3, 0]])
    ... except PlacementError as exc:
    ...     print(exc)
    placement: robots 0 and 2 (0-based index) are 3.0 mm apart, closer than the 33 mm body diameter
    """
    lines = None
    if row_offset is not None:
        n = len(positions) if hasattr(positions, "__len__") else 0
        lines = range(row_offset, row_offset + n)
    return _check(positions, diameter_mm, source, lines, min_robots)


def load_csv(path: str | os.PathLike, *, diameter_mm: float = ROBOT_DIAMETER_MM) -> np.ndarray:
    """Read and validate a placement's centres from a CSV file with columns ``x_mm`` and
    ``y_mm`` (:func:`read_placement`, without the UIDs).

    Raises
    ------
    PlacementError
        As :func:`read_placement`.
    """
    return read_placement(path, diameter_mm=diameter_mm).positions_mm


@dataclass(frozen=True)
class PlacementFile:
    """A placement read from a file: the robots' centres and, if the file gives them, their
    hardware UIDs (``kilo_uid``)."""

    positions_mm: np.ndarray
    uids: tuple[int, ...] | None


def read_placement(
    path: str | os.PathLike, *, diameter_mm: float = ROBOT_DIAMETER_MM
) -> PlacementFile:
    """Read and validate a placement from a CSV file with columns ``x_mm`` and ``y_mm`` and,
    optionally, ``uid`` (each robot's ``kilo_uid``, an integer 0–65535).

    The first non-blank line is the header; column names may be in any order and surrounded
    by spaces, and other columns are ignored. Blank lines are skipped. Errors name the CSV
    line number, counting the header as line 1 in a file without leading blank lines.

    Parameters
    ----------
    path : str or path-like
        The CSV file (UTF-8, a byte-order mark is allowed).
    diameter_mm : float
        Body diameter, mm, for the overlap check.

    Returns
    -------
    PlacementFile
        Centres, mm, in file order, and the UIDs if the file has a ``uid`` column.

    Raises
    ------
    PlacementError
        If the file is missing, unreadable, empty, lacks a column, has a row with more
        (non-empty) fields than the header has columns, holds a value that is not a finite
        number or lies beyond :data:`MAX_COORDINATE_MM`, a UID that is not an integer 0–65535,
        has fewer than 2 robots, or two robots overlap.
    """
    source = os.fspath(path)
    text = read_text(path, PlacementError, "placement file", encoding="utf-8-sig", newline="")
    try:
        reader = csv.reader(io.StringIO(text, newline=""))
        rows = [(reader.line_num, row) for row in reader if any(c.strip() for c in row)]
    except csv.Error as exc:
        raise PlacementError(f"{source} line {reader.line_num}: not valid CSV ({exc})") from None
    if not rows:
        raise PlacementError(f"{source}: file is empty, expected a header line 'x_mm,y_mm'")

    header_line, header = rows[0]
    names = [c.strip() for c in header]
    columns = []
    for col in _COLUMNS:
        if names.count(col) > 1:
            raise PlacementError(f"{source} line {header_line}: column {col!r} appears twice")
        if col not in names:
            raise PlacementError(
                f"{source}: missing column {col!r} (header has: {', '.join(names)})"
            )
        columns.append((col, names.index(col)))
    if names.count("uid") > 1:
        raise PlacementError(f"{source} line {header_line}: column 'uid' appears twice")
    uid_at = names.index("uid") if "uid" in names else None

    values, lines, problems, uids = [], [], [], []
    for line_no, row in rows[1:]:
        if any(c.strip() for c in row[len(names) :]):
            problems.append(
                f"line {line_no}: {len(row)} fields, but the header names {len(names)} columns"
            )
            continue
        xy = []
        for col, k in columns:
            if k >= len(row):
                problems.append(f"line {line_no}: {col} is missing (row has {len(row)} fields)")
                continue
            text = row[k].strip()
            try:
                value = float(text)
            except ValueError:
                problems.append(f"line {line_no}: {col} is not a number ({text!r})")
                continue
            if not math.isfinite(value):
                problems.append(f"line {line_no}: {col} is not finite ({text!r})")
            xy.append(value)
        if uid_at is not None:
            text = row[uid_at].strip() if uid_at < len(row) else ""
            # ASCII digits only: str.isdigit() is also true for '²', which int() refuses
            if not (text.isascii() and text.isdigit()) or int(text) > 0xFFFF:
                problems.append(f"line {line_no}: uid is not an integer 0-65535 ({text!r})")
            else:
                uids.append(int(text))
        values.append(xy)
        lines.append(line_no)
    if problems:
        more = f" (and {len(problems) - 1} more bad values)" if len(problems) > 1 else ""
        raise PlacementError(f"{source} {problems[0]}{more}")
    positions = _check(np.array(values).reshape(-1, 2), diameter_mm, source, lines)
    return PlacementFile(positions, tuple(uids) if uid_at is not None else None)


def save_csv(positions, path: str | os.PathLike) -> None:
    """Write centres to a CSV file with header ``x_mm,y_mm``, exactly (shortest round-trip repr).

    Parameters
    ----------
    positions : array_like, shape (N, 2)
        Robot centres, mm.
    path : str or path-like
        File to write (overwritten).

    Raises
    ------
    ValueError
        If `positions` is not an (N, 2) array of numbers.
    """
    xy = np.asarray(positions, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"save_csv: positions must have shape (N, 2), got {xy.shape}")
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(_COLUMNS)
        writer.writerows((repr(x), repr(y)) for x, y in xy.tolist())


# --------------------------------------------------------------------------------------------


def _check(
    positions, diameter_mm: float, source: str, lines: Sequence[int] | None, min_robots: int = 1
):
    """Validate positions; robot i is called ``line lines[i]``, or by index if `lines` is None."""
    if not (math.isfinite(diameter_mm) and diameter_mm > 0):
        raise ValueError(f"diameter_mm={diameter_mm} must be finite and > 0")
    try:
        xy = np.array(positions, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PlacementError(
            f"{source}: positions are not an (N, 2) array of numbers ({exc})"
        ) from None
    if xy.size == 0:
        xy = xy.reshape(0, 2)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise PlacementError(f"{source}: positions must have shape (N, 2), got {xy.shape}")

    def one(i: int) -> str:
        return f" line {lines[i]}:" if lines is not None else f": robot {i} (0-based index)"

    def two(i: int, j: int) -> str:
        return f"lines {lines[i]} and {lines[j]}" if lines is not None else f"robots {i} and {j}"

    bad = np.flatnonzero(~np.isfinite(xy).all(axis=1))
    if len(bad):
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        x, y = xy[bad[0]].tolist()
        raise PlacementError(f"{source}{one(bad[0])} position ({x}, {y}) is not finite{more}")
    far = np.flatnonzero((np.abs(xy) > MAX_COORDINATE_MM).any(axis=1))
    if len(far):
        x, y = xy[far[0]].tolist()
        raise PlacementError(
            f"{source}{one(far[0])} position ({x:g}, {y:g}) is more than "
            f"{MAX_COORDINATE_MM:g} mm from the origin"
        )
    n = len(xy)
    if n < min_robots:
        raise PlacementError(
            f"{source}: {n} robot{'' if n == 1 else 's'}, at least {min_robots} "
            f"{'is' if min_robots == 1 else 'are'} needed"
        )

    from scipy.spatial import cKDTree

    pairs = cKDTree(xy).query_pairs(diameter_mm - 1e-9, output_type="ndarray")
    if len(pairs):
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        dist = np.hypot(*(xy[pairs[:, 0]] - xy[pairs[:, 1]]).T)
        what = f"closer than the {diameter_mm:g} mm body diameter"
        if len(pairs) == 1:
            (i, j), d = pairs[0].tolist(), _mm(dist[0], diameter_mm)
            if lines is not None:
                raise PlacementError(f"{source} {two(i, j)}: robots {d} mm apart, {what}")
            raise PlacementError(f"{source}: {two(i, j)} (0-based index) are {d} mm apart, {what}")
        listed = ", ".join(
            f"{two(i, j)} ({_mm(d, diameter_mm)} mm apart)"
            for (i, j), d in zip(pairs[:_MAX_LISTED].tolist(), dist, strict=False)
        )
        more = f" and {len(pairs) - _MAX_LISTED} more" if len(pairs) > _MAX_LISTED else ""
        index = " (0-based index)" if lines is None else ""
        raise PlacementError(
            f"{source}: {len(pairs)} pairs of robots {what}{index}: {listed}{more}"
        )
    return xy


def _mm(d: float, diameter_mm: float) -> str:
    """A distance rounded to 0.1 mm, unless rounding would hide that it is below the diameter."""
    text = f"{d:.1f}"
    return text if float(text) < diameter_mm else repr(float(d))
