"""Robot placements: true centres of 33 mm disc robots on the table, in millimetres.

Generators (:func:`line`, :func:`hex_lattice`, :func:`random_uniform`) build an (N, 2) float
array of centres; :func:`load_csv` and :func:`save_csv` read and write the same array as a CSV
file with the columns ``x_mm,y_mm``. Every placement a user hands in goes through
:func:`validate_positions`, which refuses bad input with a one-line :class:`PlacementError`
naming the source, the row and the reason, e.g.::

    placement.csv line 4: x_mm is not a number ('abc')
    placement.csv lines 3 and 7: robots 3.0 mm apart, closer than the 33 mm body diameter
"""

from __future__ import annotations

import csv
import io
import math
import operator
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from kilonet.errors import UserError, read_text

__all__ = [
    "LAYOUTS",
    "MAX_COORDINATE_MM",
    "ROBOT_DIAMETER_MM",
    "PlacementError",
    "PlacementFile",
    "c_shape",
    "corridor",
    "generate",
    "generate_from",
    "hex_lattice",
    "line",
    "load_csv",
    "random_uniform",
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


def line(n: int, *, spacing_mm: float = 40.0, diameter_mm: float = ROBOT_DIAMETER_MM) -> np.ndarray:
    """Robots in a row along the x axis, the first at the origin.

    Parameters
    ----------
    n : int
        Number of robots (may be 0).
    spacing_mm : float
        Distance between neighbouring centres, mm.
    diameter_mm : float
        Body diameter, mm; `spacing_mm` may not be smaller.

    Returns
    -------
    (n, 2) float64 ndarray
        Centres ``(k * spacing_mm, 0)`` for ``k = 0 .. n-1``, mm.

    Raises
    ------
    ValueError
        If `n` is negative or the robots would overlap.

    Examples
    --------
    >>> line(3).tolist()
    [[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]]
    """
    n = _count(n)
    if not spacing_mm >= diameter_mm:
        raise ValueError(
            f"line: spacing_mm={spacing_mm} is less than the {diameter_mm:g} mm body diameter"
        )
    xy = np.zeros((n, 2))
    xy[:, 0] = np.arange(n) * float(spacing_mm)
    return xy


def hex_lattice(
    n: int,
    *,
    spacing_mm: float = 40.0,
    jitter_mm: float = 0.0,
    rng: np.random.Generator | None = None,
    diameter_mm: float = ROBOT_DIAMETER_MM,
) -> np.ndarray:
    """Robots on a hexagonal (triangular) lattice, the n sites nearest the origin.

    The lattice has a site at the origin and rows parallel to the x axis, so the swarm is a
    compact, roughly round patch. Each robot is then moved uniformly at random within a disc
    of radius `jitter_mm` around its site.

    Parameters
    ----------
    n : int
        Number of robots (may be 0).
    spacing_mm : float
        Distance between neighbouring lattice sites, mm.
    jitter_mm : float
        Radius of the disc each robot is displaced within, mm; 0 for an exact lattice.
    rng : numpy.random.Generator, optional
        Source of the jitter; required when ``jitter_mm > 0``.
    diameter_mm : float
        Body diameter, mm.

    Returns
    -------
    (n, 2) float64 ndarray
        Centres in mm, ordered by distance of their site from the origin (ties by angle).

    Raises
    ------
    ValueError
        If `n` is negative, `jitter_mm` is negative, or ``spacing_mm - 2 * jitter_mm`` is less
        than `diameter_mm` (jittered neighbours could overlap), or `rng` is missing.

    Notes
    -----
    Sites are ranked by the exact integer squared distance ``i² + ij + j²`` (in units of
    ``spacing_mm²``) of axial coordinates ``(i, j)``, so the order is deterministic.
    Cost is O(n log n).

    Examples
    --------
    >>> from scipy.spatial.distance import pdist
    >>> xy = hex_lattice(7)
    >>> xy.shape
    (7, 2)
    >>> xy[0].tolist()
    [0.0, 0.0]
    >>> round(float(pdist(xy).min()), 9)
    40.0
    >>> xy = hex_lattice(50, spacing_mm=45.0, jitter_mm=6.0, rng=np.random.default_rng(1))
    >>> bool(pdist(xy).min() >= 33.0)
    True
    """
    n = _count(n)
    if not jitter_mm >= 0:
        raise ValueError(f"hex_lattice: jitter_mm={jitter_mm} must be >= 0")
    if not spacing_mm - 2 * jitter_mm >= diameter_mm:
        raise ValueError(
            f"hex_lattice: spacing_mm={spacing_mm} minus twice jitter_mm={jitter_mm} is "
            f"{spacing_mm - 2 * jitter_mm:g} mm, less than the {diameter_mm:g} mm body "
            "diameter; jittered robots could overlap"
        )
    if jitter_mm > 0:
        _check_rng(rng, "hex_lattice with jitter_mm > 0")
    k = math.isqrt(n) + 2  # the n nearest sites lie well inside |i|, |j| <= k
    i, j = (a.ravel() for a in np.mgrid[-k : k + 1, -k : k + 1])
    x = (i + 0.5 * j) * float(spacing_mm)
    y = j * (math.sqrt(3.0) / 2.0) * float(spacing_mm)
    order = np.lexsort((np.arctan2(y, x), i * i + i * j + j * j))[:n]
    xy = np.column_stack([x[order], y[order]])
    if jitter_mm > 0:
        xy += _uniform_in_disc(n, float(jitter_mm), rng)
    return xy


def random_uniform(
    n: int,
    *,
    density_per_m2: float | None = None,
    area: str = "rect",
    width_mm: float | None = None,
    height_mm: float | None = None,
    radius_mm: float | None = None,
    rng: np.random.Generator,
    diameter_mm: float = ROBOT_DIAMETER_MM,
    max_tries: int | None = None,
) -> np.ndarray:
    """Non-overlapping robots with centres uniformly at random in a rectangle or a disc.

    Robots are placed one after another (random sequential adsorption): a centre is drawn
    uniformly in the region and kept if it is at least `diameter_mm` from every robot kept so
    far. The region is centred at the origin and sized either directly or from a target
    density.

    Parameters
    ----------
    n : int
        Number of robots (may be 0).
    density_per_m2 : float, optional
        Robots per square metre of region; sets a square (``area="rect"``) or disc of area
        ``n / density_per_m2``. Give this or the size, not both.
    area : {"rect", "disc"}
        Shape of the region.
    width_mm, height_mm : float, optional
        Size of the rectangle, mm.
    radius_mm : float, optional
        Radius of the disc, mm.
    rng : numpy.random.Generator
        Source of randomness.
    diameter_mm : float
        Body diameter, mm; minimum distance between centres.
    max_tries : int, optional
        Candidate centres drawn before giving up; default ``1000 * n``.

    Returns
    -------
    (n, 2) float64 ndarray
        Centres in mm, all inside the region (bodies may stick out by half a diameter).

    Raises
    ------
    ValueError
        If the region is under- or over-specified, or the density is too high to place all
        robots within `max_tries` draws. Random placement rarely gets beyond an area fraction
        (body area over region area) of about 0.5.

    Examples
    --------
    >>> from scipy.spatial.distance import pdist
    >>> xy = random_uniform(20, density_per_m2=100.0, rng=np.random.default_rng(0))
    >>> xy.shape
    (20, 2)
    >>> half_side_mm = 1000.0 * math.sqrt(20 / 100.0) / 2
    >>> bool(np.abs(xy).max() <= half_side_mm), bool(pdist(xy).min() >= 33.0)
    (True, True)
    """
    n = _count(n)
    _check_rng(rng, "random_uniform")
    if area == "rect":
        needed = {"width_mm": width_mm, "height_mm": height_mm}
        unused = {"radius_mm": radius_mm}
    elif area == "disc":
        needed = {"radius_mm": radius_mm}
        unused = {"width_mm": width_mm, "height_mm": height_mm}
    else:
        raise ValueError(f"random_uniform: area must be 'rect' or 'disc', got {area!r}")
    stray = [k for k, v in unused.items() if v is not None]
    if stray:
        raise ValueError(f"random_uniform: {', '.join(stray)} does not apply to area={area!r}")
    given = [k for k, v in needed.items() if v is not None]
    if density_per_m2 is not None:
        if given:
            raise ValueError(
                f"random_uniform: give either density_per_m2 or {', '.join(given)}, not both"
            )
        if not (math.isfinite(density_per_m2) and density_per_m2 > 0):
            raise ValueError(f"random_uniform: density_per_m2={density_per_m2} must be > 0")
        area_mm2 = n / density_per_m2 * 1e6
        width_mm = height_mm = math.sqrt(area_mm2)
        radius_mm = math.sqrt(area_mm2 / math.pi)
    elif len(given) < len(needed):
        raise ValueError(
            f"random_uniform: area={area!r} needs density_per_m2 or {' and '.join(needed)}"
        )
    else:
        for name, value in needed.items():
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"random_uniform: {name}={value} must be finite and >= 0")

    if area == "rect":
        region = f"{width_mm:.1f} x {height_mm:.1f} mm rectangle"
        area_mm2 = width_mm * height_mm
        scale = np.array([width_mm, height_mm])

        def draw(k: int) -> np.ndarray:
            return (rng.random((k, 2)) - 0.5) * scale
    else:
        region = f"disc of radius {radius_mm:.1f} mm"
        area_mm2 = math.pi * radius_mm**2

        def draw(k: int) -> np.ndarray:
            return _uniform_in_disc(k, radius_mm, rng)

    max_tries = 1000 * n if max_tries is None else operator.index(max_tries)
    xy, tries = _sequential_adsorption(n, draw, float(diameter_mm), max_tries)
    if len(xy) < n:
        fraction = n * math.pi * (diameter_mm / 2) ** 2 / area_mm2 if area_mm2 else math.inf
        raise ValueError(
            f"random_uniform: density too high: placed only {len(xy)} of {n} robots in a "
            f"{region} ({n / area_mm2 * 1e6 if area_mm2 else math.inf:.1f} per m², "
            f"{diameter_mm:g} mm bodies cover {fraction:.2f} of it) after {tries} tries; "
            "random placement rarely exceeds an area fraction of 0.5"
        )
    return xy


