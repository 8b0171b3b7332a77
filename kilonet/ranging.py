"""kilolib's raw distance measurement and ``estimate_distance``, on per-robot calibration tables.

A Kilobot measures the strength of each message it receives twice, through a high-gain and a
low-gain amplifier (``distance_measurement_t``: two 10-bit ADC readings), and
``estimate_distance`` turns them into millimetres with the robot's calibration tables
``kilo_irhigh[14]`` and ``kilo_irlow[14]`` (readings at 0, 5, ..., 65 mm between the bodies,
i.e. 33-98 mm centre to centre): it interpolates linearly within the table, uses the high-gain
reading below 900, the low-gain one above 700, blends the two in between, and adds the 33 mm
body diameter. :func:`estimate_distance` is that algorithm, transcribed from ``kilolib.c``.

The tables come from a model of the received intensity, not from measured robots (none are
published): relative intensity ``1 / (1 + gap / 25 mm)**2`` (:func:`intensity`), high gain
``40 + 1400 i`` (saturating at 1023), low gain ``40 + 450 i`` (:func:`readings`), each robot's
receiver gain ``1 + N(0, 0.05)`` (:func:`calibration_tables`). A robot is calibrated against a
reference emitter, so its tables hold its own gain but not the strength of the robots it will
hear: a message from a stronger emitter reads as nearer. Beyond the tables (65 mm between the
bodies) kilolib extrapolates the last segment of the high-gain table, and the readings approach
their floor, so estimates saturate: :func:`estimate_distance_array` is the same algorithm on
arrays, which the medium's default reception model uses (:mod:`kilonet.reception`).

kilonet's medium delivers the estimate itself (``robot.rx_distance = "estimate"``, the default;
see :mod:`kilonet.reception`). With ``"raw"``, ``message_rx`` receives a
:class:`DistanceMeasurement` instead: the readings, on the receiver's tables, that kilolib's
``estimate_distance`` maps to that same estimate (:func:`measurement_for`), so a program ported
line by line (``dist = self.estimate_distance(d)``) sees the same numbers either way.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

__all__ = [
    "CalibrationTables",
    "DistanceMeasurement",
    "ReadingLookup",
    "TableLookup",
    "calibration_tables",
    "estimate_distance",
    "estimate_distance_array",
    "intensity",
    "measurement_for",
    "read_calibration",
    "readings",
]

_GAPS_MM = np.arange(14) * 5.0  # the tables' distances between the bodies


@dataclass(frozen=True, slots=True)
class DistanceMeasurement:
    """kilolib's ``distance_measurement_t``: 10-bit ADC readings of a message's strength."""

    low_gain: int
    high_gain: int


@dataclass(frozen=True)
class CalibrationTables:
    """A robot's ``kilo_irhigh[14]`` and ``kilo_irlow[14]`` (readings, decreasing with distance),
    and the receiver gain they were measured with (relative; 1 for a median robot)."""

    irhigh: tuple[int, ...]
    irlow: tuple[int, ...]
    gain: float = 1.0


def intensity(gap_mm: np.ndarray | float) -> np.ndarray:
    """Relative intensity a median receiver gets from a median emitter ``gap_mm`` between the
    bodies (1 at contact).

    Examples
    --------
    >>> intensity(np.array([0.0, 25.0, 75.0])).tolist()
    [1.0, 0.25, 0.0625]
    """
    return 1.0 / (1.0 + np.asarray(gap_mm, dtype=float) / 25.0) ** 2


def readings(relative_intensity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 10-bit high- and low-gain ADC readings (floats, before rounding) of a relative
    intensity: ``40 + 1400 i`` saturating at 1023, and ``40 + 450 i``.

    Examples
    --------
    >>> high, low = readings(np.array([1.0, 0.1]))
    >>> high.tolist(), low.tolist()
    ([1023.0, 180.0], [490.0, 85.0])
    """
    i = np.asarray(relative_intensity, dtype=float)
    return np.minimum(1023.0, 40.0 + 1400.0 * i), np.minimum(1023.0, 40.0 + 450.0 * i)


