"""Placing an *island* at once: a group of unplaced robots that no robot of it can place alone.

A robot that hears fewer than three placed neighbours cannot multilaterate, and two such
robots side by side cannot place each other from candidate pairs when neither has two anchors.
Yet a group of them is often rigid as a whole: four robots that all hear each other form a
rigid body, and five links from that body to placed robots fix where it stands. This module
solves that problem from the island's distances alone (pure math, no robot API):

1. *Spread in the frame*: a member with three or more placed points (anchors it links to,
   members placed already) is multilaterated, with every check of
   :func:`~kilonet.protocols.common.geometry.multilaterate` (collinear anchors, residuals, GDOP,
   mirror image).
2. *Rigid bodies*: when that stalls, the unplaced members are placed in a local frame of their
   own, grown from a triangle that stays at least ``min_height_mm`` high whichever way each
   of its distances is off by the noise (:func:`~kilonet.protocols.common.geometry.robust_height`)
   by the same multilateration. A member that only two body members place has two mirror
   positions: the body is grown once with each (a *shape* each, at most :data:`MAX_SHAPES`),
   dropping a position that would put two robots on top of each other.
3. *Alignment*: the body's rigid motion into the frame (rotation, translation, and whether
   it is mirrored) is fitted to every distance between a body member and a placed point
   (:func:`align_body`), for every shape. It is taken only if it is unique: every other local
   optimum that moves some member more than ``3 σ`` fits worse by more than ``(3 σ)²`` in its
   sum of squared residuals — the test that
   :func:`~kilonet.protocols.localize.phase2_spread.fix_with_candidates` applies to a single robot.
   Then step 1 runs again.

The island's members solve it each on its own from the same reports and take their own
positions (:mod:`kilonet.protocols.localize.phase4_island`); refinement then polishes them with
full-precision distances.

The plane geometry is :mod:`kilonet.protocols.common.geometry`'s: members are placed by its
:func:`~kilonet.protocols.common.geometry.multilaterate`, and an alignment's starting shift is its
:func:`~kilonet.protocols.common.geometry.linear_position`. Only the alignment's Levenberg–Marquardt
(:func:`_fit_motion`) is this module's own: its unknowns are a body's rotation angle and
shift (three, the angle entering through a rotation of every member, the residuals those of
many moved points), where geometry's fit (``_refine_position``) moves one point's two
coordinates, with a closed-form 2×2 step that keeps every robot's multilateration cheap. One
routine for both would be a general n-unknown solver on geometry's hot path.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from kilonet.protocols.common.geometry import (
    MIRROR_SIGMAS,
    GeometryError,
    circle_pair,
    linear_position,
    multilaterate,
    place_references,
    robust_height,
)

__all__ = ["RigidMotion", "Tolerances", "align_body", "solve_island"]

Point = tuple[float, float]
#: Starting rotations of the alignment fit, per handedness and shape.
_START_ANGLES = 24
_ITERATIONS = 40
#: Most shapes of one body tried (each member placed by two others doubles them).
MAX_SHAPES = 16


@dataclass(frozen=True)
class RigidMotion:
    """A rigid motion of the plane: mirror across the x axis first if ``mirrored``, then
    rotate by ``angle_rad`` about the origin, then translate by ``(dx_mm, dy_mm)``.

    Examples
    --------
    >>> RigidMotion(False, math.pi / 2, 10.0, 0.0).apply(np.array([[1.0, 0.0]])).round(9)
    array([[10.,  1.]])
    >>> RigidMotion(True, 0.0, 0.0, 0.0).apply(np.array([[1.0, 2.0]]))
    array([[ 1., -2.]])
    """

    mirrored: bool
    angle_rad: float
    dx_mm: float
    dy_mm: float

    def apply(self, points_mm: np.ndarray) -> np.ndarray:
        """The moved copy of ``points_mm`` ((k, 2) array, mm)."""
        p = points_mm * (1.0, -1.0) if self.mirrored else points_mm
        c, s = math.cos(self.angle_rad), math.sin(self.angle_rad)
        return p @ np.array([[c, s], [-s, c]]) + (self.dx_mm, self.dy_mm)


def _start_shift(turned: np.ndarray, fixed: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """The translation that best puts each turned member at its link's distance from the
    placed point: the shift t lies at ``ranges[k]`` from ``fixed[k] − turned[k]``, a
    multilateration, solved in its linear form
    (:func:`~kilonet.protocols.common.geometry.linear_position`).
    Where those points lie too close to one line for it, the shift that matches the
    centroids."""
    shift, conditioning = linear_position(fixed - turned, ranges)
    if conditioning < 1e-3:
        return fixed.mean(axis=0) - turned.mean(axis=0)
    return shift


def _fit_motion(
    local: np.ndarray, fixed: np.ndarray, ranges: np.ndarray, mirrored: bool, angle: float
) -> tuple[float, RigidMotion]:
    """Levenberg–Marquardt on (angle, dx, dy) from one start; (sum of squared residuals,
    motion)."""
    p = local * (1.0, -1.0) if mirrored else local
    c, s = math.cos(angle), math.sin(angle)
    x = np.array([angle, *_start_shift(p @ np.array([[c, s], [-s, c]]), fixed, ranges)])
    damping = 1e-3

    def residuals(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c, s = math.cos(x[0]), math.sin(x[0])
        moved = p @ np.array([[c, s], [-s, c]]) + x[1:]
        v = moved - fixed
        norm = np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-9)
        return norm - ranges, v / norm[:, None], p @ np.array([[-s, c], [-c, -s]])

    r, u, dp = residuals(x)
    ssr = float(r @ r)
    for _ in range(_ITERATIONS):
        jac = np.column_stack([(u * dp).sum(axis=1), u])
        jtj = jac.T @ jac
        step = np.linalg.solve(jtj + damping * np.diag(np.diag(jtj) + 1e-9), -jac.T @ r)
        trial = x + step
        r_t, u_t, dp_t = residuals(trial)
        ssr_t = float(r_t @ r_t)
        if ssr_t < ssr:
            x, r, u, dp, ssr = trial, r_t, u_t, dp_t, ssr_t
            damping = max(damping / 10.0, 1e-9)
            if float(np.abs(step).max()) < 1e-6:
                break
        else:
            damping *= 10.0
            if damping > 1e9:
                break
    return ssr, RigidMotion(mirrored, float(x[0]), float(x[1]), float(x[2]))


def align_body(
    hypotheses: Sequence[np.ndarray],
    link_members: Sequence[int],
    fixed_mm: np.ndarray,
    ranges_mm: np.ndarray,
    *,
    sigma_mm: float,
    max_rmse_mm: float,
) -> tuple[int, RigidMotion] | None:
    """The unique rigid motion that puts a body in the frame, or None.

    Parameters
    ----------
    hypotheses : sequence of (n, 2) arrays
        The body's shapes that its distances allow (its members in one order, in a local
        frame, mm): one, or one per choice of mirror position of members that only two
        others place.
    link_members : sequence of int
        For each measured link, the row of the body member it starts from.
    fixed_mm : (k, 2) array
        For each link, the placed point's position in the frame, mm.
    ranges_mm : (k,) array
        The measured distance of each link, mm.
    sigma_mm : float
        Ranging noise per link, mm: sets the uniqueness margin.
    max_rmse_mm : float
        Largest accepted RMS residual of the links, mm.

    Returns
    -------
    (hypothesis, motion) or None
        The best fit over every shape, both handednesses and :data:`_START_ANGLES` starting
        rotations each, if its residuals pass and no other fit placing a member more than
        ``3 σ`` elsewhere comes within ``(3 σ)²`` of its sum of squared residuals; else None
        (fewer than four links never determine a body with a check to spare).

    Examples
    --------
    A square body of side 40 mm, four links to placed robots 50 mm off its corners:

    >>> body = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]])
    >>> truth = RigidMotion(True, 0.7, 300.0, -120.0)
    >>> out = np.array([[-50.0, 0.0], [90.0, 0.0], [40.0, 90.0], [-50.0, 40.0]])
    >>> links = truth.apply(out)
    >>> k, m = align_body([body], range(4), links, np.full(4, 50.0), sigma_mm=1.0,
    ...                   max_rmse_mm=4.0)
    >>> bool(np.abs(m.apply(body) - truth.apply(body)).max() < 1e-6)
    True

    With all four links to one placed point, the body could turn about it:

    >>> align_body([body], range(4), np.repeat(links[:1], 4, axis=0),
    ...            np.hypot(*(body - out[0]).T), sigma_mm=1.0, max_rmse_mm=4.0) is None
    True
    """
    if len(ranges_mm) < 4:
        return None
    rows = list(link_members)
    fits = [
        (*_fit_motion(shape[rows], fixed_mm, ranges_mm, mirrored, angle), k)
        for k, shape in enumerate(hypotheses)
        for mirrored in (False, True)
        for angle in np.linspace(0.0, 2.0 * math.pi, _START_ANGLES, endpoint=False)
    ]
    best_ssr, best, best_k = min(fits, key=lambda f: f[0])
    if math.sqrt(best_ssr / len(ranges_mm)) > max_rmse_mm:
        return None
    placed = best.apply(hypotheses[best_k])
    margin = (MIRROR_SIGMAS * sigma_mm) ** 2
    for ssr, motion, k in fits:
        apart = float(np.hypot(*(motion.apply(hypotheses[k]) - placed).T).max())
        if apart > MIRROR_SIGMAS * sigma_mm and ssr - best_ssr <= margin:
            return None
    return best_k, best


@dataclass(frozen=True)
class Tolerances:
    """What the island solve accepts.

    Attributes
    ----------
    sigma_mm : float
        Ranging noise of one distance, mm: sets the fix checks and the uniqueness margin.
    min_height_mm : float
        Thinnest triangle (and anchor spread) allowed, mm.
    max_rmse_mm : float
        Largest accepted RMS residual of a fix or an alignment, mm.
    overlap_mm : float
        Two robots closer than this would overlap, mm: a mirror position that close to a
        member is impossible.
    """

    sigma_mm: float
    min_height_mm: float
    max_rmse_mm: float
    overlap_mm: float


class _Island:
    """The solve's working state: members, their distances and links, and who is placed."""

    def __init__(
        self,
        pairs: Mapping[tuple[int, int], float],
        links: Iterable[tuple[int, Point, float]],
        tolerances: Tolerances,
    ) -> None:
        self.sigma = tolerances.sigma_mm
        self.overlap = tolerances.overlap_mm
        self.min_height = tolerances.min_height_mm
        self.max_rmse = tolerances.max_rmse_mm
        self.adjacent: dict[int, dict[int, float]] = {}
        for (a, b), d in pairs.items():
            if a != b:
                self.adjacent.setdefault(a, {})[b] = d
                self.adjacent.setdefault(b, {})[a] = d
        self.links: dict[int, list[tuple[Point, float]]] = {}
        for uid, point, d in links:
            self.links.setdefault(uid, []).append((point, d))
            self.adjacent.setdefault(uid, {})
        self.placed: dict[int, Point] = {}

    def component(self, uid: int) -> set[int]:
        """The members connected to ``uid`` by measured distances."""
        seen, todo = {uid}, [uid]
        while todo:
            for v in self.adjacent.get(todo.pop(), {}):
                if v not in seen:
                    seen.add(v)
                    todo.append(v)
        return seen

    def constraints(self, uid: int) -> list[tuple[Point, float]]:
        """The placed points ``uid`` has a distance to: its links and placed members."""
        near = [(self.placed[v], d) for v, d in self.adjacent[uid].items() if v in self.placed]
        return self.links.get(uid, []) + near

    def spread(self, members: set[int]) -> None:
        """Step 1: multilaterate members until none more can be placed."""
        tried: dict[int, int] = {}
        progress = True
        while progress:
            progress = False
            for uid in sorted(members - self.placed.keys()):
                points = self.constraints(uid)
                if len(points) < 3 or tried.get(uid) == len(points):
                    continue
                tried[uid] = len(points)
                fix = self._fix([p for p, _ in points], [d for _, d in points])
                if fix is not None:
                    self.placed[uid] = fix
                    progress = True

    def _fix(self, points: Sequence[Point], ranges: Sequence[float]) -> Point | None:
        fix = multilaterate(
            np.array(points),
            np.array(ranges),
            sigma_mm=self.sigma,
            max_rmse_mm=self.max_rmse,
            min_anchor_width_mm=self.min_height,
        )
        return (fix.x_mm, fix.y_mm) if fix.ok else None

    def bodies(self, members: set[int]) -> list[list[dict[int, Point]]]:
        """Step 2: rigid bodies of unplaced members, each as the shapes its distances allow
        (:meth:`_grow`) in a local frame, largest first."""
        free = members - self.placed.keys()
        triangles = []
        for a in sorted(free):
            near = self.adjacent[a]
            for b, c in itertools.combinations(sorted(v for v in near if v in free and v > a), 2):
                if c not in self.adjacent[b]:
                    continue
                height = robust_height(near[b], near[c], self.adjacent[b][c], self.sigma)
                if height >= self.min_height:
                    triangles.append((-height, a, b, c))
        found: list[list[dict[int, Point]]] = []
        covered: set[int] = set()
        for _, a, b, c in sorted(triangles):
            if {a, b, c} <= covered:
                continue
            shapes = self._grow(a, b, c, free)
            if shapes:
                found.append(shapes)
                covered |= shapes[0].keys()
        return sorted(found, key=lambda shapes: len(shapes[0]), reverse=True)

    def _grow(self, a: int, b: int, c: int, free: set[int]) -> list[dict[int, Point]]:
        """The shapes of the body grown from triangle abc: members with three placed
        neighbours in it are multilaterated; a member with two is tried at both mirror
        positions (each a shape of its own, while there are at most :data:`MAX_SHAPES`),
        except where it would overlap a member. Only the shapes with the most members are
        kept, and none if those differ in their members."""
        try:
            _, third = place_references(
                self.adjacent[a][b], self.adjacent[a][c], self.adjacent[b][c]
            )
        except GeometryError:
            return []
        shapes = [{a: (0.0, 0.0), b: (self.adjacent[a][b], 0.0), c: third}]
        self._extend(shapes[0], free)
        while len(shapes) * 2 <= MAX_SHAPES:
            grown = []
            for shape in shapes:
                options = self._mirror_pair(shape, free)
                for uid, point in options:
                    branch = {**shape, uid: point}
                    self._extend(branch, free)
                    grown.append(branch)
                if not options:
                    grown.append(shape)
            if len(grown) == len(shapes) and all(
                g.keys() == s.keys() for g, s in zip(grown, shapes, strict=True)
            ):
                break
            shapes = grown
        size = max(len(shape) for shape in shapes)
        shapes = [shape for shape in shapes if len(shape) == size]
        if any(shape.keys() != shapes[0].keys() for shape in shapes):
            return []
        order = list(shapes[0])
        return [{u: shape[u] for u in order} for shape in shapes]

    def _extend(self, body: dict[int, Point], free: set[int]) -> None:
        """Multilaterate members of ``free`` into ``body`` until none more can be."""
        progress = True
        while progress:
            progress = False
            for uid in sorted(free - body.keys()):
                near = [(body[v], d) for v, d in self.adjacent[uid].items() if v in body]
                if len(near) >= 3:
                    fix = self._fix([p for p, _ in near], [d for _, d in near])
                    if fix is not None:
                        body[uid] = fix
                        progress = True

    def _mirror_pair(self, body: dict[int, Point], free: set[int]) -> list[tuple[int, Point]]:
        """The two mirror positions of the member that two body members place with the
        widest gap between them (each only if it keeps clear of every member); [] if none."""
        best: tuple | None = None
        for uid in sorted(free - body.keys()):
            near = [(v, d) for v, d in self.adjacent[uid].items() if v in body]
            if len(near) != 2:
                continue
            (u, du), (v, dv) = near
            found = circle_pair(body[u], du, body[v], dv)
            if found is None or found[2] < self.min_height:
                continue
            if best is None or found[2] > best[1][2]:
                best = (uid, found)
        if best is None:
            return []
        uid, (p, q, _) = best
        clear = [
            point
            for point in (p, q)
            if all(math.dist(point, other) >= self.overlap for other in body.values())
        ]
        return [(uid, point) for point in clear]

    def align(self, shapes: list[dict[int, Point]]) -> bool:
        """Step 3: put the body in the frame if its links fix one shape and motion uniquely."""
        order = list(shapes[0])
        rows, fixed, ranges = [], [], []
        for row, uid in enumerate(order):
            for q, d in self.constraints(uid):
                rows.append(row)
                fixed.append(q)
                ranges.append(d)
        hypotheses = [np.array([shape[u] for u in order]) for shape in shapes]
        found = align_body(
            hypotheses,
            rows,
            np.array(fixed).reshape(-1, 2),
            np.array(ranges),
            sigma_mm=self.sigma,
            max_rmse_mm=self.max_rmse,
        )
        if found is None:
            return False
        k, motion = found
        for uid, (x, y) in zip(order, motion.apply(hypotheses[k]), strict=True):
            self.placed[uid] = (float(x), float(y))
        return True


