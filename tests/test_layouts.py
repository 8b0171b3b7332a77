"""Message layouts, every protocol at once: within a protocol no two layouts share a type byte
(a robot tells messages apart by that byte alone), every layout fits the kilolib payload, and
gcs registers every layout its modules hold. The inventories come from the code
(:func:`kilonet.protocols.common.layouts.discover`), not from lists kept here."""

from __future__ import annotations

import pytest

from kilonet.message import Layout
from kilonet.protocols.common.layouts import LayoutClash, ProtocolLayouts, discover, protocol_names


def test_every_protocol_is_found():
    names = protocol_names()
    assert {
        "kilonet.protocols.gcs",
        "kilonet.protocols.localize",
        "kilonet.protocols.follower",
        "kilonet.protocols.maze",
    } <= set(names)
    assert "kilonet.protocols.common" not in names


@pytest.mark.parametrize("protocol", protocol_names())
def test_no_two_layouts_of_a_protocol_share_a_type_byte(protocol):
    found = discover(protocol)  # raises LayoutClash on a shared byte
    assert len(found) >= 1, protocol
    for layout in found:
        assert 0 <= layout.type <= 255, layout.name
        assert layout.size_bytes <= 9, layout.name
    assert len(set(found.types())) == len(found)


def test_gcs_registers_every_layout_its_modules_hold():
    import kilonet.protocols.gcs.program  # noqa: F401  (imports every phase)
    from kilonet.protocols.gcs.base import LAYOUTS

    assert list(discover("kilonet.protocols.gcs")) == list(LAYOUTS)


def test_a_second_layout_on_a_taken_type_byte_is_refused():
    register = ProtocolLayouts("test")
    first = register.add(Layout("a", type=7, fields=[("x", "B")]))
    with pytest.raises(LayoutClash, match="'a' and 'b' both use type byte 7"):
        register.add(Layout("b", type=7, fields=[("y", "B")]))
    assert list(register) == [first] and first in register


def test_gcs_layout_registers_and_a_clash_fails_when_the_layout_is_built():
    from kilonet.protocols.gcs.base import gcs_layout

    register = ProtocolLayouts("gcs-test")
    gcs_layout("one", type=3, fields=[("x", "B")], register=register)
    with pytest.raises(LayoutClash):
        gcs_layout("two", type=3, fields=[("x", "B")], register=register)
    assert len(register) == 1
