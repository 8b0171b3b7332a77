"""Tests for kilonet.placement: generators, validation and CSV input/output."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree
from scipy.spatial.distance import pdist

from kilonet.placement import (
    MAX_COORDINATE_MM,
    ROBOT_DIAMETER_MM,
    PlacementError,
    load_csv,
    read_placement,
    save_csv,
    validate_positions,
)
from kilonet.scenarios.placement import generate, hex_lattice, line, random_uniform

# ------------------------------------------------------------------------------------- line


def test_line_exact_values():
    np.testing.assert_array_equal(line(3), [[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    np.testing.assert_array_equal(line(2, spacing_mm=33.0), [[0.0, 0.0], [33.0, 0.0]])
    assert line(0).shape == (0, 2)
    assert line(4).dtype == np.float64


def test_line_refuses_overlap_and_negative_n():
    with pytest.raises(ValueError, match="spacing_mm=20"):
        line(3, spacing_mm=20.0)
    with pytest.raises(ValueError, match="n=-1"):
        line(-1)


# -------------------------------------------------------------------------------- hex lattice


def test_hex_lattice_first_ring_exact():
    s = math.sqrt(3) / 2 * 40.0
    expected = [[0, 0], [-20, -s], [20, -s], [40, 0], [20, s], [-20, s], [-40, 0]]
    np.testing.assert_allclose(hex_lattice(7), expected, atol=1e-12)


@pytest.mark.parametrize("n", [2, 3, 7, 19, 50, 300])
@pytest.mark.parametrize("spacing_mm", [33.0, 40.0, 57.5])
def test_hex_lattice_nearest_neighbour_is_spacing(n, spacing_mm):
    xy = hex_lattice(n, spacing_mm=spacing_mm)
    assert xy.shape == (n, 2)
    dist, _ = cKDTree(xy).query(xy, k=2)
    np.testing.assert_allclose(dist[:, 1], spacing_mm, rtol=1e-12)
    assert len(np.unique(xy.round(6), axis=0)) == n


@pytest.mark.parametrize(("n", "rings"), [(1, 0), (7, 1), (19, 2), (37, 3)])
def test_hex_lattice_is_compact(n, rings):
    """Full hexagons: 1 + 3k(k+1) robots lie within k spacings of the origin."""
    radius = np.hypot(*hex_lattice(n).T)
    assert radius.max() == pytest.approx(rings * 40.0)


def test_hex_lattice_is_deterministic_without_jitter():
    np.testing.assert_array_equal(hex_lattice(40), hex_lattice(40))


@given(
    n=st.integers(2, 80),
    spacing_mm=st.floats(33.0, 80.0),
    jitter_fraction=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**32 - 1),
)
@settings(max_examples=60, deadline=None)
def test_hex_lattice_jitter_never_overlaps(n, spacing_mm, jitter_fraction, seed):
    jitter_mm = (spacing_mm - ROBOT_DIAMETER_MM) / 2 * jitter_fraction
    xy = hex_lattice(n, spacing_mm=spacing_mm, jitter_mm=jitter_mm, rng=np.random.default_rng(seed))
    assert xy.shape == (n, 2)
    assert pdist(xy).min() >= ROBOT_DIAMETER_MM - 1e-9
    offset = np.hypot(*(xy - hex_lattice(n, spacing_mm=spacing_mm)).T)
    assert offset.max() <= jitter_mm + 1e-9


def test_hex_lattice_jitter_is_reproducible():
    a = hex_lattice(30, spacing_mm=50.0, jitter_mm=8.0, rng=np.random.default_rng(3))
    b = hex_lattice(30, spacing_mm=50.0, jitter_mm=8.0, rng=np.random.default_rng(3))
    c = hex_lattice(30, spacing_mm=50.0, jitter_mm=8.0, rng=np.random.default_rng(4))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_hex_lattice_refuses_jitter_that_could_overlap():
    with pytest.raises(ValueError, match=r"spacing_mm=40\.0.*jitter_mm=4\.0.*32 mm.*33 mm"):
        hex_lattice(5, spacing_mm=40.0, jitter_mm=4.0, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="spacing_mm=30"):
        hex_lattice(5, spacing_mm=30.0)


def test_hex_lattice_jitter_needs_a_generator():
    with pytest.raises(ValueError, match="needs rng"):
        hex_lattice(5, jitter_mm=1.0)
    with pytest.raises(TypeError, match="Generator"):
        hex_lattice(5, jitter_mm=1.0, rng=np.random.RandomState(0))


# ----------------------------------------------------------------------------- random uniform


@given(
    n=st.integers(2, 40),
    width_mm=st.floats(300.0, 900.0),
    height_mm=st.floats(300.0, 900.0),
    seed=st.integers(0, 2**32 - 1),
)
@settings(max_examples=40, deadline=None)
def test_random_uniform_rect_inside_and_apart(n, width_mm, height_mm, seed):
    xy = random_uniform(n, width_mm=width_mm, height_mm=height_mm, rng=np.random.default_rng(seed))
    assert xy.shape == (n, 2)
    assert np.all(np.abs(xy[:, 0]) <= width_mm / 2)
    assert np.all(np.abs(xy[:, 1]) <= height_mm / 2)
    assert pdist(xy).min() >= ROBOT_DIAMETER_MM


def test_random_uniform_disc_inside_and_apart():
    xy = random_uniform(60, area="disc", radius_mm=400.0, rng=np.random.default_rng(1))
    assert xy.shape == (60, 2)
    assert np.hypot(*xy.T).max() <= 400.0 + 1e-9
    assert pdist(xy).min() >= ROBOT_DIAMETER_MM


@pytest.mark.parametrize("area", ["rect", "disc"])
def test_random_uniform_region_from_density(area):
    n, density_per_m2 = 100, 200.0
    xy = random_uniform(n, density_per_m2=density_per_m2, area=area, rng=np.random.default_rng(2))
    area_mm2 = n / density_per_m2 * 1e6
    if area == "rect":
        assert np.abs(xy).max() <= math.sqrt(area_mm2) / 2
    else:
        assert np.hypot(*xy.T).max() <= math.sqrt(area_mm2 / math.pi) + 1e-9
    assert pdist(xy).min() >= ROBOT_DIAMETER_MM
    # A uniform placement fills its region: not all robots bunched near the centre.
    assert np.hypot(*xy.T).max() > 0.6 * math.sqrt(area_mm2 / math.pi)


@pytest.mark.parametrize("area", ["rect", "disc"])
def test_random_uniform_is_uniform_at_low_density(area):
    """Half the region's area holds about half the robots (binomial sd 0.018 for n = 800)."""
    size = {"width_mm": 8000.0, "height_mm": 8000.0} if area == "rect" else {"radius_mm": 4000.0}
    xy = random_uniform(800, area=area, rng=np.random.default_rng(11), **size)
    if area == "rect":
        inner = np.abs(xy).max(axis=1) <= 4000.0 / math.sqrt(2)
    else:
        inner = np.hypot(*xy.T) <= 4000.0 / math.sqrt(2)
    assert inner.mean() == pytest.approx(0.5, abs=0.07)
    assert np.abs(xy.mean(axis=0)).max() < 300.0


