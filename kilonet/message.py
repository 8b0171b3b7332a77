"""Kilobot messages and the helper that packs protocol fields into them.

A kilolib v2 message (``message_t``) carries ``data[9]`` payload bytes, one ``type`` byte and a
16-bit ``crc``. The thesis's older library carried only 23 payload bits. Both limits are
:class:`PayloadLimit` values; the medium checks every offered message against its limit, so a
protocol that tries to send more fails loudly instead of silently getting a bigger radio.

The CRC is kilolib's :func:`message_crc` (CRC-CCITT as avr-libc's ``_crc_ccitt_update``, start
value 0xFFFF, over the nine data bytes and the type byte). A receiver drops a message whose
``crc`` does not match, as kilolib's receive interrupt does (the sync lab relies on it: it sets
``crc = 0`` to make its neighbours ignore a message). A Python program may leave ``crc`` unset
(``None``), which stands for the correct CRC, so only ported C code needs to compute it.

Protocols never hand-roll bytes: they declare a :class:`Layout` of named, typed fields (struct
codes, optionally fixed-point scaled) and call :meth:`Layout.pack` / :meth:`Layout.unpack`.

Examples
--------
>>> POSITION = Layout("position", type=3, fields=[("seed", "B"), ("x_mm", "h"), ("y_mm", "h")])
>>> msg = POSITION.pack(seed=7, x_mm=-120, y_mm=45)
>>> msg.type, len(msg.data)
(3, 5)
>>> POSITION.unpack(msg)
Position(seed=7, x_mm=-120, y_mm=45)
"""

from __future__ import annotations

import struct
from collections import namedtuple
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "FIELD_CODES",
    "KILOLIB",
    "LIMITS",
    "NORMAL",
    "SYSTEM_TYPES",
    "THESIS",
    "Layout",
    "Message",
    "PayloadError",
    "PayloadLimit",
    "message_crc",
]


class PayloadError(ValueError):
    """A message does not fit the payload limit, or a field value does not fit its field."""


@dataclass(frozen=True, slots=True)
class Message:
    """One infrared message as a program offers and receives it.

    Parameters
    ----------
    data : bytes
        Payload bytes (at most 9 under kilolib v2).
    type : int
        Message type byte, 0–255 (kilolib's ``msg.type``).
    crc : int, optional
        kilolib's 16-bit ``msg.crc``; ``None`` stands for the correct one (:func:`message_crc`).
        A message whose CRC is wrong goes on the air but every receiver drops it.

    Examples
    --------
    >>> Message(bytes(1), 0).crc_ok, Message(bytes(1), 0, crc=0).crc_ok
    (True, False)
    """

    data: bytes = b""
    type: int = 0
    crc: int | None = None
    # The last Layout.unpack of this message, (layout, record): the medium hands one message
    # object to every receiver, so each transmission is decoded once, not once per receiver.
    _decoded: Any = field(default=None, init=False, repr=False, compare=False)

    @property
    def size_bytes(self) -> int:
        """Bytes on the air: payload, type byte and a 2-byte CRC."""
        return len(self.data) + 3

    @property
    def crc_ok(self) -> bool:
        """Whether a receiver accepts this message's CRC."""
        return self.crc is None or self.crc == message_crc(self)

    def __reduce__(self) -> tuple:
        # Copies and pickles carry the message, not the decode cache (which holds a Layout).
        return (Message, (self.data, self.type, self.crc))


def _immutable(self: Message, name: str, value: Any) -> None:
    raise AttributeError(
        f"a Message cannot change (one message object reaches every receiver, and the radio "
        f"has sent it already): instead of msg.{name} = ..., build a new one, "
        f"msg = dataclasses.replace(msg, {name}=...) or Message(data, type, crc)"
    )


# A frozen dataclass's own error says only "cannot assign to field"; a kilolib programmer
# writes msg.crc = message_crc(&msg), so say what to write instead. (Set after the decorator,
# which refuses a __setattr__ in the class body; __init__ and replace() bypass it.)
Message.__setattr__ = _immutable  # type: ignore[method-assign]


def _crc_ccitt_update(crc: int, byte: int) -> int:
    """avr-libc's ``_crc_ccitt_update`` (reflected CRC-CCITT, polynomial 0x8408)."""
    byte ^= crc & 0xFF
    byte = (byte ^ (byte << 4)) & 0xFF
    return (((byte << 8) | (crc >> 8)) ^ (byte >> 4) ^ (byte << 3)) & 0xFFFF


