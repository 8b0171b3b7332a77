"""How the test kit says what happened: one-line texts for messages, states and conditions."""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from kilonet.message import Layout, Message

__all__ = ["condition_text", "describe", "fields_text", "short_repr"]


def describe(message: Message, layouts: Iterable[Layout] = ()) -> str:
    """One line for a message: decoded with the first of ``layouts`` whose type it carries
    (or the layout a program last decoded it with), else its type and payload bytes.

    Examples
    --------
    >>> GRADIENT = Layout("gradient", type=1, fields=[("gradient", "H")])
    >>> describe(GRADIENT.pack(gradient=4), [GRADIENT])
    'Gradient(gradient=4)'
    >>> describe(Message(b"\\x04\\x00", 1))
    'type 1 data 04 00'
    >>> describe(Message(b"", 1, crc=0))
    'type 1 data - (wrong CRC)'
    """
    text = None
    decoded = message._decoded  # what Layout.unpack cached when a program read it
    candidates = list(layouts) + ([decoded[0]] if decoded is not None else [])
    for layout in candidates:
        if layout.matches(message):
            try:
                text = repr(layout.unpack(message))
            except ValueError:
                continue
            break
    if text is None:
        data = message.data.hex(" ") or "-"
        text = f"type {message.type} data {data}"
    return text if message.crc_ok else f"{text} (wrong CRC)"


def short_repr(value: Any, width: int = 70) -> str:
    """``repr(value)`` cut to ``width`` characters.

    >>> short_repr(list(range(40)), 20)
    '[0, 1, 2, 3, 4, 5, …'
    """
    text = repr(value)
    return text if len(text) <= width else text[: width - 1] + "…"


def fields_text(values: Mapping[str, Any], layouts: Iterable[Layout] = ()) -> str:
    """``name=value, ...`` with short values, messages decoded with ``layouts``."""
    shown = []
    for name, value in values.items():
        if isinstance(value, Message):
            text = describe(value, layouts)
        elif isinstance(value, str):
            text = value
        else:
            text = short_repr(value, 40)
        shown.append(f"{name}={text}")
    return ", ".join(shown) or "-"


def condition_text(condition: Callable[[], bool]) -> str:
    """The condition as its source says it, to name it in a failure message: a lambda's body
    (the rest of its line up to where the call it is passed to goes on), else its name.

    >>> condition_text(lambda: 1 + (2 * 3) > 0)
    'condition `1 + (2 * 3) > 0`'
    """
    try:
        line = inspect.getsource(condition).strip()
    except (OSError, TypeError):
        return f"condition {getattr(condition, '__qualname__', condition)!r}"
    _, colon, body = line.partition("lambda")[2].partition(":")
    if not colon or "lambda" not in line:
        return f"condition `{line}`"
    depth = 0
    for k, char in enumerate(body):
        if char in "([{":
            depth += 1
        elif char in ")]}":
            depth -= 1
        if depth < 0 or (depth == 0 and char == ","):
            body = body[:k]
            break
    return f"condition `{body.strip()}`"
