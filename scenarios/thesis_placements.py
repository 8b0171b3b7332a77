"""The thesis's three failure cases (Kaiser 2014, §7, Figure 7.1) as named placements.

Kaiser names three topologies in which Rubenstein's algorithm cannot build one global
coordinate system although every non-seed sees two seeds and every seed another seed. Only the
figure's caption and the text describing it survive, so each placement here is a
reconstruction: a small swarm (centres in mm) in which the described situation arises with the
simulator's defaults — 33 mm bodies, 85 mm range centre to centre, the thesis's ``max_angle``
reference rule — and the thesis's premise that a body between two robots blocks their link
(:data:`PREMISE`; kilonet's default model, from real-robot data, has no occlusion). A run of a
named placement applies the premise unless the user sets ``medium.occlusion``. Run one by
name::

    kilonet run gcs --placement thesis-7.1c --set gcs.until=groups --json

or ``kilonet.scenarios.run(kilonet.scenarios.get("gcs"), {...}, placement="thesis-7.1c")``.

Two facts of the algorithm carry the constructions (phases 3-5, :mod:`protocols`):

1. Every member of a frame other than its seed sees the seed: the references are neighbours
   of the seed, and a robot locates itself in seed S's frame only if it sees S and two robots
   already located there.
2. So a robot is located in some frame only if two of its neighbours see each other: as a
   seed it needs two references that see each other; as a reference, the seed and the other
   reference; when it trilaterates, the seed and another member, which sees the seed (fact 1).
   A robot none of whose neighbours see each other is never located, whoever is elected.

:data:`NAMED_PLACEMENTS` maps each name to a function returning a fresh (N, 2) array; the
indices of the robots each case is about are module constants.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from kilonet.scenarios.placement import hex_lattice

__all__ = [
    "BLUE_SEED_7_1B",
    "LEFT_GROUP_7_1C",
    "NAMED_PLACEMENTS",
    "OUTER_LEFT_7_1A",
    "PREMISE",
    "RIGHT_GROUP_7_1C",
    "thesis_7_1a",
    "thesis_7_1b",
    "thesis_7_1c",
]

#: The parameters the constructions assume: messages are "received within a radius of at least
#: 7 cm, provided that there are no objects between sender and receiver" (the thesis, §5): one
#: hard radius (``medium.range_mm``, 85 mm) and no link through a body, not the real robots'
#: per-robot reach (:mod:`kilonet.radio`).
PREMISE = {"medium.occlusion": "block", "medium.reach": "disc"}

_OUTER_LEFT_MM = [(-55.0, 45.0), (-55.0, -45.0)]
# Columns 39 mm apart of a lattice with 45 mm between neighbours (rows in a column 45 mm apart,
# neighbouring columns offset by half a row). The left column lacks its rows at y = ±45 mm:
# the outer robots look into those gaps.
_LATTICE_7_1A_MM = [
    (0.0, 90.0),
    (0.0, 0.0),
    (0.0, -90.0),
    (39.0, 67.5),
    (39.0, 22.5),
    (39.0, -22.5),
    (39.0, -67.5),
    (78.0, 90.0),
    (78.0, 45.0),
    (78.0, 0.0),
    (78.0, -45.0),
    (78.0, -90.0),
]

#: Indices of the two outer left robots of :func:`thesis_7_1a`, which can never be located.
OUTER_LEFT_7_1A = (0, 1)

_BLUE_SEED_MM = (-130.0, -30.0)

#: Index of the robot of :func:`thesis_7_1b` that, once elected, is an isolated seed.
BLUE_SEED_7_1B = 0

_GROUPS_7_1C_MM = [
    (0.0, 0.0),
    (40.0, 0.0),
    (0.0, 40.0),
    (40.0, 40.0),
    (118.0, 0.0),
    (158.0, 0.0),
    (118.0, 40.0),
    (158.0, 40.0),
]

#: Indices of the left and right four-robot groups of :func:`thesis_7_1c`.
LEFT_GROUP_7_1C = (0, 1, 2, 3)
RIGHT_GROUP_7_1C = (4, 5, 6, 7)


def thesis_7_1a() -> np.ndarray:
    """Case 1, Figure 7.1a: two robots at the left edge that cannot be located in any frame.

    The thesis: "The two outer left Kilobots can only see two other robots, which have at
    least one (in this case two) assigned location in a coordinate system. ... a robot needs to
    see two located references plus the seed robot", so neither outer robot can be located.

    Reconstruction (14 robots): a lattice of 12 robots with 45 mm between neighbours whose
    left column is the three robots (0, 90), (0, 0) and (0, -90) mm, 90 mm apart, and the two
    outer robots 0 and 1 at (-55, ±45) mm, in front of the column's gaps. Each outer robot
    sees exactly two robots, at 71 mm: robot 0 sees (0, 90) and (0, 0), robot 1 sees (0, 0)
    and (0, -90). The next robots in line, (39, ±22.5) and (39, ±67.5) mm, are 97 mm away and
    the two outer robots are 90 mm apart, all out of range. The two robots each outer robot
    sees are 90 mm apart and do not see each other, so by fact 2 of the module docstring it is
    never located, whoever is elected: it cannot trilaterate (it sees no third robot), no seed
    can take it as a reference, and if it is elected itself it has no pair of references and
    builds no frame (it is then also listed as an isolated seed). The robots it sees are
    located in the lattice's frames, as in the figure (``kilonet analyze`` predicts it;
    tests/test_thesis_cases.py checks it).

    Returns
    -------
    (14, 2) float ndarray
        Centres, mm; the outer robots are :data:`OUTER_LEFT_7_1A` = (0, 1).

    Examples
    --------
    >>> from kilonet.visibility import LinkModel, communication_graph
    >>> g = communication_graph(thesis_7_1a(), LinkModel(85.0, "block"))
    >>> [sorted(g[robot]) for robot in OUTER_LEFT_7_1A]
    [[2, 3], [3, 4]]
    >>> g.has_edge(2, 3) or g.has_edge(3, 4)
    False
    """
    return np.array(_OUTER_LEFT_MM + _LATTICE_7_1A_MM, dtype=float)


def thesis_7_1b() -> np.ndarray:
    """Case 2, Figure 7.1b: a seed that can join no merging group (isolated seed).

    The thesis: "No matter how the other seed robots choose their coordinate systems, the
    blue seed will never be able to join a merging group with either of them. ... Only the seed
    and the two references are able to position them in the blue seed's system."

    Reconstruction (20 robots): the 19 sites of a hexagonal lattice of 40 mm nearest the
    origin (:func:`kilonet.scenarios.placement.hex_lattice`), plus robot 0, the blue robot, at
    (-130, -30) mm beside the lattice's left corner. It sees exactly two robots, (-80, 0) and
    (-60, -34.6) mm (58 and 70 mm away; every other robot is at least 94 mm away), and those
    two see each other. When it is elected, that pair is its only choice of
    references, and no other robot sees it, so by fact 1 of the module docstring its frame
    holds only itself and its two references. A merging group for its frame would need three
    robots located both in it and in another frame; the blue seed is located in no other frame
    (it sees too few robots to trilaterate, and each of its neighbours, if elected, prefers
    another pair of references under either reference rule). So it is
    an isolated seed however the other seeds choose their references — the lattice's frames
    merge among themselves into one.

    The case needs robot 0 to be elected, as the figure takes the seeds as given. It sees only
    two robots, so as a non-seed it asks for re-elections until both of them are seeds; when
    it is elected (as with seed 1, the default) it is an isolated seed, and otherwise it is a
    robot that cannot be located (case 1) instead.

    Returns
    -------
    (20, 2) float ndarray
        Centres, mm; the blue robot is :data:`BLUE_SEED_7_1B` = 0.

    Examples
    --------
    >>> from kilonet.visibility import LinkModel, communication_graph
    >>> g = communication_graph(thesis_7_1b(), LinkModel(85.0, "block"))
    >>> b, c = sorted(g[BLUE_SEED_7_1B])
    >>> thesis_7_1b()[[b, c]].round(1).tolist(), g.has_edge(b, c)
    ([[-60.0, -34.6], [-80.0, 0.0]], True)
    """
    return np.vstack([[_BLUE_SEED_MM], hex_lattice(19, spacing_mm=40.0)])


def thesis_7_1c() -> np.ndarray:
    """Case 3, Figure 7.1c: two four-robot groups that merge separately — two "global" frames.

    The thesis: "Even though merging groups could be constructed, they are placed such, that
    multiple 'global' coordinate systems will emerge. Like in figure 7.1c, where the four
    robots on the left will establish a coordinate system and the four Kilobots on the right
    side as well."

    Reconstruction (8 robots): two squares of side 40 mm, 78 mm apart: robots 0-3 at x = 0
    and 40 mm, robots 4-7 at x = 118 and 158 mm, y = 0 and 40 mm. In each square all four
    robots see each other, so every frame of a seed in it holds the whole square, and the
    square's seeds (the seed check elects at least two) share merging groups and merge. The
    squares see each other through two parallel links, (40, 0)-(118, 0) and (40, 40)-(118,
    40) mm, 78 mm long; the diagonals between them are 87.7 mm, out of range. So every robot
    sees at most one robot of the other square, and frames never reach across: the first robot
    located in a frame of the other square would see that frame's seed and a second robot of
    that square (the other reference, or the members it trilaterates from) — unless it were a
    reference whose partner is from its own square, and then the seed would see two robots
    across. No merging group spans the squares, whoever is elected: two global frames, one
    per square.
    A new seed election at the squares' edges (the thesis's remedy) cannot join them either,
    for the same reason.

    Returns
    -------
    (8, 2) float ndarray
        Centres, mm; the groups are :data:`LEFT_GROUP_7_1C` and :data:`RIGHT_GROUP_7_1C`.

    Examples
    --------
    >>> from kilonet.visibility import LinkModel, communication_graph
    >>> g = communication_graph(thesis_7_1c(), LinkModel(85.0, "block"))
    >>> sorted((i, j) for i, j in g.edges if (i < 4) != (j < 4))
    [(1, 4), (3, 6)]
    """
    return np.array(_GROUPS_7_1C_MM, dtype=float)


#: Placement name (``kilonet run --placement NAME``) -> function returning its centres, mm.
NAMED_PLACEMENTS: dict[str, Callable[[], np.ndarray]] = {
    "thesis-7.1a": thesis_7_1a,
    "thesis-7.1b": thesis_7_1b,
    "thesis-7.1c": thesis_7_1c,
}
