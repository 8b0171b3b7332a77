"""Frame keys, roots and ranks (kilonet.protocols.gcs.frame_keys): ordered exactly as the integers
the protocol once packed them into, and carried by their message fields without loss."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kilonet.protocols.gcs.frame_keys import EDGE_BIT, MAX_HOPS, FrameKey, Rank, Root

uids = st.integers(0, (1 << 15) - 1)  # gcs.id_bits is at most 15
salts = st.integers(0, 255)
hops = st.integers(0, MAX_HOPS)
ranks = st.builds(
    lambda edge, uid, salt, h: Rank(Root(edge, FrameKey(uid, salt)), h),
    st.booleans(),
    uids,
    salts,
    hops,
)


def packed(rank: Rank) -> int:
    """The integer the protocol used for a rank before these types: ((edge · 2¹⁵ + ID) · 256 +
    salt) · 256 + hops."""
    key = rank.root.key
    return ((((EDGE_BIT if rank.root.edge else 0) | key.uid) << 8 | key.salt) << 8) | rank.hops


@given(ranks, ranks)
def test_ranks_order_as_their_packed_integers(a, b):
    assert (a < b) == (packed(a) < packed(b))
    assert (a == b) == (packed(a) == packed(b))
    assert (a.root < b.root) == (packed(a) >> 8 < packed(b) >> 8)
    assert (a.root.key < b.root.key) == ((packed(a) >> 8) & 0x7FFFFF < (packed(b) >> 8) & 0x7FFFFF)


@given(ranks)
def test_a_rank_survives_its_message_fields(rank):
    wire_id, salt, h = rank.wire()
    assert 0 <= wire_id < 1 << 16 and 0 <= salt < 256 and 0 <= h < 256
    assert Rank.from_wire(wire_id, salt, h) == rank
    assert rank.root.number == packed(rank) >> 8


def test_the_edge_flag_is_bit_15_of_the_root_id_field():
    assert Root(True, FrameKey(3, 9)).wire_id == 0x8003
    assert Root(False, FrameKey(3, 9)).wire_id == 3
    assert Root.from_wire(0x8003, 9) == Root(True, FrameKey(3, 9))
    assert Root(True, FrameKey(3, 9)).number == 0x800309


def test_edge_roots_rank_after_every_elected_root():
    elected = Rank(Root(False, FrameKey((1 << 15) - 1, 255)), MAX_HOPS)
    edge = Rank.own(FrameKey(0, 0), edge=True)
    assert elected < edge


def test_one_hop_further_and_own():
    own = Rank.own(FrameKey(7, 200), edge=False)
    assert own == Rank(Root(False, FrameKey(7, 200)), 0)
    assert own.one_hop_further() == Rank(own.root, 1)
    assert packed(own.one_hop_further()) == packed(own) + 1


def test_values_read_off_the_wire_are_interned():
    assert FrameKey.from_wire(12, 34) is FrameKey.from_wire(12, 34)
    assert Rank.from_wire(5, 6, 7) is Rank.from_wire(5, 6, 7)
    assert FrameKey.from_wire(12, 34) == FrameKey(12, 34)


@pytest.mark.parametrize("cls", [FrameKey, Root, Rank])
def test_the_values_are_immutable(cls):
    value = {
        FrameKey: FrameKey(1, 2),
        Root: Root(False, FrameKey(1, 2)),
        Rank: Rank.own(FrameKey(1, 2), edge=False),
    }[cls]
    with pytest.raises(AttributeError):
        value.__setattr__(cls._fields[0], 0)