def calibration_tables(n: int, rng: np.random.Generator, spread: float = 0.05) -> list:
    """Calibration tables of ``n`` robots from the intensity model in the module docstring.

    Examples
    --------
    >>> t = calibration_tables(1, np.random.default_rng(1), spread=0.0)[0]
    >>> t.irhigh[:4], t.irlow[:4]
    ((1023, 1012, 754, 587), (490, 352, 270, 216))
    """
    scale = 1.0 + spread * rng.standard_normal(n)
    tables = []
    for s in scale:
        high, low = readings(s * intensity(_GAPS_MM))
        tables.append(
            CalibrationTables(
                tuple(np.rint(high).astype(int).tolist()),
                tuple(np.rint(low).astype(int).tolist()),
                float(s),
            )
        )
    return tables


def read_calibration(path: str, n: int) -> list[CalibrationTables]:
    """The calibration tables of ``n`` robots from a CSV file: one row per robot, in robot
    order, with columns ``irhigh_0`` ... ``irhigh_13`` and ``irlow_0`` ... ``irlow_13`` (the
    values ``kilo_irhigh`` and ``kilo_irlow`` hold in each robot's EEPROM: ADC readings at 0,
    5, ..., 65 mm between the bodies). Each robot's receiver gain is fitted to its high-gain
    table against :func:`intensity`.

    Raises
    ------
    kilonet.params.ParamError
        One line naming the file and line: a missing or unreadable file, a missing column, a
        value that is not an integer 0-1023, a table that rises with distance, or fewer rows
        than robots.
    """
    import csv

    from kilonet.errors import read_text
    from kilonet.params import ParamError

    where = f"ranging.calibration_file {path}"
    text = read_text(path, ParamError, "calibration file", newline="")
    reader = csv.DictReader(text.splitlines())
    columns = [f"irhigh_{k}" for k in range(14)] + [f"irlow_{k}" for k in range(14)]
    missing = [c for c in columns if c not in (reader.fieldnames or [])]
    if missing:
        raise ParamError(f"{where}: no column {missing[0]} (needs irhigh_0..13, irlow_0..13)")
    tables = []
    ideal = intensity(_GAPS_MM)
    for line, row in enumerate(reader, start=2):
        values = []
        for c in columns:
            raw = (row.get(c) or "").strip()
            if not (raw.isascii() and raw.isdigit() and 0 <= int(raw) <= 1023):
                raise ParamError(f"{where}:{line}: {c} = {raw!r} is not an integer 0-1023")
            values.append(int(raw))
        high, low = tuple(values[:14]), tuple(values[14:])
        for name, table in (("irhigh", high), ("irlow", low)):
            if any(b > a for a, b in itertools.pairwise(table)):
                raise ParamError(f"{where}:{line}: {name} rises with distance: {list(table)}")
        unsaturated = np.asarray(high) < 1023
        if not unsaturated.any():
            raise ParamError(f"{where}:{line}: irhigh is saturated (1023) at every distance")
        gain = float(
            np.median((np.asarray(high)[unsaturated] - 40.0) / (1400 * ideal[unsaturated]))
        )
        tables.append(CalibrationTables(high, low, gain))
    if len(tables) < n:
        raise ParamError(f"{where}: {len(tables)} robots' tables for a swarm of {n}")
    return tables[:n]


def _table_mm(reading: int, table: tuple[int, ...], beyond: int | None) -> int:
    """kilolib's interpolation on one table: mm between the bodies, truncated like the C code."""
    if reading > table[0]:
        return 0
    index = next((k for k in range(1, 14) if reading > table[k]), None)
    if index is None:
        if beyond is not None:
            return beyond
        index = 13
    slope = (table[index] - table[index - 1]) / 0.5
    b = table[index] - slope * (index * 0.5)
    return int(int((reading - b) * 10) / int(slope))


