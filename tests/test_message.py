"""Tests for kilonet.message: payload limits and the Layout packing helper."""

from __future__ import annotations

import copy
import pickle

import pytest

from kilonet.message import KILOLIB, LIMITS, THESIS, Layout, Message, PayloadError

# ------------------------------------------------------------------------------- Message


def test_message_size_counts_type_and_crc():
    assert Message(b"").size_bytes == 3
    assert Message(bytes(9), type=7).size_bytes == 12
    assert Message().type == 0


# ------------------------------------------------------------------------------ kilolib v2


@pytest.mark.parametrize("n_bytes", [0, 1, 8, 9])
def test_kilolib_accepts_up_to_nine_bytes(n_bytes):
    KILOLIB.check(Message(b"\xff" * n_bytes, type=127))


@pytest.mark.parametrize("system_type", [128, 0x8A, 255])
def test_kilolibs_system_types_are_refused_because_they_never_reach_message_rx(system_type):
    with pytest.raises(PayloadError, match=f"type {system_type}: types 128 and up are kilolib's"):
        KILOLIB.check(Message(b"", type=system_type))


def test_kilolib_refuses_ten_bytes():
    with pytest.raises(PayloadError, match=r"10 bytes .* exceeds the kilolib limit of 72 bits"):
        KILOLIB.check(Message(bytes(10)))


@pytest.mark.parametrize("bad_type", [-1, 256])
def test_type_must_be_a_byte(bad_type):
    with pytest.raises(PayloadError, match=f"type {bad_type}"):
        KILOLIB.check(Message(b"", type=bad_type))


def test_data_must_be_bytes():
    with pytest.raises(PayloadError, match="must be bytes, got str"):
        KILOLIB.check(Message("abc"))


# ---------------------------------------------------------------------------------- thesis


@pytest.mark.parametrize(
    "data",
    [b"", b"\x01", ((1 << 23) - 1).to_bytes(3, "little"), b"\xff\x7f\x00", b"\xff\xff\x7f"],
)
def test_thesis_accepts_23_bits(data):
    THESIS.check(Message(data))


@pytest.mark.parametrize(
    ("data", "why"),
    [
        ((1 << 23).to_bytes(3, "little"), "24 significant bits"),
        (b"\xff\xff\xff", "24 significant bits"),
        (b"\x01\x00\x00\x00", "4 bytes"),
    ],
)
def test_thesis_refuses_more_than_23_bits(data, why):
    with pytest.raises(PayloadError, match=why):
        THESIS.check(Message(data))


def test_thesis_has_no_type_byte():
    with pytest.raises(PayloadError, match="no type byte; got type=1"):
        THESIS.check(Message(b"\x01", type=1))


def test_limits_air_bytes():
    assert (KILOLIB.data_bits, KILOLIB.air_bytes, KILOLIB.has_type) == (72, 12, True)
    assert (THESIS.data_bits, THESIS.air_bytes, THESIS.has_type) == (23, 4, False)


# ---------------------------------------------------------------------------------- Layout

POSITION = Layout(
    "local_position", type=3, fields=[("seed", "B"), ("x_mm", "h"), ("y_mm", "h"), ("ok", "?")]
)


def test_layout_round_trip():
    msg = POSITION.pack(seed=200, x_mm=-32768, y_mm=32767, ok=True)
    assert msg.type == 3
    assert len(msg.data) == POSITION.size_bytes == 6
    assert (
        msg.data
        == bytes([200])
        + (-32768).to_bytes(2, "little", signed=True)
        + (32767).to_bytes(2, "little", signed=True)
        + b"\x01"
    )
    got = POSITION.unpack(msg)
    assert got == (200, -32768, 32767, True)
    assert type(got).__name__ == "LocalPosition"
    assert (got.seed, got.x_mm, got.y_mm, got.ok) == (200, -32768, 32767, True)
    KILOLIB.check(msg)


