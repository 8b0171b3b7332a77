"""NeighbourTable.heard skips the duplicate test's arithmetic when no sample can fail it
(``duplicate_mm`` infinite, as gcs leaves it): the records must be those the test would give,
and a program that sets ``duplicate_mm`` (or ``duplicate_after``) later turns the test on."""

from __future__ import annotations

import math
import random

from kilonet.protocols.common.neighbours import NeighbourTable


def _feed(table: NeighbourTable) -> list[tuple]:
    draw = random.Random(7)
    for k in range(3000):
        table.heard(draw.randrange(20), draw.randrange(30, 120), k // 50)
    return [
        (n.uid, n.samples, n.distance_sum_mm, n.distance_sq_sum_mm2, n.heard_round, n.ambiguous)
        for n in table.known() + [table[u] for u in table.ids() if table[u].ambiguous]
    ]


def test_infinite_limit_skips_a_test_that_could_not_fail() -> None:
    fast = NeighbourTable()  # duplicate_mm = inf: the test is skipped
    careful = NeighbourTable(duplicate_mm=1e300)  # the test runs and never fires
    assert _feed(fast) == _feed(careful)
    assert fast.samples_total == careful.samples_total == 3000


def test_setting_the_limit_later_turns_the_test_on() -> None:
    table = NeighbourTable(duplicate_after=2)
    for d in (40, 40, 90):
        table.heard(7, d)
    assert not table[7].ambiguous  # no limit yet
    table.duplicate_mm = 6.0
    table.heard(7, 90)
    assert table[7].ambiguous
    assert table.duplicate_mm == 6.0

    later = NeighbourTable(duplicate_mm=6.0, duplicate_after=100)
    for d in (40, 40, 90):
        later.heard(7, d)
    assert not later[7].ambiguous  # too few samples to judge
    later.duplicate_after = 3
    later.heard(7, 90)
    assert later[7].ambiguous

    off = NeighbourTable(duplicate_mm=6.0, duplicate_after=1)
    off.duplicate_mm = math.inf
    for d in (40, 90, 200):
        off.heard(7, d)
    assert not off[7].ambiguous