def test_random_uniform_is_reproducible():
    kwargs = {"density_per_m2": 300.0, "area": "disc"}
    a = random_uniform(80, rng=np.random.default_rng(7), **kwargs)
    b = random_uniform(80, rng=np.random.default_rng(7), **kwargs)
    c = random_uniform(80, rng=np.random.default_rng(8), **kwargs)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_random_uniform_density_too_high():
    # 100 bodies of 33 mm would cover the whole 1 m² / 1000 = 0.1 m² square about 0.86 times.
    with pytest.raises(ValueError, match=r"density too high.*100 robots.*1000\.0 per m²"):
        random_uniform(100, density_per_m2=1000.0, rng=np.random.default_rng(0), max_tries=20_000)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({}, "needs density_per_m2 or width_mm and height_mm"),
        ({"width_mm": 500.0}, "needs density_per_m2 or width_mm and height_mm"),
        ({"density_per_m2": 10.0, "width_mm": 500.0}, "either density_per_m2 or width_mm"),
        ({"radius_mm": 500.0}, "radius_mm does not apply"),
        ({"area": "hexagon", "density_per_m2": 10.0}, "area must be"),
        ({"density_per_m2": -1.0}, "density_per_m2=-1.0"),
        ({"width_mm": math.nan, "height_mm": 5.0}, "width_mm=nan"),
    ],
)
def test_random_uniform_bad_region(kwargs, message):
    with pytest.raises(ValueError, match=message):
        random_uniform(5, rng=np.random.default_rng(0), **kwargs)


def test_random_uniform_needs_a_generator():
    with pytest.raises(ValueError, match="needs rng"):
        random_uniform(5, density_per_m2=10.0, rng=None)


# ------------------------------------------------------------------------- validate_positions