def estimate_distance(d: DistanceMeasurement | int, tables: CalibrationTables) -> int:
    """kilolib's ``estimate_distance``: centre-to-centre distance in mm (0-255, uint8).

    An ``int`` is an estimate already (the medium's default delivery) and is returned as it is.

    Examples
    --------
    >>> t = calibration_tables(1, np.random.default_rng(1), spread=0.0)[0]
    >>> estimate_distance(DistanceMeasurement(low_gain=300, high_gain=400), t)
    57
    >>> estimate_distance(DistanceMeasurement(low_gain=300, high_gain=800), t)  # blended
    41
    >>> estimate_distance(47, t)
    47
    """
    if not isinstance(d, DistanceMeasurement):
        return int(d)
    high, low = d.high_gain, d.low_gain
    dist_high = dist_low = 255
    if high < 900:
        dist_high = _table_mm(high, tables.irhigh, None)
    if high > 700:
        dist_low = _table_mm(low, tables.irlow, 90)
    if dist_low != 255:
        if dist_high != 255:
            blended = (dist_high * (900.0 - high) + dist_low * (high - 700.0)) / 200.0
            return int(33 + blended) & 0xFF
        return (33 + dist_low) & 0xFF
    return (33 + dist_high) & 0xFF


def _table_mm_array(reading: np.ndarray, table: np.ndarray, beyond: int | None) -> np.ndarray:
    """:func:`_table_mm` on arrays: ``reading`` (..., R) on tables (R, 14), one per column."""
    table = table.astype(np.int64)
    # The first k in 1..13 with reading > table[k] (13 if none): from the last down, each
    # match overwrites, so the first one stays.
    index = np.full(np.broadcast_shapes(np.shape(reading), table.shape[:1]), 13)
    found = np.zeros(index.shape, dtype=bool)
    for k in range(13, 0, -1):
        above = reading > table[:, k]
        index[above] = k
        found |= above
    cols = np.broadcast_to(np.arange(table.shape[0]), index.shape)
    t_hi, t_lo = table[cols, index], table[cols, index - 1]
    slope = (t_hi - t_lo) / 0.5
    b = t_hi - slope * (index * 0.5)
    scaled = np.trunc((reading - b) * 10)
    mm = np.trunc(scaled / np.trunc(slope)).astype(np.int64)
    if beyond is not None:
        mm = np.where(found, mm, beyond)
    return np.where(reading > table[:, 0], 0, mm)


def estimate_distance_array(
    high: np.ndarray, low: np.ndarray, irhigh: np.ndarray, irlow: np.ndarray
) -> np.ndarray:
    """:func:`estimate_distance` on arrays of readings, column ``k`` on the tables of row ``k``
    of ``irhigh`` and ``irlow`` ((R, 14) arrays): estimates in mm (int, 0-255).

    Examples
    --------
    >>> t = calibration_tables(2, np.random.default_rng(1))
    >>> irh = np.array([x.irhigh for x in t]); irl = np.array([x.irlow for x in t])
    >>> high = np.array([[400, 800], [100, 950]]); low = np.array([[300, 300], [60, 500]])
    >>> estimate_distance_array(high, low, irh, irl).tolist() == [
    ...     [estimate_distance(DistanceMeasurement(int(lo), int(hi)), t[k])
    ...      for k, (hi, lo) in enumerate(zip(hr, lr))] for hr, lr in zip(high, low)]
    True
    """
    high = np.asarray(high, dtype=np.int64)
    low = np.asarray(low, dtype=np.int64)
    dist_high = np.where(high < 900, _table_mm_array(high, irhigh, None), 255)
    return _blend(high, dist_high, _table_mm_array(low, irlow, 90))


