"""Placement generators: the swarms scenarios and the test kit start from (a line, a jittered
hex lattice, robots at random in a disc, a corridor, a C, a ring), as (N, 2) float arrays of
true centres, mm. Each result is checked like any placement a user hands in
(:func:`kilonet.placement.validate_positions`)."""

from __future__ import annotations

import math
import operator

import numpy as np

from kilonet.placement import (
    ROBOT_DIAMETER_MM,
)

__all__ = [
    "LAYOUTS",
    "c_shape",
    "corridor",
    "generate",
    "generate_from",
    "hex_lattice",
    "line",
    "random_uniform",
]


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
