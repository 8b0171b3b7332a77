"""Every model parameter in one typed, validated structure.

Parameters live in sections (``medium``, ``ranging``, ``robot``, ``battery``, ``motion``,
``faults``, ``placement``, ``light``, ``trace``, plus one section per scenario) and are
addressed by dotted keys such as ``medium.loss_prob``. Each field carries its unit in its name
and its valid range in its metadata, so a wrong key or an out-of-range value is an error that
names the key.

Examples
--------
>>> p = Params()
>>> p = p.with_overrides({"medium.loss_prob": "0.2", "robot.rx_mode": "polled"})
>>> p.medium.loss_prob, p.robot.rx_mode
(0.2, 'polled')
>>> p.with_overrides({"medium.los": "1"})
Traceback (most recent call last):
...
kilonet.params.ParamError: unknown parameter 'medium.los'; medium has: airtime_s, ...
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Literal

from kilonet.errors import UserError, read_text

__all__ = [
    "BatteryParams",
    "FaultParams",
    "LightParams",
    "MediumParams",
    "MotionParams",
    "ParamError",
    "Params",
    "PlacementParams",
    "RangingParams",
    "RobotParams",
    "TraceParams",
    "param",
]


class ParamError(UserError, ValueError):
    """A parameter key is unknown or its value is invalid; the message names the key."""


def param(default: Any, *, lo: float | None = None, hi: float | None = None, doc: str = "") -> Any:
    """Declare a dataclass field with an inclusive valid range and a one-line description."""
    return field(default=default, metadata={"lo": lo, "hi": hi, "doc": doc})


@dataclass(frozen=True)
class MediumParams:
    """The infrared channel."""

    reach: Literal["argos", "argos-long", "disc"] = param(
        "argos",
        doc="how far links reach: per-robot reach with a soft edge fitted to real Kilobots "
        "(argos: the ARGoS data's majority series; argos-long: its long-reach series), or "
        "one hard radius range_mm (disc: the thesis's and Kilombo's model)",
    )
    range_mm: float = param(85.0, lo=33.0, hi=1000.0, doc="disc: reception range, centre to centre")
    reach_median_mm: float | None = param(
        None, lo=33.0, hi=1000.0, doc="argos*: median link reach, mm; none: the preset's"
    )
    rx_sensitivity_sd: float | None = param(
        None, lo=0.0, hi=1.0, doc="argos*: log spread of receiver sensitivity; none: preset's"
    )
    edge_mm: float | None = param(
        None, lo=0.0, hi=100.0, doc="argos*: width of a link's soft edge, mm; none: preset's"
    )
    tx_strength_sd: float = param(
        0.08,
        lo=0.0,
        hi=1.0,
        doc="log spread of emitter strength: each sender's reach, and the bias it gives "
        "the receivers' distance estimates",
    )
    occlusion: Literal["none", "graded", "block"] = param(
        "none",
        doc="bodies between sender and receiver: no effect (real-robot data), each weakens "
        "the link (graded), or cuts it (block)",
    )
    occlusion_range_factor: float = param(
        0.9, lo=0.0, hi=1.0, doc="graded: each body crossed scales the link's reach by this"
    )
    occlusion_loss: float = param(
        0.1, lo=0.0, hi=1.0, doc="graded: each body crossed loses this share of receptions"
    )
    loss_prob: float = param(0.0, lo=0.0, hi=1.0, doc="independent loss per reception")
    message_format: Literal["kilolib", "thesis"] = param(
        "kilolib", doc="payload limit: kilolib v2 9 bytes, or the thesis's 23 bits"
    )
    bitrate_bps: float = param(
        29_740.0, lo=100.0, hi=1e7, doc="on-air bit rate (kilolib: 8 MHz / 269 cycles a bit)"
    )
    preamble_s: float = param(
        0.0012,
        lo=0.0,
        hi=1.0,
        doc="per message on air beyond its bytes: preamble and contention check (message_send.S)",
    )
    airtime_s: float = param(
        0.0,
        lo=0.0,
        hi=1.0,
        doc="airtime of one message; 0 derives it from format, bitrate and preamble",
    )
    csma: bool = param(True, doc="sense the carrier and back off while the channel is busy")
    sense_delay_s: float = param(
        0.0002,
        lo=0.0,
        hi=0.1,
        doc="a reception is sensed as a carrier this long after it begins (about 6 bit "
        "times; fitted to the ARGoS data's short links): senders starting closer collide",
    )
    backoff_max_s: float = param(
        0.03264,
        lo=1.28e-4,  # one count of kilolib's 7,812.5 Hz timer, its least wait
        hi=10.0,
        doc="random back-off is U(0, this), own clock (kilolib: rand() & 0xFF counts at 7812.5/s)",
    )


@dataclass(frozen=True)
class RangingParams:
    """Distance estimates that come with every reception."""

    model: str = param(
        "tables",
        doc="tables: kilolib's estimate_distance on the receiver's calibration tables from the "
        "received intensity (the sender's strength biases it; saturates beyond the tables); "
        "gaussian: round(true + receiver bias + N(0, sigma_mm)), independent per reception; "
        "or package.module:Class, your own (kilonet.reception)",
    )
    calibration_file: str = param(
        "",
        doc="tables: CSV of each robot's kilo_irhigh/kilo_irlow (columns irhigh_0..13, "
        "irlow_0..13, a row per robot); empty: tables drawn from the intensity model",
    )
    intensity_noise: float = param(
        0.015, lo=0.0, hi=1.0, doc="tables: relative noise of each reception's intensity (sd)"
    )
    sigma_mm: float = param(1.0, lo=0.0, hi=100.0, doc="gaussian: noise per reception (sd)")
    bias_sigma_mm: float = param(
        0.0, lo=0.0, hi=100.0, doc="gaussian: per-receiver bias ~ N(0, this)"
    )
    min_mm: int = param(0, lo=0, hi=255, doc="estimates are clipped to [min_mm, max_mm]")
    max_mm: int = param(255, lo=1, hi=255, doc="uint8 ceiling of kilolib's estimate")


@dataclass(frozen=True)
class RobotParams:
    """The robot runtime (kilolib v2 unless a scenario chooses the thesis's library)."""

    tx_period_s: float = param(
        0.524288,
        lo=0.001,
        hi=60.0,
        doc="one message offer per period, own clock (kilolib: 16 ticks; thesis: 0.2)",
    )
    tx_jitter_s: float = param(
        0.0, lo=0.0, hi=60.0, doc="offer period is period ± U(jitter), own clock"
    )
    tx_retry: Literal["tick", "period"] = param(
        "tick",
        doc="after message_tx() returns None, ask again at the next tick (kilolib) "
        "or the next period (the thesis's send buffer)",
    )
    loop_ticks: int = param(1, lo=1, hi=10_000, doc="loop() runs once every this many ticks")
    ticks_per_s: float = param(
        30.517578125,
        lo=1.0,
        hi=1000.0,
        doc="nominal kilo_ticks rate: 8 MHz / 1024 / 256 (kilolib's TICKS_PER_SEC says 31)",
    )
    clock_sd: float = param(
        0.01, lo=0.0, hi=0.2, doc="per-robot tick-rate error ~ N(0, this); 0: perfect clocks"
    )
    rx_mode: Literal["callback", "polled"] = param(
        "callback", doc="kilolib v2 message_rx on arrival, or the thesis's polled buffer"
    )
    rx_buffer: int = param(3, lo=1, hi=1000, doc="polled mode: messages kept, oldest dropped")
    rx_distance: Literal["estimate", "raw"] = param(
        "estimate",
        doc="message_rx's distance: the estimate in mm, or the raw DistanceMeasurement",
    )
    hardware_uids: bool = param(True, doc="kilo_uid available (False: the thesis's premise)")
    temperature_c: float = param(
        25.0, lo=-40.0, hi=85.0, doc="air temperature get_temperature() measures"
    )


@dataclass(frozen=True)
class BatteryParams:
    """Battery voltage and how a low battery degrades the robot."""

    enabled: bool = param(True, doc="model the battery at all")
    initial_v: float = param(4.2, lo=0.0, hi=5.0, doc="voltage at start")
    degrade_v: float = param(3.6, lo=0.0, hi=5.0, doc="below this the robot degrades")
    cutoff_v: float = param(3.2, lo=0.0, hi=5.0, doc="at this the robot stops")
    idle_drain_v_per_h: float = param(
        1.0 / 24.0, lo=0.0, hi=100.0, doc="drain with motors off (24 h to cut-off)"
    )
    motor_drain_v_per_h: float = param(
        0.1458, lo=0.0, hi=100.0, doc="extra drain per motor on (both on: 3 h to cut-off)"
    )
    loss_at_cutoff: float = param(0.5, lo=0.0, hi=1.0, doc="extra reception loss at cut-off")
    range_factor_at_cutoff: float = param(0.6, lo=0.0, hi=1.0, doc="range multiplier at cut-off")
    motor_factor_at_cutoff: float = param(0.5, lo=0.0, hi=1.0, doc="speed multiplier at cut-off")
    led_factor_at_cutoff: float = param(0.3, lo=0.0, hi=1.0, doc="LED brightness at cut-off")
    update_s: float = param(1.0, lo=0.01, hi=3600.0, doc="how often degradation is re-evaluated")


@dataclass(frozen=True)
class MotionParams:
    """Vibration-motor motion (see :mod:`kilonet.motion` for the model and its sources)."""

    speed_mm_s: float = param(10.0, lo=0.0, hi=1000.0, doc="forward speed at calibrated drive")
    turn_deg_s: float = param(45.0, lo=0.0, hi=3600.0, doc="one-motor pivot rate, calibrated")
    speed_error: float = param(0.1, lo=0.0, hi=0.9, doc="per-robot relative speed error (sd)")
    turn_error: float = param(0.1, lo=0.0, hi=0.9, doc="per-robot relative turn-rate error (sd)")
    pivot_radius_mm: float = param(
        16.5, lo=0.0, hi=100.0, doc="a one-motor turn pivots about a rear leg this far out"
    )
    pivot_angle_deg: float = param(
        125.5, lo=0.0, hi=180.0, doc="angle between heading and that rear leg (Kilombo)"
    )
    drift_gain: float = param(
        0.5, lo=0.0, hi=10.0, doc="both motors: yaw rate per unit of drive difference"
    )
    motor_offset: float = param(60.0, lo=0.0, hi=255.0, doc="duty cycle at zero drive")
    motor_offset_sd: float = param(3.0, lo=0.0, hi=100.0, doc="per-motor offset spread (sd)")
    motor_gain: float = param(15.0, lo=0.1, hi=255.0, doc="duty cycle per unit of drive")
    motor_gain_sd: float = param(0.1, lo=0.0, hi=0.9, doc="per-motor relative gain spread (sd)")
    calibration_sd: float = param(
        1.0, lo=0.0, hi=50.0, doc="stored calibration values miss the true best ones by N(0, this)"
    )
    stall_drive: float = param(0.5, lo=0.0, hi=10.0, doc="a running motor stalls below this")
    start_drive: float = param(
        1.2, lo=0.0, hi=10.0, doc="a stopped motor starts at this drive (or after a spin-up)"
    )
    max_drive: float = param(2.0, lo=0.1, hi=20.0, doc="drive saturates here")
    step_s: float = param(0.05, lo=0.001, hi=10.0, doc="integration step while moving")


@dataclass(frozen=True)
class LightParams:
    """The light field ``get_ambientlight()`` reads (one source, plus ambient light)."""

    ambient: float = param(200.0, lo=0.0, hi=1023.0, doc="reading with no source, ADC counts")
    source_intensity: float = param(
        0.0, lo=0.0, hi=1e6, doc="the source's reading at its own position above ambient"
    )
    source_x_mm: float = param(0.0, doc="source position on the table")
    source_y_mm: float = param(0.0, doc="source position on the table")
    falloff_mm: float = param(
        300.0, lo=1.0, hi=1e6, doc="distance at which the source's share halves"
    )
    sensor_angle_deg: float = param(
        100.0, lo=-180.0, hi=180.0, doc="where the sensor sees best, CCW from the heading (ARGoS)"
    )
    directionality: float = param(
        1.0, lo=0.0, hi=1.0, doc="source's share x (1 - this * angle off sensor_angle / 180°)"
    )
    noise_sd: float = param(10.0, lo=0.0, hi=1023.0, doc="reading noise, ADC counts (sd)")


@dataclass(frozen=True)
class FaultParams:
    """Faults injected by probability; times are simulated seconds."""

    crash_fraction: float = param(0.0, lo=0.0, hi=1.0, doc="share of robots that crash")
    crash_from_s: float = param(0.0, lo=0.0, doc="crash time drawn from U(from, to)")
    crash_to_s: float = param(0.0, lo=0.0, doc="see crash_from_s")
    remove_fraction: float = param(0.0, lo=0.0, hi=1.0, doc="share of robots removed")
    remove_from_s: float = param(0.0, lo=0.0, doc="removal time drawn from U(from, to)")
    remove_to_s: float = param(0.0, lo=0.0, doc="see remove_from_s")
    faulty_rx_fraction: float = param(0.0, lo=0.0, hi=1.0, doc="share with a faulty receiver")
    faulty_rx_drop_prob: float = param(0.3, lo=0.0, hi=1.0, doc="faulty receiver drop share")
    faulty_rx_delay_prob: float = param(0.3, lo=0.0, hi=1.0, doc="share of the rest delayed")
    faulty_rx_delay_s: float = param(0.5, lo=0.0, hi=60.0, doc="delay is U(0, this)")


@dataclass(frozen=True)
class TraceParams:
    """What a run records beyond LED changes, protocol events, poses and stops."""

    messages: bool = param(False, doc="record every transmission (t_s, sender, receptions)")
    estimates_period_s: float = param(
        1.0,
        lo=0.0,
        hi=3600.0,
        doc="sample each program's position_estimate() this often into the estimates table "
        "(s; 0: never)",
    )


@dataclass(frozen=True)
class PlacementParams:
    """Where robots stand when no placement file is given."""

    kind: Literal["scenario", "hex", "random", "line", "corridor", "c_shape", "ring"] = param(
        "scenario",
        doc="placement generator; 'scenario' uses the scenario's own; corridor, c_shape and "
        "ring (a disc with a hole) place robots at random in their shape",
    )
    robots: int = param(0, lo=0, hi=1_000_000, doc="number of robots; 0 = scenario default")
    spacing_mm: float = param(40.0, lo=33.0, hi=10_000.0, doc="hex/line lattice spacing")
    jitter_mm: float = param(2.0, lo=0.0, hi=1000.0, doc="hex lattice jitter radius")
    density_per_m2: float = param(400.0, lo=1.0, hi=1e4, doc="random placement density")
    area: Literal["rect", "disc"] = param("disc", doc="random placement region shape")
    length_mm: float = param(5000.0, lo=33.0, hi=1e6, doc="corridor length (along x)")
    width_mm: float = param(200.0, lo=33.0, hi=1e6, doc="corridor width (along y)")
    outer_radius_mm: float = param(700.0, lo=33.0, hi=1e6, doc="c_shape and ring outer radius")
    inner_radius_mm: float = param(
        450.0, lo=0.0, hi=1e6, doc="c_shape and ring inner radius (the hole's)"
    )
    opening_deg: float = param(
        90.0, lo=0.0, hi=359.0, doc="c_shape opening, degrees, centred on the +x axis"
    )


@dataclass(frozen=True)
class Params:
    """All parameters of one run.

    ``scenario`` holds the scenario's own section (a frozen dataclass) or ``None``.
    """

    seed: int = param(1, lo=0, doc="master seed of the run")
    duration_s: float = param(60.0, lo=0.0, doc="simulated time to run")
    medium: MediumParams = field(default_factory=MediumParams)
    ranging: RangingParams = field(default_factory=RangingParams)
    robot: RobotParams = field(default_factory=RobotParams)
    battery: BatteryParams = field(default_factory=BatteryParams)
    motion: MotionParams = field(default_factory=MotionParams)
    faults: FaultParams = field(default_factory=FaultParams)
    placement: PlacementParams = field(default_factory=PlacementParams)
    light: LightParams = field(default_factory=LightParams)
    trace: TraceParams = field(default_factory=TraceParams)
    scenario: Any = None

    def __post_init__(self) -> None:
        for section in (self, *self._sections().values()):
            _check_ranges(section, self._prefix_of(section))
        b = self.battery
        if not b.cutoff_v < b.degrade_v:
            raise ParamError(
                f"battery.cutoff_v ({b.cutoff_v}) must be below battery.degrade_v ({b.degrade_v})"
            )
        r = self.robot
        if not r.tx_jitter_s < r.tx_period_s:
            raise ParamError(
                f"robot.tx_jitter_s ({r.tx_jitter_s}) must be below robot.tx_period_s "
                f"({r.tx_period_s}): an offer would fall before the one it follows"
            )
        pl = self.placement
        if pl.kind in ("c_shape", "ring") and not pl.inner_radius_mm < pl.outer_radius_mm:
            raise ParamError(
                f"placement.inner_radius_mm ({pl.inner_radius_mm}) must be below "
                f"placement.outer_radius_mm ({pl.outer_radius_mm}) for placement.kind = "
                f"{pl.kind!r}"
            )
        model = self.ranging.model
        if model not in ("tables", "gaussian") and not _is_import_path(model):
            raise ParamError(
                f"ranging.model = {model!r} is neither tables, gaussian nor a "
                "package.module:Class import path"
            )
        if self.ranging.min_mm > self.ranging.max_mm:
            raise ParamError("ranging.min_mm must not exceed ranging.max_mm")
        m = self.motion
        if not m.stall_drive <= m.start_drive <= m.max_drive:
            raise ParamError(
                "motion.stall_drive <= motion.start_drive <= motion.max_drive must hold, got "
                f"{m.stall_drive}, {m.start_drive}, {m.max_drive}"
            )

    def _sections(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if _is_section(f.type)}
        if self.scenario is not None:
            out[_scenario_name(self.scenario)] = self.scenario
        return out

    def _prefix_of(self, section: Any) -> str:
        if section is self:
            return ""
        for name, value in self._sections().items():
            if value is section:
                return name + "."
        return ""

    def with_overrides(self, overrides: dict[str, Any]) -> Params:
        """Return a copy with dotted keys set; string values are parsed to the field's type.

        Raises
        ------
        ParamError
            For an unknown key, a value of the wrong type, or a value out of range.
        """
        top: dict[str, Any] = {}
        per_section: dict[str, dict[str, Any]] = {}
        sections = self._sections()
        for key, raw in overrides.items():
            head, _, rest = key.partition(".")
            if not rest:
                target, name, prefix = self, head, ""
            elif head in sections:
                target, name, prefix = sections[head], rest, head + "."
            else:
                raise ParamError(
                    f"unknown parameter {key!r}; sections are: {', '.join(sorted(sections))}"
                )
            known = {f.name: f for f in fields(target) if not _is_section(f.type)}
            known.pop("scenario", None)
            if name not in known:
                raise ParamError(
                    f"unknown parameter {key!r}; {prefix.rstrip('.') or 'the top level'} has: "
                    f"{', '.join(sorted(known))}"
                )
            value = _coerce(key, raw, _field_type(type(target), name))
            if target is self:
                top[name] = value
            else:
                per_section.setdefault(head, {})[name] = value
        changes = dict(top)
        for head, values in per_section.items():
            if head in {f.name for f in fields(self)}:
                changes[head] = replace(sections[head], **values)
            else:
                changes["scenario"] = replace(self.scenario, **values)
        return replace(self, **changes)

    def to_flat_dict(self) -> dict[str, Any]:
        """All parameters as ``{dotted key: value}``, for run records and summaries."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if not _is_section(f.type)}
        out.pop("scenario", None)
        for name, section in self._sections().items():
            for f in fields(section):
                out[f"{name}.{f.name}"] = getattr(section, f.name)
        return out

    @staticmethod
    def read_toml(path: str | Path) -> tuple[str | None, dict[str, Any]]:
        """Read a run file: an optional ``scenario = "name"`` and sections of parameters.

        Returns the scenario name and the parameters as dotted-key overrides.

        Raises
        ------
        ParamError
            If the file is missing, a directory, unreadable, not UTF-8 text or not valid TOML.
        """
        path = Path(path)
        try:
            data = tomllib.loads(read_text(path, ParamError, "run file"))
        except tomllib.TOMLDecodeError as exc:
            raise ParamError(f"{path}: not valid TOML ({exc})") from None
        scenario = data.pop("scenario", None)
        flat: dict[str, Any] = {}
        for key, value in data.items():
            if isinstance(value, dict):
                for sub, v in value.items():
                    flat[f"{key}.{sub}"] = v
            else:
                flat[key] = value
        return scenario, flat


def _is_import_path(text: str) -> bool:
    """Whether ``text`` has the form ``package.module:name``."""
    module, sep, name = text.partition(":")
    return bool(sep) and all(p.isidentifier() for p in module.split(".")) and name.isidentifier()


def load_object(path: str, key: str) -> Any:
    """The object an import path ``package.module:name`` names, for parameter ``key``.

    Raises
    ------
    ParamError
        If the module cannot be imported or has no such name (one line naming ``key``).

    Examples
    --------
    >>> load_object("math:pi", "x") > 3
    True
    >>> load_object("math:nope", "ranging.model")
    Traceback (most recent call last):
    ...
    kilonet.params.ParamError: ranging.model = 'math:nope': module math has no 'nope'
    """
    import importlib

    module_name, _, name = path.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ParamError(f"{key} = {path!r}: cannot import {module_name} ({exc})") from None
    try:
        return getattr(module, name)
    except AttributeError:
        raise ParamError(f"{key} = {path!r}: module {module_name} has no {name!r}") from None


def _scenario_name(section: Any) -> str:
    return getattr(section, "section_name", type(section).__name__.lower())


def _is_section(tp: Any) -> bool:
    return isinstance(tp, str) and tp.endswith("Params") and tp != "Params"


def _field_type(cls: type, name: str) -> Any:
    return typing.get_type_hints(cls)[name]


def _check_ranges(section: Any, prefix: str) -> None:
    for f in fields(section):
        lo, hi = f.metadata.get("lo"), f.metadata.get("hi")
        value = getattr(section, f.name)
        if isinstance(value, bool) or not isinstance(value, int | float):
            continue
        if isinstance(value, float) and not math.isfinite(value):
            raise ParamError(f"{prefix}{f.name} = {value} is not a finite number")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            # Only finite numbers are taken (above), so an open side is no bound of "inf".
            if lo is not None and hi is not None:
                allowed = f"out of range [{lo}, {hi}]"
            elif lo is not None:
                allowed = f"out of range: give a finite number >= {lo}"
            else:
                allowed = f"out of range: give a finite number <= {hi}"
            raise ParamError(f"{prefix}{f.name} = {value} is {allowed}")


def _optional(tp: Any) -> Any:
    """``X`` for a type ``X | None``, else ``None``."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in args:
        (inner,) = (a for a in args if a is not type(None))
        return inner
    return None


def _coerce(key: str, raw: Any, tp: Any) -> Any:
    """Parse ``raw`` (a string from the command line, or a TOML value) as type ``tp``;
    for ``X | None``, ``none`` is ``None``."""
    if (inner := _optional(tp)) is not None:
        if raw is None or str(raw).strip().lower() == "none":
            return None
        return _coerce(key, raw, inner)
    if typing.get_origin(tp) is Literal:
        choices = typing.get_args(tp)
        if raw not in choices:
            raise ParamError(f"{key} = {raw!r} is not one of: {', '.join(map(str, choices))}")
        return raw
    if tp is bool:
        if isinstance(raw, bool):
            return raw
        text = str(raw).strip().lower()
        if text in {"1", "true", "yes", "on"}:
            return True
        if text in {"0", "false", "no", "off"}:
            return False
        raise ParamError(f"{key} = {raw!r} is not a boolean (true/false)")
    if tp in (int, float):
        if isinstance(raw, bool):
            raise ParamError(f"{key} = {raw!r} is not a number")
        try:
            value = tp(raw) if tp is float or isinstance(raw, int) else int(str(raw), 0)
        except (TypeError, ValueError):
            raise ParamError(
                f"{key} = {raw!r} is not {'an integer' if tp is int else 'a number'}"
            ) from None
        return value
    if tp is str:
        return str(raw)
    raise ParamError(f"{key}: parameters of type {tp} cannot be set from text")


def describe(params: Params) -> list[tuple[str, Any, str, str]]:
    """``(dotted key, value, type and allowed values, description)`` for every parameter, for
    ``--help`` style listings.

    Examples
    --------
    >>> for row in describe(Params()):
    ...     if row[0] in ("seed", "medium.loss_prob", "robot.rx_mode"):
    ...         print(row[:3])
    ('seed', 1, 'int >= 0')
    ('medium.loss_prob', 0.0, 'float, 0 to 1')
    ('robot.rx_mode', 'callback', 'one of: callback, polled')
    """
    rows = []
    for key, value in params.to_flat_dict().items():
        head, _, name = key.rpartition(".")
        section = params._sections()[head] if head else params
        meta = {f.name: f.metadata for f in dataclasses.fields(section)}.get(name, {})
        kind = _allowed(_field_type(type(section), name), meta.get("lo"), meta.get("hi"))
        rows.append((key, value, kind, meta.get("doc", "")))
    return rows


def _allowed(tp: Any, lo: float | None, hi: float | None) -> str:
    """A field's type and allowed values in words: ``float, 0 to 1``, ``one of: a, b``."""
    if typing.get_origin(tp) is Literal:
        return "one of: " + ", ".join(map(str, typing.get_args(tp)))
    if (inner := _optional(tp)) is not None:
        return _allowed(inner, lo, hi).replace(inner.__name__, f"{inner.__name__} or none", 1)
    name = getattr(tp, "__name__", str(tp))
    if lo is not None and hi is not None:
        return f"{name}, {lo:g} to {hi:g}"
    if lo is not None:
        return f"{name} >= {lo:g}"
    if hi is not None:
        return f"{name} <= {hi:g}"
    return name