def test_validate_returns_float_copy():
    given_positions = np.array([[0, 0], [40, 0]], dtype=int)
    xy = validate_positions(given_positions)
    assert xy.dtype == np.float64
    xy[0, 0] = 99.0
    assert given_positions[0, 0] == 0


@pytest.mark.parametrize(
    ("positions", "message"),
    [
        ([[0.0, 0.0], [40.0, 0.0], [3.0, 4.0]], "robots 0 and 2 (0-based index) are 5.0 mm apart"),
        ([[0.0, 0.0], [0.0, math.inf]], "robot 1 (0-based index) position (0.0, inf) is not fin"),
        ([], "0 robots, at least 1 is needed"),
        ([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0]], "must have shape (N, 2), got (2, 3)"),
    ],
)
def test_validate_array_messages(positions, message):
    with pytest.raises(PlacementError) as info:
        validate_positions(positions, source="swarm")
    assert str(info.value).startswith("swarm")
    assert message in str(info.value)


def test_validate_lists_a_few_overlaps_then_counts():
    xy = np.column_stack([np.arange(8) * 10.0, np.zeros(8)])  # pairs within 33 mm: 7 + 6 + 5
    with pytest.raises(PlacementError) as info:
        validate_positions(xy, row_offset=2)
    message = str(info.value)
    assert "18 pairs of robots closer than the 33 mm body diameter" in message
    assert "lines 2 and 3 (10.0 mm apart)" in message
    assert message.count("apart") == 5
    assert message.endswith("and 13 more")
    assert "\n" not in message


def test_validate_touching_is_fine_and_diameter_is_a_parameter():
    validate_positions([[0.0, 0.0], [33.0, 0.0]])
    with pytest.raises(PlacementError, match="closer than the 40 mm body diameter"):
        validate_positions([[0.0, 0.0], [33.0, 0.0]], diameter_mm=40.0)


# ------------------------------------------------------------------------------------ CSV


def test_csv_round_trip_is_exact(tmp_path):
    xy = hex_lattice(25, spacing_mm=47.3, jitter_mm=6.1, rng=np.random.default_rng(5))
    path = tmp_path / "swarm.csv"
    save_csv(xy, path)
    assert path.read_text().splitlines()[0] == "x_mm,y_mm"
    loaded = load_csv(path)
    assert loaded.dtype == np.float64
    np.testing.assert_array_equal(loaded, xy)


def test_csv_extra_columns_any_order_spaces_and_blank_lines(tmp_path):
    path = tmp_path / "placement.csv"
    path.write_text("id, y_mm ,note,  x_mm\n1,0,a,0\n\n2,5.5,b,40\n3,-1e2,c,80\n\n")
    np.testing.assert_array_equal(load_csv(path), [[0.0, 0.0], [40.0, 5.5], [80.0, -100.0]])


