"""Hostile and generated input to the command line: every outcome is a run (exit 0) or one line
on stderr with exit 2, never a traceback, a hang or a half-written output.

The regression tests pin the cases found by hand and by the fuzz campaign; the Hypothesis tests
draw placements, ``--set`` values and sweep files and run the real ``kilonet`` entry point
(:func:`kilonet.app.cli.main`) in-process on tiny swarms. ``test_cli_fuzz_campaign`` is the long
campaign (``-m slow``; ``KILONET_FUZZ_EXAMPLES`` cases, default 2000).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import os
import signal
import tempfile
import typing
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import kilonet.app.cli
from kilonet import scenarios
from kilonet.scenarios.base import build_params

SCENARIOS = ("gradient", "localize", "follower", "gcs", "maze")


def _kilonet(argv: list[str], capsys) -> tuple[int, str]:
    status = kilonet.app.cli.main(argv)
    return status, capsys.readouterr().err


def _one_line(err: str) -> str:
    assert err.startswith("kilonet: error: "), err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


# ---------------------------------------------------------------------------- regressions


@pytest.mark.parametrize(
    ("scenario", "setting", "allowed"),
    [
        *((s, "medium.message_format=thesis", "'kilolib'") for s in SCENARIOS if s != "maze"),
        # found by the fuzz test: raw measurements where the programs add millimetres
        *((s, "robot.rx_distance=raw", "'estimate'") for s in SCENARIOS if s != "gradient"),
    ],
)
def test_a_setting_a_scenarios_programs_are_not_written_for_is_refused_in_one_line(
    tmp_path, capsys, scenario, setting, allowed
):
    argv = ["run", scenario, "--duration", "2", "--set", setting]
    status, err = _kilonet([*argv, "--out", str(tmp_path / "out")], capsys)
    assert status == 2
    key, _, value = setting.partition("=")
    assert _one_line(err) == (
        f"kilonet: error: {key} = {value!r}: the {scenario} scenario's programs are written "
        f"for {allowed} only\n"
    )
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("scenario", "setting"),
    [
        ("maze", "medium.message_format=thesis"),
        ("gradient", "robot.rx_distance=raw"),
        ("localize", "robot.rx_mode=polled"),
        ("gcs", "robot.rx_mode=polled"),
        # programs with only message_rx receive in polled mode: the kernel drains the buffer
        # into message_rx after each loop (Kilobot.drain_messages)
        *((s, "robot.rx_mode=polled") for s in ("gradient", "follower", "maze")),
    ],
)
def test_settings_a_scenario_supports_run(capsys, scenario, setting):
    argv = ["run", scenario, "--duration", "3", "--json", "--set", setting]
    if scenario not in ("maze", "follower"):
        argv += ["--robots", "8"]
    status, err = _kilonet(argv, capsys)
    assert status == 0, err


def test_a_sweep_over_the_message_format_is_refused_naming_the_cell(tmp_path, capsys):
    sweep = tmp_path / "formats.toml"
    sweep.write_text(
        'scenario = "gradient"\n[fixed]\nduration_s = 2.0\n'
        '[grid]\n"medium.message_format" = ["kilolib", "thesis"]\n'
    )
    status, err = _kilonet(["sweep", str(sweep), "--out", str(tmp_path / "out")], capsys)
    assert status == 2
    assert _one_line(err).startswith(
        f"kilonet: error: {sweep}: [grid] medium.message_format = 'thesis': the gradient "
        "scenario's programs are written for 'kilolib' only"
    )
    assert not (tmp_path / "out").exists()


def test_localize_with_every_robot_crashed_writes_its_figure(tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["run", "localize", "--robots", "12", "--duration", "3", "--out", str(out)]
    status, err = _kilonet([*argv, "--set", "faults.crash_fraction=1"], capsys)
    assert status == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["localized_fraction"] == 0 and summary["rmse_mm"] is None
    assert (out / "localize.png").stat().st_size > 0


@pytest.mark.parametrize("y", ["1e-30", "0", "-1e-300"])
def test_the_gradient_figure_of_a_swarm_without_height(tmp_path, capsys, y):
    placement = tmp_path / "line.csv"
    placement.write_text(f"x_mm,y_mm\n0,0\n40,{y}\n80,0\n")
    out = tmp_path / "out"
    argv = ["run", "gradient", "--placement", str(placement), "--duration", "1"]
    status, err = _kilonet([*argv, "--out", str(out)], capsys)
    assert status == 0, err
    assert (out / "gradient.png").stat().st_size > 0


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("seeds = 1000000000000", "seeds = 1000000000000: at most 100000 seeds"),
        ("seeds = {first = 0, count = 10000000000}", "at most 100000 seeds"),
        ('[grid]\n"medium.loss_prob" = {start = 0.0, stop = 1.0, step = 1e-300}',
         "[grid] medium.loss_prob: step 1e-300 from 0.0 to 1.0 gives more than 100000 values"),
        ('[grid]\n"medium.loss_prob" = {start = 0.0, stop = 1.0, num = 100000000}',
         "range num = 100000000: at most 100000 values"),
        ('[grid]\n"medium.loss_prob" = {start = 0.0, stop = 1.0, num = 1000}\n'
         '"medium.range_mm" = {start = 40.0, stop = 100.0, num = 1000}',
         "1000000 runs (cells x seeds); a sweep has at most 100000"),
    ],
)  # fmt: skip
def test_a_sweep_of_billions_of_runs_is_refused_before_it_is_built(tmp_path, capsys, line, message):
    # found by the fuzz test: a tiny step made parse_sweep build values until memory ran out
    sweep = tmp_path / "huge.toml"
    sweep.write_text(f'scenario = "gradient"\n{line}\n')
    status, err = _kilonet(["sweep", str(sweep), "--out", str(tmp_path / "out")], capsys)
    assert status == 2
    assert message in _one_line(err)
    assert not (tmp_path / "out").exists()


def test_a_uid_that_only_python_calls_a_digit_is_one_line(tmp_path, capsys):
    placement = tmp_path / "uids.csv"
    placement.write_text("x_mm,y_mm,uid\n0,0,1\n40,0,²\n", encoding="utf-8")
    status, err = _kilonet(["run", "gradient", "--placement", str(placement)], capsys)
    assert status == 2
    assert _one_line(err) == (
        f"kilonet: error: {placement} line 3: uid is not an integer 0-65535 ('²')\n"
    )


# ---------------------------------------------------------------------------- the fuzz test
#
# Each case is (argv, files): the argument list of `kilonet` with {dir} standing for a fresh
# directory, and the files to write there first. The only allowed outcomes: exit 0, or exit 2
# with exactly one line on stderr ("kilonet: error: ...") and no --out directory left behind;
# each within LIMIT_S seconds (a guard against hangs, far above the second a tiny run takes).

LIMIT_S = 120.0
#: Keys that set how much work a run is (its size and length): the fuzz keeps runs tiny.
_SIZE_KEYS = {"duration_s", "placement.robots", "placement.density_per_m2"}


class _Hang(BaseException):
    """Raised by the alarm when a case runs past LIMIT_S (not an Exception: nothing in the
    command line may catch it)."""


def _fields(scenario: str) -> list[tuple[str, typing.Any, float | None, float | None]]:
    """(dotted key, type, lo, hi) of every parameter of ``scenario``."""
    params = build_params(scenarios.get(scenario))
    out = []
    for head, section in {"": params, **params._sections()}.items():
        hints = typing.get_type_hints(type(section))
        for f in dataclasses.fields(section):
            if dataclasses.is_dataclass(getattr(section, f.name)) or f.name == "scenario":
                continue
            key = f"{head}.{f.name}" if head else f.name
            if key not in _SIZE_KEYS:
                out.append((key, hints[f.name], f.metadata.get("lo"), f.metadata.get("hi")))
    return out


_FIELDS = {name: _fields(name) for name in SCENARIOS}

_ODD_TEXT = st.sampled_from(
    ["", " ", "nan", "inf", "-inf", "NaN", "1e400", "-0", "1e-30", "-1e-300", "0x10", "1_000",
     "٣", "²", "１", "1e", "--1", "+5", " 40 ", "4e1", "true", "True", "yes", "none", "None",
     "[1]", "{}", "'", '"', "\\", "\x00", "é", "🤖", "1,5", "1;2", "=", "a=b"]
)  # fmt: skip


def _number_text(lo: float | None, hi: float | None) -> st.SearchStrategy[str]:
    """Numbers near and beyond the bounds, as the command line would read them."""
    edges = [v for v in (lo, hi) if v is not None]
    near = [e + d for e in edges for d in (0.0, -1e-9, 1e-9, -1.0, 1.0)]
    inside = (
        st.floats(lo, hi, allow_nan=False) if lo is not None and hi is not None else st.floats()
    )
    return st.one_of(
        st.sampled_from(near or [0.0]).map(repr),
        inside.map(repr),
        st.integers(-(10**12), 10**12).map(str),
        _ODD_TEXT,
    )


def _value_text(tp: typing.Any, lo: float | None, hi: float | None) -> st.SearchStrategy[str]:
    if typing.get_origin(tp) is typing.Literal:
        return st.one_of(st.sampled_from([str(a) for a in typing.get_args(tp)]), _ODD_TEXT)
    if tp is bool:
        return st.one_of(st.sampled_from(["true", "false", "1", "0", "on", "off"]), _ODD_TEXT)
    return _number_text(lo, hi)


@st.composite
def set_cases(draw) -> tuple[list[str], dict[str, bytes]]:
    """`kilonet run SCENARIO --robots N --duration D --set KEY=VALUE ...`."""
    scenario = draw(st.sampled_from(SCENARIOS))
    fields = _FIELDS[scenario]
    argv = ["run", scenario, "--robots", str(draw(st.integers(2, 8)))]
    argv += ["--duration", repr(draw(st.floats(0.0, 2.0))), "--seed", str(draw(st.integers(0, 9)))]
    for _ in range(draw(st.integers(1, 3))):
        key, tp, lo, hi = draw(st.sampled_from(fields))
        if draw(st.integers(0, 9)) == 0:  # now and then a key that does not exist
            key = draw(st.sampled_from([key + "x", key.upper(), "medium", "medium.", ".seed"]))
        argv += ["--set", f"{key}={draw(_value_text(tp, lo, hi))}"]
    if draw(st.booleans()):
        argv += ["--out", "{dir}/out"]
    return argv, {}


_COORD = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**7), 10**7).map(str),
    _ODD_TEXT,
)
_HEADERS = st.sampled_from(
    ["x_mm,y_mm", "y_mm,x_mm", "x_mm,y_mm,uid", "uid,x_mm,y_mm", "\ufeffx_mm,y_mm",
     " x_mm , y_mm ,note", "x,y", "x_mm", "x_mm,x_mm,y_mm", "x_mm,y_mm,uid,uid", ""]
)  # fmt: skip


@st.composite
def placement_cases(draw) -> tuple[list[str], dict[str, bytes]]:
    """`kilonet run SCENARIO --placement F.csv`: a lattice 40 mm apart with hostile cells."""
    header = draw(st.one_of(st.just("x_mm,y_mm"), st.just("x_mm,y_mm,uid"), _HEADERS))
    names = [c.strip().lstrip("\ufeff") for c in header.split(",")]
    lines = [header]
    for i in range(draw(st.integers(0, 2) | st.integers(3, 7) | st.integers(3, 7))):
        cells = []
        for name in names:
            true = {"x_mm": str(40 * i), "y_mm": str(draw(st.sampled_from([0, 40]))), "uid": str(i)}
            good = true.get(name, "n")
            cells.append(good if draw(st.integers(0, 24)) else draw(_COORD))
        if draw(st.integers(0, 9)) == 0:
            cells.append(draw(_COORD))  # a field more than the header names
        lines.append(",".join(cells))
        if draw(st.integers(0, 9)) == 0:
            lines.append(draw(st.sampled_from(["", "  ", ",,", '"', "#", "\r"])))
    text = "\n".join(lines) + draw(st.sampled_from(["\n", "", "\r\n"]))
    data = text.encode()
    if draw(st.integers(0, 14)) == 0:
        data = data.replace(b"0", b"\xff", 1)  # not UTF-8
    scenario = draw(st.sampled_from(["gradient", "gradient", *SCENARIOS]))
    argv = ["run", scenario, "--placement", "{dir}/p.csv", "--duration", "1"]
    if draw(st.booleans()):
        argv += ["--out", "{dir}/out"]
    return argv, {"p.csv": data}


def _toml_value(value: typing.Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return (
            "nan"
            if math.isnan(value)
            else {math.inf: "inf", -math.inf: "-inf"}.get(value, repr(value))
        )
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(v)}" for k, v in value.items()) + "}"


_TOML_SCALAR = st.one_of(
    st.booleans(),
    st.integers(-(10**20), 10**20),
    st.floats(),
    st.text(max_size=6),
)


def _toml_typed(tp: typing.Any, lo: float | None, hi: float | None) -> st.SearchStrategy:
    """A TOML value for a parameter: mostly of its type, near its bounds; sometimes anything."""
    if typing.get_origin(tp) is typing.Literal:
        typed: st.SearchStrategy = st.sampled_from(typing.get_args(tp))
    elif tp is bool:
        typed = st.booleans()
    elif tp is int:
        typed = st.integers(int(lo or 0) - 2, int(min(hi or 100, 10**6)) + 2)
    else:
        edges = [v for v in (lo, hi) if v is not None] or [0.0]
        typed = st.one_of(st.sampled_from(edges), st.floats(lo, hi, allow_nan=False))
    return st.one_of(typed, typed, typed, _TOML_SCALAR, st.lists(_TOML_SCALAR, max_size=2))


@st.composite
def run_file_cases(draw) -> tuple[list[str], dict[str, bytes]]:
    """`kilonet run FILE.toml --duration D --robots N`: a run file with hostile tables."""
    scenario = draw(st.sampled_from(SCENARIOS))
    tables: dict[str, dict[str, typing.Any]] = {}
    top: dict[str, typing.Any] = {}
    if draw(st.integers(0, 5)):
        top["scenario"] = scenario
    elif draw(st.booleans()):
        top["scenario"] = draw(_TOML_SCALAR)
    for key, tp, lo, hi in draw(st.lists(st.sampled_from(_FIELDS[scenario]), max_size=4)):
        head, _, name = key.rpartition(".")
        value = draw(_toml_typed(tp, lo, hi))
        (tables.setdefault(head, {}) if head else top)[name] = value
    lines = [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in top.items()]
    for head, values in tables.items():
        lines.append(f"[{head}]")
        lines += [f"{name} = {_toml_value(v)}" for name, v in values.items()]
    text = "\n".join(lines) + "\n"
    if draw(st.integers(0, 9)) == 0:
        text = text[: draw(st.integers(0, len(text)))]  # cut anywhere
    argv = ["run", "{dir}/run.toml", "--duration", "1", "--robots", str(draw(st.integers(2, 6)))]
    return argv, {"run.toml": text.encode()}


@st.composite
def sweep_file_cases(draw) -> tuple[list[str], dict[str, bytes]]:
    """`kilonet sweep FILE.toml --out DIR`: tiny sweeps (at most 2 x 2 cells, 2 seeds)."""
    scenario = draw(st.sampled_from(SCENARIOS))
    lines = [f"scenario = {json.dumps(scenario)}"]
    seeds = draw(
        st.one_of(
            st.integers(1, 2),
            st.integers(1, 2),
            st.integers(-1, 2),
            st.lists(st.integers(-1, 3), max_size=3),
            st.fixed_dictionaries({"first": st.integers(-1, 3), "count": st.integers(-1, 2)}),
            _TOML_SCALAR,
        )
    )
    lines.append(f"seeds = {_toml_value(seeds)}")
    fixed = {"duration_s": 1.0, "placement.robots": draw(st.integers(2, 6))}
    grid: dict[str, typing.Any] = {}
    for key, tp, lo, hi in draw(st.lists(st.sampled_from(_FIELDS[scenario]), max_size=3)):
        if draw(st.booleans()):
            fixed[key] = draw(_toml_typed(tp, lo, hi))
        elif draw(st.integers(0, 3)):
            grid[key] = draw(
                st.lists(
                    _toml_typed(tp, lo, hi), min_size=draw(st.sampled_from([0, 1, 1])), max_size=2
                )
            )
        else:
            grid[key] = draw(
                st.fixed_dictionaries(
                    {"start": _toml_typed(tp, lo, hi), "stop": _toml_typed(tp, lo, hi)},
                    optional={"num": st.integers(-1, 2), "step": _TOML_SCALAR, "log": _TOML_SCALAR},
                )
            )
    lines.append("[fixed]")
    lines += [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in fixed.items()]
    lines.append("[grid]")
    lines += [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in grid.items()]
    if draw(st.integers(0, 3)) == 0:
        lines += ["[report]", f"x = {_toml_value(draw(st.sampled_from([*grid, 'nope'])))}"]
        lines.append(f"xscale = {_toml_value(draw(st.sampled_from(['linear', 'log', 'x'])))}")
    argv = ["sweep", "{dir}/s.toml", "--out", "{dir}/out", "--workers", "1", "--no-progress"]
    return argv, {"s.toml": ("\n".join(lines) + "\n").encode()}


def _too_many_runs(files: dict[str, bytes]) -> bool:
    """Whether a sweep file would run more than 8 runs (step ranges can make many)."""
    from kilonet.experiments.sweep import SweepError, parse_sweep

    try:
        return len(parse_sweep(files["s.toml"].decode(), name="s").runs()) > 8
    except (SweepError, UnicodeDecodeError):
        return False


CASES = st.one_of(set_cases(), placement_cases(), run_file_cases(), sweep_file_cases())


@contextlib.contextmanager
def _time_limit(what: str) -> typing.Iterator[None]:
    """Raise :class:`_Hang` in the main thread if the block runs longer than LIMIT_S."""

    def alarm(signum: int, frame: typing.Any) -> None:
        raise _Hang(f"{what} ran longer than {LIMIT_S} s")

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, LIMIT_S)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def check_case(case: tuple[list[str], dict[str, bytes]]) -> None:
    """Run one case through the real entry point and assert its outcome is allowed."""
    argv, files = case
    with _time_limit(f"kilonet {' '.join(argv)}"):
        if "s.toml" in files and _too_many_runs(files):
            return
    with tempfile.TemporaryDirectory() as tmp:
        for name, data in files.items():
            (Path(tmp) / name).write_bytes(data)
        argv = [a.replace("{dir}", tmp) for a in argv]
        err, out = io.StringIO(), io.StringIO()
        with (
            _time_limit(f"kilonet {' '.join(argv)}"),
            contextlib.redirect_stderr(err),
            contextlib.redirect_stdout(out),
        ):
            try:
                status = kilonet.app.cli.main(argv)
            except SystemExit as exc:  # argparse
                status = exc.code
        text = err.getvalue()
        assert "Traceback" not in text, text
        if status == 0:
            return
        assert status == 2, f"exit {status}: {text}"
        # what a terminal shows: each line as its last carriage return left it (the progress
        # display redraws itself with \r), blank lines dropped
        lines = [ln.rpartition("\r")[2].strip() for ln in text.split("\n")]
        lines = [ln for ln in lines if ln]
        assert len(lines) == 1 and lines[0].startswith("kilonet: error: "), text
        assert not (Path(tmp) / "out").exists(), f"{argv}: exit 2 left {tmp}/out behind"


#: Hypothesis settings of both fuzz tests: the time limit is LIMIT_S, not a deadline.
_FUZZ = {
    "deadline": None,
    "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large],
}


@pytest.mark.twin_of("test_cli_fuzz_campaign")
@settings(max_examples=40, **_FUZZ)
@given(CASES)
def test_cli_fuzz(case):
    check_case(case)


@pytest.mark.slow
@settings(max_examples=int(os.environ.get("KILONET_FUZZ_EXAMPLES", "2000")), **_FUZZ)
@given(CASES)
def test_cli_fuzz_campaign(case):
    check_case(case)