def corridor(
    n: int,
    *,
    length_mm: float,
    width_mm: float,
    rng: np.random.Generator,
    diameter_mm: float = ROBOT_DIAMETER_MM,
) -> np.ndarray:
    """Non-overlapping robots uniformly at random in a long rectangle along the x axis,
    ``[0, length_mm] × [0, width_mm]`` (random sequential adsorption, as
    :func:`random_uniform`): a swarm much longer than wide.

    Raises
    ------
    ValueError
        As :func:`random_uniform`: a size that is not finite and positive, or too many robots
        for the area.

    Examples
    --------
    >>> from scipy.spatial.distance import pdist
    >>> xy = corridor(100, length_mm=2000.0, width_mm=150.0, rng=np.random.default_rng(1))
    >>> xy.shape, bool(xy[:, 0].max() > 1900.0), bool(xy[:, 1].max() <= 150.0)
    ((100, 2), True, True)
    >>> bool(pdist(xy).min() >= 33.0)
    True
    """
    xy = random_uniform(n, width_mm=length_mm, height_mm=width_mm, rng=rng, diameter_mm=diameter_mm)
    return xy + np.array([0.5 * length_mm, 0.5 * width_mm])


def c_shape(
    n: int,
    *,
    outer_radius_mm: float,
    inner_radius_mm: float,
    opening_deg: float = 90.0,
    rng: np.random.Generator,
    diameter_mm: float = ROBOT_DIAMETER_MM,
    max_tries: int | None = None,
) -> np.ndarray:
    """Non-overlapping robots uniformly at random in a C: the ring between the two radii
    about the origin, less the sector of ``opening_deg`` degrees centred on the +x axis — a
    non-convex swarm whose ends face each other across the opening.

    Raises
    ------
    ValueError
        If the radii are not finite with ``0 <= inner < outer``, the opening is not within
        [0, 360), or the robots do not fit (as :func:`random_uniform`).

    Examples
    --------
    >>> xy = c_shape(60, outer_radius_mm=400.0, inner_radius_mm=250.0,
    ...              rng=np.random.default_rng(2))
    >>> r = np.hypot(*xy.T)
    >>> bool(r.min() >= 250.0), bool(r.max() <= 400.0)
    (True, True)
    >>> bool((np.abs(np.degrees(np.arctan2(xy[:, 1], xy[:, 0]))) >= 45.0).all())
    True
    """
    n = _count(n)
    _check_rng(rng, "c_shape")
    if (
        not (math.isfinite(outer_radius_mm) and math.isfinite(inner_radius_mm))
        or not 0 <= inner_radius_mm < outer_radius_mm
    ):
        raise ValueError(
            f"c_shape: need 0 <= inner_radius_mm < outer_radius_mm, got {inner_radius_mm} "
            f"and {outer_radius_mm}"
        )
    if not 0 <= opening_deg < 360:
        raise ValueError(f"c_shape: opening_deg={opening_deg} must lie in [0, 360)")
    half_gap = math.radians(opening_deg) / 2.0
    arc = 2.0 * math.pi - 2.0 * half_gap

    def draw(k: int) -> np.ndarray:
        # Uniform in the ring's sector: radius by area, angle uniform outside the opening.
        r = np.sqrt(inner_radius_mm**2 + rng.random(k) * (outer_radius_mm**2 - inner_radius_mm**2))
        theta = half_gap + arc * rng.random(k)
        return np.column_stack([r * np.cos(theta), r * np.sin(theta)])

    max_tries = 1000 * n if max_tries is None else operator.index(max_tries)
    xy, tries = _sequential_adsorption(n, draw, float(diameter_mm), max_tries)
    if len(xy) < n:
        raise ValueError(
            f"c_shape: density too high: placed only {len(xy)} of {n} robots after {tries} tries"
        )
    return xy