class TableLookup:
    """:func:`estimate_distance_array` for a swarm's tables, by table look-up: each robot's
    interpolation (``_table_mm``) on its high- and low-gain tables is computed once for every
    10-bit reading, so an estimate costs two look-ups and the blend. The result is the same,
    bit for bit (the interpolation of one reading depends on that reading and one table only).

    Parameters
    ----------
    irhigh, irlow : (N, 14) int arrays
        Each robot's ``kilo_irhigh`` and ``kilo_irlow``.

    Examples
    --------
    >>> t = calibration_tables(2, np.random.default_rng(1))
    >>> irh = np.array([x.irhigh for x in t]); irl = np.array([x.irlow for x in t])
    >>> high = np.array([[400, 800], [100, 950]]); low = np.array([[300, 300], [60, 500]])
    >>> lookup = TableLookup(irh, irl)
    >>> bool((lookup.estimates(high, low, np.array([0, 1])) ==
    ...       estimate_distance_array(high, low, irh, irl)).all())
    True
    """

    #: Chunk of robots whose look-up rows are computed at once (bounds the temporary arrays).
    _CHUNK = 256

    def __init__(self, irhigh: np.ndarray, irlow: np.ndarray) -> None:
        every = np.arange(1024, dtype=np.int64)[:, None]  # (1024, 1): every 10-bit reading
        #: (N, 1024): robot k's high-gain distance of reading v (255 from 900 on: unused).
        self.high_mm = self._rows(every, np.asarray(irhigh), None)
        self.high_mm[:, 900:] = 255
        #: (N, 1024): robot k's low-gain distance of reading v.
        self.low_mm = self._rows(every, np.asarray(irlow), 90)
        self._high_flat, self._low_flat = self.high_mm.ravel(), self.low_mm.ravel()

    @classmethod
    def _rows(cls, every: np.ndarray, tables: np.ndarray, beyond: int | None) -> np.ndarray:
        """(N, 1024) int16: ``_table_mm`` of every reading on each robot's table."""
        rows = [
            _table_mm_array(every, tables[k : k + cls._CHUNK], beyond).T
            for k in range(0, len(tables), cls._CHUNK)
        ]
        out = np.concatenate(rows) if rows else np.empty((0, 1024), dtype=np.int64)
        if len(out) and (out.min() < -(1 << 15) or out.max() >= 1 << 15):
            return out
        return out.astype(np.int16)

    def estimates(self, high: np.ndarray, low: np.ndarray, receivers: np.ndarray) -> np.ndarray:
        """Estimates in mm (int, 0-255) of integer readings ``high`` and ``low`` (..., R, each
        0-1023), column ``k`` on the tables of robot ``receivers[k]``."""
        high = np.asarray(high, dtype=np.intp)
        low = np.asarray(low, dtype=np.intp)
        row = receivers * 1024  # where each receiver's row starts in the flat tables
        return _blend(high, self._high_flat.take(high + row), self._low_flat.take(low + row))


class ReadingLookup:
    """Clipped estimates (uint8, mm) of reading pairs that come from one intensity
    (:func:`readings`), by one look-up each: the medium's reception model asks this for every
    block of receptions it draws, where :meth:`TableLookup.estimates`, the blend and the clip
    cost a few dozen NumPy calls on small arrays. The result is :meth:`TableLookup.estimates`
    clipped to ``[min_mm, max_mm]``, bit for bit: every entry is computed by it.

    kilolib's estimate of a pair depends on the high-gain reading alone up to 700 (the low-gain
    table is not used) and on the low-gain reading alone from 900 (the high-gain one is
    saturated); in between it blends both. There, the two readings of one intensity are tied:
    a high reading ``h`` spans an intensity band in which the low reading, 450/1400 as steep,
    takes at most two neighbouring values. So each robot's table holds one estimate per high
    reading up to 700, :data:`_BAND` per high reading in between (the low readings from
    ``_band_low[h]``, with a margin of one on either side) and one per low reading from 900.

    Parameters
    ----------
    lookup : TableLookup
        The swarm's tables.
    min_mm, max_mm : int
        The clip (``ranging.min_mm``, ``ranging.max_mm``).

    Examples
    --------
    >>> t = calibration_tables(3, np.random.default_rng(1))
    >>> lookup = TableLookup(np.array([x.irhigh for x in t]), np.array([x.irlow for x in t]))
    >>> high, low = readings(np.array([[0.02, 0.5, 0.9], [0.3, 0.47, 0.61]]))
    >>> high, low = np.rint(high), np.rint(low)
    >>> receivers = np.array([2, 0, 1])
    >>> bool((ReadingLookup(lookup, 0, 255).estimates(high, low, receivers) ==
    ...       lookup.estimates(high, low, receivers)).all())
    True
    """

    #: Low readings kept per high reading in the blend band (two possible, one margin each side).
    _BAND = 4
    _CHUNK = 128

    def __init__(self, lookup: TableLookup, min_mm: int, max_mm: int) -> None:
        every = np.arange(1024)
        middle = every[701:900]
        # the low reading of the intensity at the lower edge of high reading h, less the margin
        band_low = np.rint(40.0 + 450.0 * (middle - 40.5) / 1400.0).astype(np.intp) - 1
        band = self._BAND
        slot_high = np.concatenate([every[:701], np.repeat(middle, band), np.full(1024, 900)])
        slot_low = np.concatenate(
            [np.zeros(701, dtype=np.intp), (band_low[:, None] + np.arange(band)).ravel(), every]
        )
        width = len(slot_high)
        # slot of (h, l) = offset[h] + l * uses_low[h]
        offset = np.concatenate(
            [every[:701], 701 + band * np.arange(len(middle)) - band_low, np.full(124, 0)]
        )
        offset[900:] = 701 + band * len(middle)
        self._offset = offset.astype(np.intp)
        self._uses_low = (every > 700).astype(np.intp)
        self._width = width
        n = lookup.high_mm.shape[0]
        rows = []
        for k in range(0, n, self._CHUNK):
            robots = np.arange(k, min(n, k + self._CHUNK))
            est = lookup.estimates(slot_high[None, :], slot_low[None, :], robots[:, None])
            rows.append(np.clip(est, min_mm, max_mm).astype(np.uint8))
        #: (N * width,) uint8: robot k's estimates from k * width on.
        self.table = np.concatenate(rows).ravel() if rows else np.empty(0, dtype=np.uint8)

    def estimates(self, high: np.ndarray, low: np.ndarray, receivers: np.ndarray) -> np.ndarray:
        """Estimates (uint8, mm, clipped) of integer readings ``high`` and ``low`` (..., R,
        each 0-1023, both from one intensity through :func:`readings` and rounding), column
        ``k`` on the tables of robot ``receivers[k]``."""
        high = np.asarray(high, dtype=np.intp)
        low = np.array(low, dtype=np.intp)  # a copy: it becomes the slot
        low *= self._uses_low.take(high)
        low += self._offset.take(high)
        low += receivers * self._width
        return self.table.take(low)