def test_csv_refuses_a_row_with_more_fields_than_the_header(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("x_mm,y_mm\n0,0\n40,0,7\n")
    with pytest.raises(PlacementError, match=r"p\.csv line 3: 3 fields, but the header names 2"):
        load_csv(path)
    path.write_text("x_mm,y_mm\n0,0,\n40,0, \n")  # empty trailing fields carry nothing
    np.testing.assert_array_equal(load_csv(path), [[0.0, 0.0], [40.0, 0.0]])


def test_csv_refuses_coordinates_beyond_a_kilometre(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("x_mm,y_mm\n0,0\n0,1e308\n")
    with pytest.raises(PlacementError, match=r"line 3: position \(0, 1e\+308\) is more than"):
        load_csv(path)
    with pytest.raises(PlacementError, match=r"robot 1 \(0-based index\) position"):
        validate_positions([[0.0, 0.0], [-2e6, 0.0]])
    assert validate_positions([[0.0, 0.0], [MAX_COORDINATE_MM, 0.0]])[1, 0] == 1e6


def test_csv_accepts_byte_order_mark(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_bytes(b"\xef\xbb\xbfx_mm,y_mm\r\n0,0\r\n40,0\r\n")
    np.testing.assert_array_equal(load_csv(path), [[0.0, 0.0], [40.0, 0.0]])


GOOD = ["0,0", "40,0", "80,0", "120,0", "160,0", "200,0"]


@pytest.mark.parametrize(
    ("text", "fragments"),
    [
        pytest.param(
            "x,y\n0,0\n40,0\n",
            ["placement.csv: missing column 'x_mm' (header has: x, y)"],
            id="missing-both-columns",
        ),
        pytest.param(
            "x_mm,y\n0,0\n40,0\n",
            ["placement.csv: missing column 'y_mm' (header has: x_mm, y)"],
            id="missing-column",
        ),
        pytest.param(
            "x_mm,x_mm,y_mm\n0,0,0\n",
            ["placement.csv line 1: column 'x_mm' appears twice"],
            id="duplicate-column",
        ),
        pytest.param(
            "x_mm,y_mm\n0,0\n40,0\nabc,5\n",
            ["placement.csv line 4: x_mm is not a number ('abc')"],
            id="not-a-number",
        ),
        pytest.param(
            "x_mm,y_mm\n0,0\n40,\n",
            ["placement.csv line 3: y_mm is not a number ('')"],
            id="empty-cell",
        ),
        pytest.param(
            "x_mm,y_mm\n0,0\n40\n",
            ["placement.csv line 3: y_mm is missing (row has 1 fields)"],
            id="short-row",
        ),
        pytest.param(
            "x_mm,y_mm\n0,0\nnan,40\n",
            ["placement.csv line 3: x_mm is not finite ('nan')"],
            id="nan",
        ),
        pytest.param(
            "x_mm,y_mm\n0,0\n40,0\n80,inf\n",
            ["placement.csv line 4: y_mm is not finite ('inf')"],
            id="inf",
        ),
        pytest.param(
            "x_mm,y_mm\n0,0\n-inf,0\nzz,1\n",
            ["placement.csv line 3: x_mm is not finite ('-inf')", "(and 1 more bad values)"],
            id="several-bad-values",
        ),
        pytest.param(
            "x_mm,y_mm\n", ["placement.csv: 0 robots, at least 1 is needed"], id="header-only"
        ),
        pytest.param(
            "\n".join(["x_mm,y_mm", *GOOD[:1], "300,0", *GOOD[1:4], "3,0"]) + "\n",
            [
                "placement.csv lines 2 and 7: robots 3.0 mm apart,",
                "closer than the 33 mm body diameter",
            ],
            id="overlap",
        ),
        pytest.param(
            "\n".join(["x_mm,y_mm", "0,0", "", "", "40,0", "300,0", "41.5,0"]) + "\n",
            ["placement.csv lines 5 and 7: robots 1.5 mm apart"],
            id="overlap-line-numbers-count-blank-lines",
        ),
        pytest.param(
            "\n".join(["x_mm,y_mm", "0,0", "1,0", "2,0", "200,0", "201,0"]) + "\n",
            [
                "placement.csv: 4 pairs of robots closer than the 33 mm body diameter: ",
                "lines 2 and 3 (1.0 mm apart), lines 2 and 4 (2.0 mm apart), ",
                "lines 3 and 4 (1.0 mm apart), lines 5 and 6 (1.0 mm apart)",
            ],
            id="several-overlaps",
        ),
        pytest.param("", ["placement.csv: file is empty"], id="empty-file"),
        pytest.param("\n  \n", ["placement.csv: file is empty"], id="blank-file"),
    ],
)
def test_csv_bad_input(tmp_path, text, fragments):
    path = tmp_path / "placement.csv"
    path.write_text(text)
    with pytest.raises(PlacementError) as info:
        load_csv(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    relative = message.replace(str(path), "placement.csv", 1)
    for fragment in fragments:
        assert fragment in relative


def test_csv_missing_file(tmp_path):
    path = tmp_path / "nowhere.csv"
    with pytest.raises(PlacementError, match=r"nowhere\.csv: no such placement file"):
        load_csv(path)


def test_csv_directory_is_not_a_file(tmp_path):
    with pytest.raises(PlacementError, match="is a directory, not a placement file"):
        load_csv(tmp_path)


def test_csv_binary_file(tmp_path):
    path = tmp_path / "photo.csv"
    path.write_bytes(b"\xff\xd8\xff\xe0 not text")
    with pytest.raises(PlacementError, match=r"photo\.csv: not a UTF-8 text file"):
        load_csv(path)


def test_placement_error_is_a_value_error():
    assert issubclass(PlacementError, ValueError)


# ------------------------------------------------------------------------ named layouts


def test_generate_names_the_kernels_generators():
    rng = np.random.default_rng(2)
    np.testing.assert_array_equal(generate("line", 3, spacing_mm=50.0), line(3, spacing_mm=50.0))
    np.testing.assert_array_equal(generate("hex", 7), hex_lattice(7))
    random = generate("random", 10, rng=rng, density_per_m2=100.0, area="rect")
    expected = random_uniform(10, density_per_m2=100.0, rng=np.random.default_rng(2))
    np.testing.assert_array_equal(random, expected)
    with pytest.raises(ValueError, match="unknown layout 'grid'; layouts are: hex, line, random"):
        generate("grid", 3)
    with pytest.raises(ValueError, match="random_uniform needs rng"):
        generate("random", 3)


def test_a_lone_robot_is_valid_only_where_asked_for():
    assert validate_positions([[1.0, 2.0]], min_robots=1).tolist() == [[1.0, 2.0]]
    with pytest.raises(PlacementError, match="0 robots, at least 1 is needed"):
        validate_positions([], min_robots=1)


def test_a_placement_file_may_give_each_robots_uid(tmp_path):
    path = tmp_path / "uids.csv"
    path.write_text("uid,x_mm,y_mm\n42,0,0\n\n7,50,0\n")
    placement = read_placement(path)
    assert placement.uids == (42, 7)
    assert placement.positions_mm.tolist() == [[0.0, 0.0], [50.0, 0.0]]
    path.write_text("x_mm,y_mm\n0,0\n50,0\n")
    assert read_placement(path).uids is None


@pytest.mark.parametrize("bad", ["x", "-1", "65536", "1.5", "", "²", "٣", "１"])
def test_a_uid_that_is_not_a_uint16_is_refused_with_file_and_line(tmp_path, bad):
    path = tmp_path / "bad.csv"
    path.write_text(f"x_mm,y_mm,uid\n0,0,1\n\n50,0,{bad}\n")
    with pytest.raises(PlacementError, match=r"bad.csv line 4: uid is not an integer 0-65535"):
        read_placement(path)


# ------------------------------------------------- shapes selected by parameters (issue 33)


def _placed(overrides: dict, seed: int = 1) -> np.ndarray:
    from kilonet import scenarios
    from kilonet.scenarios.base import build_params, place

    localize = scenarios.get("localize")
    return place(localize, build_params(localize, overrides, seed=seed))


def test_a_corridor_c_shape_and_ring_come_from_parameters():
    xy = _placed(
        {
            "placement.kind": "corridor",
            "placement.robots": 120,
            "placement.length_mm": 2000.0,
            "placement.width_mm": 150.0,
        }
    )
    assert xy.shape == (120, 2)
    assert xy[:, 0].min() >= 0.0 and xy[:, 0].max() <= 2000.0 and xy[:, 0].max() > 1800.0
    assert xy[:, 1].min() >= 0.0 and xy[:, 1].max() <= 150.0
    assert pdist(xy).min() >= 33.0
    c = {
        "placement.robots": 80,
        "placement.outer_radius_mm": 500.0,
        "placement.inner_radius_mm": 350.0,
    }
    xy = _placed({**c, "placement.kind": "c_shape", "placement.opening_deg": 120.0})
    r, angle = np.hypot(*xy.T), np.degrees(np.arctan2(xy[:, 1], xy[:, 0]))
    assert r.min() >= 350.0 and r.max() <= 500.0
    assert np.abs(angle).min() >= 60.0  # nothing in the opening about +x
    ring = _placed({**c, "placement.kind": "ring", "placement.opening_deg": 120.0})
    angle = np.degrees(np.arctan2(ring[:, 1], ring[:, 0]))
    assert np.abs(angle).min() < 20.0  # a ring has no opening, whatever opening_deg says
    assert np.hypot(*ring.T).min() >= 350.0


def test_shape_parameters_are_checked_with_clear_errors():
    from kilonet.params import ParamError, Params

    with pytest.raises(ParamError, match=r"inner_radius_mm .* must be below"):
        Params().with_overrides({"placement.kind": "ring", "placement.inner_radius_mm": 800.0})
    # Only shapes with radii care about them.
    Params().with_overrides({"placement.kind": "corridor", "placement.inner_radius_mm": 800.0})
    with pytest.raises(ParamError, match="opening_deg"):
        Params().with_overrides({"placement.opening_deg": 400.0})
    with pytest.raises(ParamError, match=r"placement\.kind"):
        Params().with_overrides({"placement.kind": "spiral"})
    with pytest.raises(ParamError, match=r"placement \(corridor, 200 robots\): .*too high"):
        _placed(
            {
                "placement.kind": "corridor",
                "placement.robots": 200,
                "placement.length_mm": 500.0,
                "placement.width_mm": 100.0,
            }
        )