#: Names of the generated placements :func:`generate` knows.
LAYOUTS = ("hex", "line", "random", "corridor", "c_shape", "ring")


def generate(
    kind: str,
    n: int,
    *,
    rng: np.random.Generator | None = None,
    spacing_mm: float = 40.0,
    jitter_mm: float = 0.0,
    density_per_m2: float = 400.0,
    area: str = "disc",
    length_mm: float = 5000.0,
    width_mm: float = 200.0,
    outer_radius_mm: float = 700.0,
    inner_radius_mm: float = 450.0,
    opening_deg: float = 90.0,
    diameter_mm: float = ROBOT_DIAMETER_MM,
) -> np.ndarray:
    """A generated placement by name, as ``placement.kind`` names them: ``"hex"``
    (:func:`hex_lattice` with ``spacing_mm`` and ``jitter_mm``), ``"line"`` (:func:`line`),
    ``"random"`` (:func:`random_uniform` at ``density_per_m2`` in a region of shape ``area``),
    ``"corridor"`` (:func:`corridor`, ``length_mm`` × ``width_mm``), ``"c_shape"``
    (:func:`c_shape` between the two radii, open by ``opening_deg``) or ``"ring"`` (a disc
    with a hole: the C shape without an opening). Sizes in mm.

    Raises
    ------
    ValueError
        If ``kind`` is not one of :data:`LAYOUTS`, or the generator refuses its parameters.

    Examples
    --------
    >>> generate("line", 3, spacing_mm=50.0)[:, 0].tolist()
    [0.0, 50.0, 100.0]
    >>> generate("hex", 7).shape
    (7, 2)
    >>> xy = generate("ring", 50, rng=np.random.default_rng(1), outer_radius_mm=400.0,
    ...               inner_radius_mm=300.0)
    >>> r = np.hypot(*xy.T)
    >>> bool(r.min() >= 300.0 and r.max() <= 400.0)
    True
    >>> generate("spiral", 3)
    Traceback (most recent call last):
    ...
    ValueError: unknown layout 'spiral'; layouts are: hex, line, random, corridor, c_shape, ring
    """
    if kind == "hex":
        return hex_lattice(
            n, spacing_mm=spacing_mm, jitter_mm=jitter_mm, rng=rng, diameter_mm=diameter_mm
        )
    if kind == "line":
        return line(n, spacing_mm=spacing_mm, diameter_mm=diameter_mm)
    if kind == "random":
        return random_uniform(
            n, density_per_m2=density_per_m2, area=area, rng=rng, diameter_mm=diameter_mm
        )
    if kind == "corridor":
        return corridor(n, length_mm=length_mm, width_mm=width_mm, rng=rng, diameter_mm=diameter_mm)
    if kind in ("c_shape", "ring"):
        return c_shape(
            n,
            outer_radius_mm=outer_radius_mm,
            inner_radius_mm=inner_radius_mm,
            opening_deg=opening_deg if kind == "c_shape" else 0.0,
            rng=rng,
            diameter_mm=diameter_mm,
        )
    raise ValueError(f"unknown layout {kind!r}; layouts are: {', '.join(LAYOUTS)}")