def solve_island(
    own: int,
    pairs: Mapping[tuple[int, int], float],
    links: Iterable[tuple[int, Point, float]],
    tolerances: Tolerances,
    *,
    max_members: int = 64,
) -> dict[int, Point]:
    """Positions in the frame for the members of ``own``'s island that its distances fix.

    Parameters
    ----------
    own : int
        The solving robot's ID: only its island (the members connected to it by ``pairs``)
        is solved.
    pairs : mapping
        ``pairs[(a, b)]``: the measured distance between unplaced members a and b, mm.
    links : iterable of (member, (x, y), distance)
        Distances from members to placed robots, with the placed robots' positions, mm.
    tolerances : Tolerances
        Noise, thinnest triangle, largest residual and body overlap.
    max_members : int
        An island larger than this is not solved (the returned mapping is empty).

    Returns
    -------
    dict
        ``{member: (x_mm, y_mm)}`` for every member placed; members the distances do not fix
        are left out.

    Examples
    --------
    Four robots that all hear each other (a 40 mm square) and placed robots 50 mm off three
    of its corners and 60 mm off the fourth — two links from one robot, one from each of the
    others, no robot with three:

    >>> square = {0: (0.0, 0.0), 1: (40.0, 0.0), 2: (40.0, 40.0), 3: (0.0, 40.0)}
    >>> pairs = {(a, b): math.dist(square[a], square[b]) for a, b in [(0, 1), (0, 2), (0, 3),
    ...          (1, 2), (1, 3), (2, 3)]}
    >>> anchors = [(0, (-50.0, 0.0)), (0, (0.0, -50.0)), (1, (90.0, 0.0)), (2, (40.0, 90.0)),
    ...            (3, (-60.0, 40.0))]
    >>> links = [(u, q, math.dist(square[u], q)) for u, q in anchors]
    >>> tolerances = Tolerances(sigma_mm=0.5, min_height_mm=10.0, max_rmse_mm=2.0, overlap_mm=28.0)
    >>> found = solve_island(2, pairs, links, tolerances)
    >>> {u: tuple(round(v, 6) for v in p) for u, p in sorted(found.items())} == square
    True
    """
    island = _Island(pairs, links, tolerances)
    if own not in island.adjacent:
        return {}
    members = island.component(own)
    if len(members) > max_members:
        return {}
    island.spread(members)
    while own not in island.placed:
        if not any(island.align(body) for body in island.bodies(members)):
            break
        island.spread(members)
    return {u: p for u, p in island.placed.items() if u in members}
