"""Message layouts per protocol: every type byte of a protocol used once, checked in one place.

A robot tells messages apart by their type byte alone, so within one protocol (the programs
that share a swarm) no two layouts may carry the same byte. :class:`ProtocolLayouts` is a
protocol's register: a layout added under a byte another layout holds raises
:class:`LayoutClash` at once (gcs registers each layout as it is built,
:func:`kilonet.protocols.gcs.base.gcs_layout`). :func:`discover` reads every layout a protocol's
modules define, so that a test checks every protocol the same way, and lists what a protocol
sends without anyone keeping the list by hand.

Examples
--------
>>> from kilonet.message import Layout
>>> register = ProtocolLayouts("demo")
>>> hello = register.add(Layout("hello", type=5, fields=[("hops", "B")]))
>>> register.add(hello) is hello, len(register)  # the same layout again: nothing changes
(True, 1)
>>> register.add(Layout("other", type=5, fields=[]))
Traceback (most recent call last):
...
kilonet.protocols.common.layouts.LayoutClash: demo: layouts 'hello' and 'other' both use type byte 5
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Iterator

from kilonet.message import Layout

__all__ = ["LayoutClash", "ProtocolLayouts", "discover", "protocol_names"]


class LayoutClash(ValueError):
    """Two layouts of one protocol use the same type byte."""


class ProtocolLayouts:
    """The message layouts of one protocol, by type byte.

    Parameters
    ----------
    protocol : str
        The protocol's name (for messages).
    """

    def __init__(self, protocol: str) -> None:
        self.protocol = protocol
        self._by_type: dict[int, Layout] = {}

    def add(self, layout: Layout) -> Layout:
        """Register ``layout`` and return it.

        Raises
        ------
        LayoutClash
            If another layout of the protocol holds its type byte.
        """
        held = self._by_type.setdefault(layout.type, layout)
        if held is not layout:
            raise LayoutClash(
                f"{self.protocol}: layouts {held.name!r} and {layout.name!r} both use type "
                f"byte {layout.type}"
            )
        return layout

    def __iter__(self) -> Iterator[Layout]:
        """The layouts in type-byte order."""
        return iter(self._by_type[t] for t in sorted(self._by_type))

    def __len__(self) -> int:
        return len(self._by_type)

    def __contains__(self, layout: object) -> bool:
        return isinstance(layout, Layout) and self._by_type.get(layout.type) is layout

    def types(self) -> list[int]:
        """The type bytes in use, ascending."""
        return sorted(self._by_type)


def protocol_names() -> list[str]:
    """Every protocol: the modules and packages of ``protocols`` except ``common`` (dotted).

    >>> [name for name in protocol_names() if name.endswith(("gcs", "gradient"))]
    ['kilonet.protocols.gcs', 'kilonet.protocols.gradient']
    """
    import kilonet.protocols as protocols

    return [
        f"kilonet.protocols.{m.name}"
        for m in pkgutil.iter_modules(protocols.__path__)
        if m.name != "common"
    ]


def discover(protocol: str) -> ProtocolLayouts:
    """Every layout that the modules of ``protocol`` (a module or a package, dotted) define or
    import at module level, registered afresh.

    Raises
    ------
    LayoutClash
        If two of them share a type byte.
    """
    module = importlib.import_module(protocol)
    modules = [module]
    if hasattr(module, "__path__"):
        modules += [
            importlib.import_module(m.name)
            for m in pkgutil.walk_packages(module.__path__, protocol + ".")
        ]
    found = ProtocolLayouts(protocol.rpartition(".")[2])
    for m in modules:
        for value in vars(m).values():
            if isinstance(value, Layout):
                found.add(value)
    return found