def generate_from(placement, kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """:func:`generate` of layout ``kind`` with the sizes of a ``placement`` parameter
    section (:class:`kilonet.params.PlacementParams`: its spacing, jitter, density, area,
    corridor and C-shape fields)."""
    return generate(
        kind,
        n,
        rng=rng,
        spacing_mm=placement.spacing_mm,
        jitter_mm=placement.jitter_mm,
        density_per_m2=placement.density_per_m2,
        area=placement.area,
        length_mm=placement.length_mm,
        width_mm=placement.width_mm,
        outer_radius_mm=placement.outer_radius_mm,
        inner_radius_mm=placement.inner_radius_mm,
        opening_deg=placement.opening_deg,
    )


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


def _count(n) -> int:
    n = operator.index(n)
    if n < 0:
        raise ValueError(f"number of robots n={n} must be >= 0")
    return n


def _check_rng(rng, who: str) -> None:
    if rng is None:
        raise ValueError(f"{who} needs rng, e.g. rng=numpy.random.default_rng(seed)")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"{who}: rng must be a numpy.random.Generator, got {rng!r}")


def _uniform_in_disc(k: int, radius_mm: float, rng: np.random.Generator) -> np.ndarray:
    """`k` points uniformly distributed in the disc of radius `radius_mm` at the origin."""
    r = radius_mm * np.sqrt(rng.random(k))
    theta = 2.0 * math.pi * rng.random(k)
    return np.column_stack([r * np.cos(theta), r * np.sin(theta)])


def _sequential_adsorption(n: int, draw, diameter_mm: float, max_tries: int):
    """Keep drawn centres at least `diameter_mm` from all kept so far; return (kept, tries).

    A dict grid of `diameter_mm` cells makes each check look at the 3 x 3 neighbouring cells.
    """
    kept: list[tuple[float, float]] = []
    grid: dict[tuple[int, int], list[tuple[float, float]]] = {}
    d2 = diameter_mm * diameter_mm
    tries = 0
    while len(kept) < n and tries < max_tries:
        batch = draw(min(max(2 * (n - len(kept)), 64), max_tries - tries)).tolist()
        for x, y in batch:
            tries += 1
            cx, cy = math.floor(x / diameter_mm), math.floor(y / diameter_mm)
            if all(
                (x - px) ** 2 + (y - py) ** 2 >= d2
                for gx in (cx - 1, cx, cx + 1)
                for gy in (cy - 1, cy, cy + 1)
                for px, py in grid.get((gx, gy), ())
            ):
                kept.append((x, y))
                grid.setdefault((cx, cy), []).append((x, y))
                if len(kept) == n:
                    break
    return np.array(kept, dtype=np.float64).reshape(-1, 2), tries