def test_layout_scaled_fields_round_trip_to_the_scale():
    layout = Layout("fine", type=9, fields=[("x_mm", "h", 0.1), ("angle_deg", "B", 2.0)])
    msg = layout.pack(x_mm=-123.44, angle_deg=181.2)
    assert msg.data == (-1234).to_bytes(2, "little", signed=True) + bytes([91])
    got = layout.unpack(msg)
    assert got.x_mm == pytest.approx(-123.4, abs=1e-9)
    assert got.angle_deg == 182.0
    # Values are stored to the nearest step of the scale.
    assert layout.unpack(layout.pack(x_mm=3276.7, angle_deg=510.0)) == pytest.approx(
        (3276.7, 510.0)
    )


@pytest.mark.parametrize(
    ("values", "field"),
    [
        ({"seed": 256, "x_mm": 0, "y_mm": 0, "ok": False}, "seed=256"),
        ({"seed": 0, "x_mm": 40000, "y_mm": 0, "ok": False}, "x_mm=40000"),
        ({"seed": 0, "x_mm": 0, "y_mm": -32769, "ok": False}, "y_mm=-32769"),
    ],
)
def test_layout_out_of_range_value_names_the_field(values, field):
    with pytest.raises(PayloadError, match=f"'local_position': field {field}"):
        POSITION.pack(**values)


def test_layout_scaled_out_of_range_names_the_field():
    layout = Layout("fine", type=9, fields=[("x_mm", "h", 0.1)])
    with pytest.raises(PayloadError, match=r"field x_mm=3300\.0"):
        layout.pack(x_mm=3300.0)


def test_layout_missing_and_unknown_fields():
    with pytest.raises(
        PayloadError, match=r"missing fields \['y_mm', 'ok'\], unknown fields \['z'\]"
    ):
        POSITION.pack(seed=1, x_mm=2, z=3)


def test_layout_over_nine_bytes_is_refused():
    Layout("nine", type=1, fields=[("a", "I"), ("b", "I"), ("c", "B")])  # exactly 9: fine
    with pytest.raises(PayloadError, match="'ten' needs 10 bytes, more than the 9-byte payload"):
        Layout("ten", type=1, fields=[("a", "I"), ("b", "I"), ("c", "H")])


def test_layout_max_bytes_for_smaller_payloads():
    with pytest.raises(PayloadError, match="needs 3 bytes, more than the 2-byte"):
        Layout("small", type=0, fields=[("a", "H"), ("b", "B")], max_bytes=2)


def test_layout_unpack_checks_type_and_length():
    with pytest.raises(PayloadError, match="has type 3, the message has 4"):
        POSITION.unpack(Message(bytes(6), type=4))
    with pytest.raises(PayloadError, match="'local_position'"):
        POSITION.unpack(Message(bytes(2), type=3))


def test_layout_matches_by_type():
    assert POSITION.matches(Message(b"", type=3))
    assert not POSITION.matches(Message(b"", type=2))


def test_a_decoded_message_still_pickles_and_copies_as_itself():
    layout = Layout("pos", type=3, fields=[("seed", "B"), ("x_mm", "h", 0.5)])
    message = layout.pack(seed=7, x_mm=-12.5)
    record = layout.unpack(message)
    assert layout.unpack(message) is record  # decoded once for every receiver
    for twin in (pickle.loads(pickle.dumps(message)), copy.deepcopy(message)):
        assert twin == message
        assert layout.unpack(twin) == record


def test_a_layout_lists_its_fields_and_limits_go_by_format_name():
    layout = Layout("pos", type=3, fields=[("id", "B"), ("x_mm", "h", 0.5)])
    assert layout.fields == [("id", "B", None), ("x_mm", "h", 0.5)]
    assert repr(layout) == "Layout('pos', type=3)"
    assert LIMITS == {"kilolib": KILOLIB, "thesis": THESIS}