def message_crc(message: Message) -> int:
    """kilolib's ``message_crc``: the CRC of the nine data bytes (a shorter payload is padded
    with zeros, as the C struct always holds nine) and the type byte.

    Examples
    --------
    >>> c = 0xFFFF
    >>> for b in b"123456789":
    ...     c = _crc_ccitt_update(c, b)
    >>> hex(c)  # the CRC-16/MCRF4XX check value
    '0x6f91'
    """
    crc = 0xFFFF
    for byte in message.data.ljust(9, b"\x00")[:9]:
        crc = _crc_ccitt_update(crc, byte)
    return _crc_ccitt_update(crc, message.type & 0xFF)


@dataclass(frozen=True, slots=True)
class PayloadLimit:
    """What one message may carry.

    Parameters
    ----------
    name : str
        ``"kilolib"`` or ``"thesis"``.
    data_bits : int
        Payload bits available for ``data`` (72 under kilolib v2, 23 in the thesis's library).
    has_type : bool
        Whether the ``type`` byte exists (the thesis's library had none: type must be 0).
    air_bytes : int
        Bytes on the air including type and CRC; sets the airtime.
    """

    name: str
    data_bits: int
    has_type: bool
    air_bytes: int

    def check(self, message: Message, sender: int | None = None) -> None:
        """Raise :class:`PayloadError` if ``message`` is not a :class:`Message` that fits
        this limit; the error names robot ``sender``'s ``message_tx()`` when it is given."""
        if not isinstance(message, Message):
            who = "message_tx()" if sender is None else f"robot {sender}'s message_tx()"
            shown = repr(message)
            shown = shown if len(shown) <= 40 else shown[:37] + "..."
            raise PayloadError(
                f"{who} returned {type(message).__name__} {shown}, not a Message or None; "
                "return Message(data_bytes, type) or a Layout's pack(...)"
            )
        data = message.data
        if not isinstance(data, bytes | bytearray):
            raise PayloadError(f"message data must be bytes, got {type(data).__name__}")
        if not isinstance(message.type, int) or not 0 <= message.type <= 255:
            raise PayloadError(f"message type {message.type!r} is not a byte (0-255)")
        if not self.has_type and message.type != 0:
            raise PayloadError(
                f"the {self.name} message format has no type byte; got type={message.type}"
            )
        if message.type >= SYSTEM_TYPES:
            raise PayloadError(
                f"message type {message.type}: types {SYSTEM_TYPES} and up are kilolib's system "
                "messages (the overhead controller's boot, reset, run ...), which never reach "
                "message_rx; use a type below 128"
            )
        # Little-endian like Layout: bits beyond the limit are the top bits of the last byte.
        used = int.from_bytes(data, "little").bit_length()
        if len(data) > -(-self.data_bits // 8) or used > self.data_bits:
            raise PayloadError(
                f"message payload of {len(data)} bytes ({used} significant bits) exceeds "
                f"the {self.name} limit of {self.data_bits} bits; pack fields more tightly"
            )


#: The struct codes a :class:`Layout` field may use: integers of 1, 2 and 4 bytes and a bool
#: (floats and strings do not belong in a 9-byte payload; scale a number to an integer).
FIELD_CODES = ("B", "b", "H", "h", "I", "i", "?")

#: kilolib's ``message_type_t`` for a program's own messages (``message.h``).
NORMAL = 0
#: The first of kilolib's system message types (``BOOT = 0x80``): kilolib handles them itself.
SYSTEM_TYPES = 0x80

#: kilolib v2: ``data[9]`` + type + 16-bit CRC = 12 bytes on the air.
KILOLIB = PayloadLimit("kilolib", data_bits=72, has_type=True, air_bytes=12)
#: The thesis's library: 2 bytes and 7 bits of payload plus a checksum, "almost 4 bytes".
THESIS = PayloadLimit("thesis", data_bits=23, has_type=False, air_bytes=4)
#: The limits by ``medium.message_format``.
LIMITS = {"kilolib": KILOLIB, "thesis": THESIS}


class Layout:
    """A named message format: fields packed little-endian with :mod:`struct` codes.

    Parameters
    ----------
    name : str
        Name of the format; the unpacked record type is its CamelCase form.
    type : int
        The message type byte every message of this layout carries.
    fields : list of (name, code) or (name, code, scale)
        ``code`` is a struct code (``B`` uint8, ``b`` int8, ``H`` uint16, ``h`` int16, ``I``,
        ``i``, ``?``). With ``scale``, the stored integer is ``round(value / scale)`` and
        :meth:`unpack` returns ``stored * scale`` (e.g. ``("x_mm", "h", 0.1)`` stores tenths of
        a millimetre).
    max_bytes : int
        Payload size the layout must fit (9, kilolib v2).

    Raises
    ------
    PayloadError
        If the fields take more than ``max_bytes``, or a code is not one of
        :data:`FIELD_CODES`.
    """

    def __init__(
        self,
        name: str,
        *,
        type: int,
        fields: list[tuple[str, str] | tuple[str, str, float]],
        max_bytes: int = 9,
    ) -> None:
        self.name = name
        self.type = type
        self._names = [f[0] for f in fields]
        self._codes = [f[1] for f in fields]
        for field_name, code in zip(self._names, self._codes, strict=True):
            if code not in FIELD_CODES:
                raise PayloadError(
                    f"layout {name!r}: field {field_name} has struct code {code!r}; a field is "
                    f"one of {', '.join(FIELD_CODES)} (a number with a fraction is a scaled "
                    f"integer: ({field_name!r}, 'h', 0.1) stores tenths)"
                )
        self._scales = [f[2] if len(f) > 2 else None for f in fields]
        self._named_scales = list(zip(self._names, self._scales, strict=True))
        self._struct = struct.Struct("<" + "".join(self._codes))
        if self._struct.size > max_bytes:
            raise PayloadError(
                f"layout {name!r} needs {self._struct.size} bytes, more than the {max_bytes}-byte "
                "payload"
            )
        record_name = "".join(part.capitalize() for part in name.split("_"))
        self.record = namedtuple(record_name, self._names)
        self._make = self.record._make
        self._scaled = any(s is not None for s in self._scales)

    @property
    def size_bytes(self) -> int:
        """Payload bytes this layout uses."""
        return self._struct.size

    @property
    def fields(self) -> list[tuple[str, str, float | None]]:
        """The fields in payload order, each as ``(name, struct code, scale or None)``.

        Examples
        --------
        >>> Layout("p", type=3, fields=[("seed", "B"), ("x_mm", "h", 0.5)]).fields
        [('seed', 'B', None), ('x_mm', 'h', 0.5)]
        """
        return list(zip(self._names, self._codes, self._scales, strict=True))

    def __repr__(self) -> str:
        return f"Layout({self.name!r}, type={self.type})"

    def pack(self, **values: Any) -> Message:
        """Build a :class:`Message` from field values.

        Raises
        ------
        PayloadError
            If a field is missing, unknown, or its value does not fit the field's type.
        """
        try:
            raw = [
                values[name] if scale is None else round(values[name] / scale)
                for name, scale in self._named_scales
            ]
        except KeyError:
            raw = None
        if raw is None or len(values) != len(raw):
            unknown = set(values) - set(self._names)
            missing = [n for n in self._names if n not in values]
            raise PayloadError(
                f"layout {self.name!r}: missing fields {missing}, unknown fields {sorted(unknown)}"
            )
        try:
            return Message(self._struct.pack(*raw), self.type)
        except struct.error as exc:
            for name, code, value in zip(self._names, self._codes, raw, strict=True):
                try:
                    struct.pack("<" + code, value)
                except struct.error:
                    raise PayloadError(
                        f"layout {self.name!r}: field {name}={values[name]!r} does not fit "
                        f"struct code {code!r}"
                    ) from exc
            raise PayloadError(f"layout {self.name!r}: {exc}") from exc

    def unpack(self, message: Message) -> Any:
        """Read the fields of ``message`` back as a named tuple.

        Raises
        ------
        PayloadError
            If the message's type is not this layout's, or the payload is too short.
        """
        decoded = message._decoded
        if decoded is not None and decoded[0] is self:
            return decoded[1]
        if message.type != self.type:
            raise PayloadError(
                f"layout {self.name!r} has type {self.type}, the message has {message.type}"
            )
        try:
            raw = self._struct.unpack_from(message.data)
        except struct.error as exc:
            raise PayloadError(f"layout {self.name!r}: {exc}") from exc
        if self._scaled:
            raw = [v * s if s else v for v, s in zip(raw, self._scales, strict=True)]
        record = self._make(raw)
        object.__setattr__(message, "_decoded", (self, record))  # records are immutable
        return record

    def matches(self, message: Message) -> bool:
        """Whether ``message`` carries this layout's type byte."""
        return message.type == self.type