def _blend(high: np.ndarray, dist_high: np.ndarray, table_low: np.ndarray) -> np.ndarray:
    """kilolib's choice and blend of the two tables' distances (mm between the bodies) by the
    high-gain reading ``high``: ``dist_high`` is the high-gain table's (255 where ``high`` is
    900 or more), ``table_low`` the low-gain table's; the centre-to-centre estimate, mm (int,
    0-255)."""
    dist_low = np.where(high > 700, table_low, 255)
    blended = (dist_high * (900.0 - high) + dist_low * (high - 700.0)) / 200.0
    blended += 33
    out = np.where(
        dist_low != 255,
        np.where(dist_high != 255, np.trunc(blended).astype(np.int64), dist_low + 33),
        dist_high + 33,
    )
    out &= 0xFF
    return out


def _reading(table: tuple[int, ...], gap_mm: float) -> float:
    """The reading a table predicts at ``gap_mm`` between the bodies (linear interpolation)."""
    return float(np.interp(gap_mm, _GAPS_MM, np.asarray(table, dtype=float)))


def measurement_for(estimate_mm: int, tables: CalibrationTables) -> DistanceMeasurement:
    """Readings on ``tables`` that :func:`estimate_distance` maps to ``estimate_mm``, as near
    as the tables allow (an estimate outside their 33-98 mm gets the nearest reachable one).

    Examples
    --------
    >>> t = calibration_tables(1, np.random.default_rng(1), spread=0.0)[0]
    >>> [estimate_distance(measurement_for(mm, t), t) for mm in (40, 59, 85)]
    [40, 59, 85]
    """
    gap = min(max(estimate_mm - 33, 0), 65)
    best, best_err = None, None
    centre_h, centre_l = _reading(tables.irhigh, gap), _reading(tables.irlow, gap)
    for dh in range(-6, 7):
        high = int(np.clip(round(centre_h) + dh, 0, 1023))
        for dl in (0, -1, 1, -2, 2, -3, 3):
            low = int(np.clip(round(centre_l) + dl, 0, 1023))
            m = DistanceMeasurement(low, high)
            err = abs(estimate_distance(m, tables) - estimate_mm)
            if best_err is None or err < best_err:
                best, best_err = m, err
            if err == 0:
                return m
    return best
