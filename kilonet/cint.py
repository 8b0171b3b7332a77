"""C's integer arithmetic on the Kilobot's ATmega328P, for programs ported from kilolib.

Python's integers never overflow and its ``//`` and ``%`` round down; avr-gcc's ``int`` is 16
bits, wraps around (in practice; the standard leaves signed overflow undefined), and its ``/``
and ``%`` truncate towards zero. A port that must behave as the C program does on the robot
wraps each result the C code stores::

    total = int16(total + sample)   # C: int sum; sum = sum + sample;

Summing 300 ambient-light samples (move_to_light's average) in a C ``int`` passes 32,767 once
the readings average 110 or more, and the sum wraps negative on the robot; a ``long`` does not.
``int16`` reproduces the wrap, plain Python does not.

Examples
--------
>>> int16(300 * 600), uint8(256 + 7), uint16(-1)
(-16608, 7, 65535)
>>> c_div(-7, 2), c_mod(-7, 2), -7 // 2, -7 % 2
(-3, -1, -4, 1)
"""

from __future__ import annotations

__all__ = ["c_div", "c_mod", "int8", "int16", "int32", "uint8", "uint16", "uint32"]


def _wrap(value: int, bits: int, signed: bool) -> int:
    value = int(value) & ((1 << bits) - 1)
    if signed and value >> (bits - 1):
        value -= 1 << bits
    return value


def int8(value: int) -> int:
    """``value`` as C's ``int8_t`` stores it (wrapped to -128..127)."""
    return _wrap(value, 8, True)


def uint8(value: int) -> int:
    """``value`` as C's ``uint8_t`` stores it (wrapped to 0..255)."""
    return _wrap(value, 8, False)


def int16(value: int) -> int:
    """``value`` as avr-gcc's ``int`` / ``int16_t`` stores it (wrapped to -32768..32767).

    >>> int16(32767 + 1), int16(-32769)
    (-32768, 32767)
    """
    return _wrap(value, 16, True)


def uint16(value: int) -> int:
    """``value`` as C's ``uint16_t`` / avr-gcc's ``unsigned int`` stores it (0..65535)."""
    return _wrap(value, 16, False)


def int32(value: int) -> int:
    """``value`` as avr-gcc's ``long`` / ``int32_t`` stores it."""
    return _wrap(value, 32, True)


def uint32(value: int) -> int:
    """``value`` as avr-gcc's ``unsigned long`` / ``uint32_t`` stores it (``kilo_ticks``)."""
    return _wrap(value, 32, False)


def c_div(a: int, b: int) -> int:
    """C's integer ``a / b``: the quotient truncated towards zero.

    Raises
    ------
    ZeroDivisionError
        If ``b`` is 0 (undefined in C).

    Examples
    --------
    >>> c_div(7, 2), c_div(-7, 2), c_div(7, -2)
    (3, -3, -3)
    """
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def c_mod(a: int, b: int) -> int:
    """C's ``a % b``: the remainder of :func:`c_div`, with the sign of ``a``.

    >>> c_mod(-30, 64), c_mod(30, -64)
    (-30, 30)
    """
    return a - b * c_div(a, b)
