"""A seed's transform of its frame (phase 6, :mod:`kilonet.protocols.gcs.phase6_merging`) and its
wire form: the rotation as three int16 quaternion words, the version byte with its done bit.

Every robot reads transforms (its global estimate, :mod:`kilonet.protocols.gcs.global_estimate`);
only phase 6 makes them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kilonet.protocols.common.alignment import (
    level_matrix,
    pack_quaternion,
    unpack_quaternion,
    words_matrix,
)

__all__ = [
    "Transform",
    "quaternion_fields",
    "rotation_from_fields",
    "version_byte",
    "version_number",
]

_DONE = 0x80  # bit of the version byte: the seed is done
_VERSION = 0x7F  # bits of the version byte that count versions (they wrap after 128)


def version_byte(version: int, done: bool) -> int:
    """The version byte a seed broadcasts: the version's 7 low bits, bit 7 when done.

    Examples
    --------
    >>> version_byte(130, True), version_number(version_byte(130, True))
    (130, 2)
    """
    return (version & _VERSION) | (_DONE if done else 0)


def version_number(byte: int) -> int:
    """The version a version byte counts (bit 7, done, left out)."""
    return byte & _VERSION


class Transform:
    """A seed's frame transform as a robot holds it: ``global = rotation · (x, y, 0) + shift``.

    A heard transform keeps the three message words and decodes the rotation on first use:
    robots hear many more transforms than they ever use, and decoding is the costly part.

    Parameters
    ----------
    shift : (3,) array
        mm.
    version : int
        The version byte as broadcast (bit 7: the seed is done).
    rotation : Rotation, optional
        The rotation itself (a seed's own transform) ...
    words : tuple of three int, optional
        ... or its :func:`quaternion_fields` words (a heard one).

    Raises
    ------
    ValueError
        Unless exactly one of ``rotation`` and ``words`` is given.
    """

    __slots__ = ("_affine", "_flat", "_matrix", "_rotation", "_words", "shift", "version")

    def __init__(
        self,
        shift: np.ndarray,
        version: int,
        *,
        rotation: Rotation | None = None,
        words: tuple[int, int, int] | None = None,
    ) -> None:
        if (rotation is None) == (words is None):
            raise ValueError("give a Transform either its rotation or its words")
        self._rotation, self._words = rotation, words
        self.shift, self.version = shift, version
        self._matrix: np.ndarray | None = None
        self._flat: np.ndarray | None = None
        self._affine: tuple[float, ...] | None = None  # apply_point's matrix columns and shift

    @property
    def words(self) -> tuple[int, int, int] | None:
        """The message words it was heard as (``None`` for a seed's own)."""
        return self._words

    @property
    def rotation(self) -> Rotation:
        """The rotation (decoded from the words on first use when heard)."""
        if self._rotation is None:
            self._rotation = unpack_quaternion(self._words)
        return self._rotation

    def apply_point(self, x_mm: float, y_mm: float) -> tuple[float, float, float]:
        """One local point (x, y, 0), mm, in the seed's "global" coordinates, mm (a robot asks
        this many times a second: plain floats, not NumPy or a scipy ``Rotation.apply``)."""
        if self._affine is None:
            (a, b, _), (c, d, _), (e, f, _) = self.matrix.tolist()
            self._affine = (a, b, c, d, e, f, *(float(v) for v in self.shift))
        a, b, c, d, e, f, sx, sy, sz = self._affine
        return a * x_mm + b * y_mm + sx, c * x_mm + d * y_mm + sy, e * x_mm + f * y_mm + sz

    @property
    def matrix(self) -> np.ndarray:
        """The rotation as a 3×3 matrix (computed once, from the words when heard)."""
        if self._matrix is None:
            words = self._words
            self._matrix = self.rotation.as_matrix() if words is None else words_matrix(words)
        return self._matrix

    @property
    def flat(self) -> np.ndarray:
        """The 3×3 matrix of :func:`kilonet.protocols.common.alignment.level_matrix` for this
        transform: global coordinates in the common plane laid flat are the first two of ``flat @
        g``."""
        if self._flat is None:
            self._flat = level_matrix(self.matrix)
        return self._flat

    @property
    def done(self) -> bool:
        """Whether the seed reported itself done with this version."""
        return bool(self.version & _DONE)

    def apply(self, points_mm: np.ndarray) -> np.ndarray:
        """Local points, (n, 3) or (3,), mm, in the seed's "global" coordinates, mm."""
        return points_mm @ self.matrix.T + self.shift


def quaternion_fields(rotation: Rotation) -> dict[str, int]:
    """The message fields of a rotation: the three words of
    :func:`kilonet.protocols.common.alignment.pack_quaternion` (at most 0.0086° lost, also near
    180°)."""
    q0, q1, q2 = pack_quaternion(rotation)
    return {"q0": q0, "q1": q1, "q2": q2}


def rotation_from_fields(q0: int, q1: int, q2: int) -> Rotation:
    """The rotation carried by three message words.

    Examples
    --------
    >>> r = Rotation.from_euler("x", 180, degrees=True)
    >>> back = rotation_from_fields(**quaternion_fields(r))
    >>> bool(np.degrees((back * r.inv()).magnitude()) < 0.01)
    True
    """
    return unpack_quaternion((q0, q1, q2))
