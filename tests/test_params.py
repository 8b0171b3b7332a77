"""Tests for kilonet.params: typed, validated parameters addressed by dotted keys."""

from __future__ import annotations

import re

import pytest

from kilonet.params import MediumParams, ParamError, Params, describe


def test_defaults_match_the_kilobot_model():
    p = Params()
    assert p.medium.reach == "argos"  # per-robot reach fitted to real robots (tests/validation)
    assert p.medium.range_mm == 85.0  # the disc's radius: the thesis's "at least 7 cm"
    assert p.medium.occlusion == "none"  # real-robot data show no effect of a body between
    assert p.medium.csma is True
    assert p.medium.message_format == "kilolib"
    assert p.medium.backoff_max_s == 255 / 7812.5  # kilolib: rand() & 0xFF timer counts
    assert p.medium.bitrate_bps == 29_740.0  # 8 MHz / 269 cycles a bit
    assert p.robot.tx_period_s == 16 * 256 / 7812.5  # kilolib: 16 ticks (kilo_tx_period 3906)
    assert p.robot.tx_jitter_s == 0.0
    assert p.robot.tx_retry == "tick"
    assert p.robot.rx_mode == "callback"
    assert p.robot.rx_buffer == 3
    assert p.robot.ticks_per_s == 8e6 / 1024 / 256  # the hardware tick; TICKS_PER_SEC says 31
    assert p.robot.clock_sd == 0.01  # the ATmega328P's calibrated RC oscillator: about ±1 %
    assert p.robot.loop_ticks == 1
    assert (p.motion.pivot_radius_mm, p.motion.pivot_angle_deg) == (16.5, 125.5)  # Kilombo
    assert (p.motion.motor_offset, p.motion.motor_gain) == (60.0, 15.0)  # Kilombo's curve
    assert p.ranging.model == "tables"  # kilolib's estimate on per-robot calibration tables
    assert p.ranging.sigma_mm == 1.0
    assert p.ranging.bias_sigma_mm == 0.0


def test_a_reception_model_that_is_no_import_path_is_refused_naming_the_key():
    with pytest.raises(ParamError, match=re.escape("ranging.model = 'fancy'")):
        Params().with_overrides({"ranging.model": "fancy"})
    with pytest.raises(ParamError, match="cannot import no_such_module"):
        from kilonet import Kilobot, Simulation

        Simulation(
            [[0, 0]], Kilobot, Params().with_overrides({"ranging.model": "no_such_module:X"})
        )


def test_overrides_parse_strings_to_field_types():
    p = Params().with_overrides(
        {
            "seed": "42",
            "duration_s": "12.5",
            "medium.loss_prob": "0.25",
            "medium.occlusion": "block",
            "medium.csma": "on",
            "robot.rx_mode": "polled",
            "robot.rx_buffer": "0x10",
            "ranging.max_mm": 200,
        }
    )
    assert p.seed == 42 and isinstance(p.seed, int)
    assert p.duration_s == 12.5
    assert p.medium.loss_prob == 0.25
    assert p.medium.occlusion == "block"
    assert p.medium.csma is True
    assert p.robot.rx_mode == "polled"
    assert p.robot.rx_buffer == 16
    assert p.ranging.max_mm == 200


def test_overrides_return_a_copy():
    base = Params()
    changed = base.with_overrides({"medium.range_mm": 70})
    assert base.medium.range_mm == 85.0
    assert changed.medium.range_mm == 70.0
    assert changed.robot == base.robot


@pytest.mark.parametrize(
    "key",
    ["medium.los", "mediums.range_mm", "range_mm", "robot.scenario", "medium.range_mm.x"],
)
def test_unknown_key_is_an_error_naming_the_key(key):
    with pytest.raises(ParamError, match=re.escape(f"unknown parameter {key!r}")):
        Params().with_overrides({key: "1"})


def test_unknown_key_lists_what_the_section_has():
    with pytest.raises(ParamError, match="medium has: airtime_s, backoff_max_s, bitrate_bps"):
        Params().with_overrides({"medium.los": "1"})


@pytest.mark.parametrize(
    ("key", "value", "why"),
    [
        ("medium.loss_prob", "abc", "is not a number"),
        ("medium.loss_prob", True, "is not a number"),
        ("robot.rx_buffer", "2.5", "is not an integer"),
        ("robot.rx_buffer", 2.5, "is not an integer"),
        ("medium.csma", "maybe", "is not a boolean"),
        ("robot.rx_mode", "push", "is not one of: callback, polled"),
        ("medium.message_format", "kilolib3", "is not one of: kilolib, thesis"),
    ],
)
def test_bad_type_is_an_error_naming_the_key(key, value, why):
    with pytest.raises(ParamError, match=re.escape(key) + ".*" + re.escape(why)):
        Params().with_overrides({key: value})


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("medium.loss_prob", "1.5"),
        ("medium.loss_prob", "-0.1"),
        ("medium.range_mm", "10"),
        ("ranging.max_mm", "256"),
        ("robot.rx_buffer", "0"),
        ("seed", "-1"),
        ("motion.speed_error", "0.95"),
    ],
)
def test_out_of_range_is_an_error_naming_the_key(key, value):
    with pytest.raises(ParamError, match=re.escape(key) + r" = \S+ is out of range"):
        Params().with_overrides({key: value})


def test_non_finite_is_an_error_naming_the_key():
    with pytest.raises(ParamError, match=r"medium\.range_mm = nan is not a finite number"):
        Params().with_overrides({"medium.range_mm": "nan"})


def test_cross_field_checks():
    with pytest.raises(ParamError, match=r"battery\.cutoff_v .* below battery\.degrade_v"):
        Params().with_overrides({"battery.cutoff_v": 3.7})
    with pytest.raises(ParamError, match=r"ranging\.min_mm must not exceed ranging\.max_mm"):
        Params().with_overrides({"ranging.min_mm": 100, "ranging.max_mm": 50})


def test_direct_construction_is_validated_too():
    with pytest.raises(
        ParamError, match=r"medium\.loss_prob = 2\.0 is out of range \[0\.0, 1\.0\]"
    ):
        Params(medium=MediumParams(loss_prob=2.0))


def test_read_toml(tmp_path):
    path = tmp_path / "run.toml"
    path.write_text(
        'scenario = "gradient"\n'
        "seed = 7\n"
        "duration_s = 30\n"
        "[medium]\n"
        "loss_prob = 0.3\n"
        'occlusion = "graded"\n'
        "[robot]\n"
        'rx_mode = "polled"\n'
        "rx_buffer = 5\n"
    )
    scenario, flat = Params.read_toml(path)
    assert scenario == "gradient"
    assert flat == {
        "seed": 7,
        "duration_s": 30,
        "medium.loss_prob": 0.3,
        "medium.occlusion": "graded",
        "robot.rx_mode": "polled",
        "robot.rx_buffer": 5,
    }
    p = Params().with_overrides(flat)
    assert (p.seed, p.duration_s, p.medium.loss_prob) == (7, 30.0, 0.3)
    assert isinstance(p.duration_s, float)
    assert (p.medium.occlusion, p.robot.rx_mode, p.robot.rx_buffer) == ("graded", "polled", 5)


def test_read_toml_without_scenario(tmp_path):
    path = tmp_path / "run.toml"
    path.write_text("[ranging]\nsigma_mm = 2\n")
    assert Params.read_toml(path) == (None, {"ranging.sigma_mm": 2})


def test_read_toml_errors_name_the_file(tmp_path):
    missing = tmp_path / "nope.toml"
    with pytest.raises(ParamError, match=re.escape(f"{missing}: no such run file")):
        Params.read_toml(missing)
    broken = tmp_path / "broken.toml"
    broken.write_text("[medium\nloss_prob = 0.3\n")
    with pytest.raises(ParamError, match=re.escape(f"{broken}: not valid TOML")):
        Params.read_toml(broken)
    with pytest.raises(ParamError, match=re.escape(f"{tmp_path}: is a directory, not a run")):
        Params.read_toml(tmp_path)
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\x00\xff\xfe")
    with pytest.raises(ParamError, match=re.escape(f"{binary}: not a UTF-8 text file")):
        Params.read_toml(binary)


def test_optional_fields_take_none_or_a_value_in_range():
    from kilonet.protocols.maze.program import MazeParams

    p = Params(scenario=MazeParams())
    assert p.scenario.filter_p_open is None
    assert p.with_overrides({"maze.filter_p_open": "0.5"}).scenario.filter_p_open == 0.5
    assert p.with_overrides({"maze.filter_p_open": 0.5}).scenario.filter_p_open == 0.5
    set_then_reset = p.with_overrides({"maze.filter_p_open": 0.5})
    assert set_then_reset.with_overrides({"maze.filter_p_open": "none"}) == p
    with pytest.raises(ParamError, match=r"maze\.filter_p_open = 2\.0 is out of range"):
        p.with_overrides({"maze.filter_p_open": "2"})
    with pytest.raises(ParamError, match=r"maze\.filter_p_open = 'high' is not a number"):
        p.with_overrides({"maze.filter_p_open": "high"})
    kinds = {key: kind for key, _, kind, _ in describe(p)}
    assert kinds["maze.filter_p_open"] == "float or none, 0 to 1"


def test_toml_values_are_type_checked_by_key(tmp_path):
    path = tmp_path / "run.toml"
    path.write_text("[robot]\nrx_buffer = 2.5\n")
    _, flat = Params.read_toml(path)
    with pytest.raises(ParamError, match=r"robot\.rx_buffer = 2\.5 is not an integer"):
        Params().with_overrides(flat)


def test_flat_dict_and_describe_cover_every_key():
    flat = Params().to_flat_dict()
    assert flat["medium.range_mm"] == 85.0
    assert flat["seed"] == 1
    assert "scenario" not in flat
    rows = describe(Params())
    assert [key for key, _, _, _ in rows] == list(flat)
    docs = {key: doc for key, _, _, doc in rows}
    assert docs["medium.range_mm"] == "disc: reception range, centre to centre"
    kinds = {key: kind for key, _, kind, _ in rows}
    assert kinds["medium.range_mm"] == "float, 33 to 1000"
    assert kinds["medium.csma"] == "bool"
    assert kinds["medium.message_format"] == "one of: kilolib, thesis"
    assert kinds["duration_s"] == "float >= 0"
    # Every key given back as an override reproduces the same parameters.
    assert Params().with_overrides(flat) == Params()
