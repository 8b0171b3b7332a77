"""Hypothesis strategies for protocol tests: placements, payloads, channel settings.

They compose like Hypothesis's own (``hypothesis.extra.numpy``): a placement strategy draws a
swarm for :func:`kilonet.testing.run_swarm`, a payload strategy the fields of a
:class:`~kilonet.message.Layout`, a settings strategy dotted parameter overrides for the
``params`` argument of the kit.

* :func:`connected_placements`: robots whose range graph is connected and where every robot
  has a number of neighbours in a given range; ``"lattice"`` (the kernel's hex and line
  generators at a drawn spacing) or ``"random"`` (each robot dropped within range of one
  already placed, at a drawn bearing and distance; shrinks toward tight clusters).
* :func:`payloads` / :func:`messages`: field values that fit a layout (every struct code's
  full range, scaled fields on their grid), and the packed messages; :func:`raw_messages`:
  any message the payload limit accepts.
* :func:`loss_settings`, :func:`noise_settings`, :func:`channel_settings`: ``medium.loss_prob``
  and ``ranging.sigma_mm`` / ``ranging.bias_sigma_mm`` overrides.

Examples
--------
>>> import networkx as nx
>>> from hypothesis import given, settings
>>> from kilonet.visibility import LinkModel, communication_graph
>>> @settings(max_examples=5, database=None)
... @given(connected_placements(min_robots=4, max_robots=6, max_neighbours=3))
... def check(xy):
...     graph = communication_graph(xy, LinkModel(85.0))
...     assert 4 <= len(xy) <= 6 and nx.is_connected(graph)
...     assert max(d for _, d in graph.degree) <= 3
>>> check()
"""

from __future__ import annotations

import math
from typing import Any

import networkx as nx
import numpy as np

try:
    from hypothesis import assume
    from hypothesis import strategies as st
except ImportError as exc:  # pragma: no cover - hypothesis is a test dependency
    raise ImportError(
        "kilonet.testing.strategies needs Hypothesis: pip install 'kilonet[test]' or "
        "pip install hypothesis"
    ) from exc

from kilonet.message import KILOLIB, SYSTEM_TYPES, Layout, Message, PayloadLimit
from kilonet.placement import ROBOT_DIAMETER_MM
from kilonet.scenarios.placement import generate
from kilonet.visibility import LinkModel, communication_graph

__all__ = [
    "channel_settings",
    "connected_placements",
    "loss_settings",
    "messages",
    "noise_settings",
    "payloads",
    "raw_messages",
]

#: Value ranges of the struct codes a Layout may use.
_CODE_RANGES = {
    "B": (0, 0xFF),
    "b": (-0x80, 0x7F),
    "H": (0, 0xFFFF),
    "h": (-0x8000, 0x7FFF),
    "I": (0, 0xFFFF_FFFF),
    "i": (-0x8000_0000, 0x7FFF_FFFF),
}


# ------------------------------------------------------------------------------ placements


def _fits(xy: np.ndarray, range_mm: float, min_neighbours: int, max_neighbours: int | None) -> bool:
    """Whether the range graph of ``xy`` is connected with every degree within the bounds."""
    graph = communication_graph(xy, LinkModel(range_mm))
    degrees = [d for _, d in graph.degree]
    high = len(xy) if max_neighbours is None else max_neighbours
    return min_neighbours <= min(degrees) and max(degrees) <= high and nx.is_connected(graph)


@st.composite
def _lattice(draw: Any, n: int, range_mm: float) -> np.ndarray:
    layout = draw(st.sampled_from(["hex", "line"]))
    spacing = draw(st.floats(ROBOT_DIAMETER_MM, range_mm))
    return generate(layout, n, spacing_mm=spacing)


@st.composite
def _grown(draw: Any, n: int, range_mm: float) -> np.ndarray:
    """Each robot within ``range_mm`` of one placed before it, never overlapping one."""
    xy = [(0.0, 0.0)]
    reach = math.nextafter(range_mm, 0.0) - 1e-6  # stays within range after rounding
    while len(xy) < n:
        for _ in range(20):
            px, py = xy[draw(st.integers(0, len(xy) - 1))]
            angle = draw(st.floats(0.0, 2 * math.pi, exclude_max=True))
            dist = draw(st.floats(ROBOT_DIAMETER_MM, reach))
            x, y = px + dist * math.cos(angle), py + dist * math.sin(angle)
            if all(math.hypot(x - qx, y - qy) >= ROBOT_DIAMETER_MM for qx, qy in xy):
                xy.append((x, y))
                break
        else:
            assume(False)  # boxed in: no free spot found
    return np.array(xy)


def connected_placements(
    *,
    min_robots: int = 3,
    max_robots: int = 12,
    kind: str = "any",
    range_mm: float = 85.0,
    min_neighbours: int = 1,
    max_neighbours: int | None = None,
) -> st.SearchStrategy[np.ndarray]:
    """Placements (``(N, 2)`` centres, mm) whose robots all reach each other through links
    of at most ``range_mm`` (``medium.range_mm``; no occlusion), each with between
    ``min_neighbours`` and ``max_neighbours`` robots in range.

    Parameters
    ----------
    min_robots, max_robots : int
        Swarm size bounds (at least 2).
    kind : {"any", "lattice", "random"}
        The kernel's hex and line lattices at a drawn spacing, robots dropped one by one
        within range of the swarm, or either.
    range_mm : float
        Link range, mm.
    min_neighbours, max_neighbours : int
        Bounds on every robot's number of robots in range (``None``: no upper bound).

    Raises
    ------
    ValueError
        For bounds no placement can meet.
    """
    if not 2 <= min_robots <= max_robots:
        raise ValueError(f"need 2 <= min_robots <= max_robots, got {min_robots}, {max_robots}")
    if max_neighbours is not None and max_neighbours < min_neighbours:
        raise ValueError(f"max_neighbours={max_neighbours} is below min_neighbours")
    if range_mm < ROBOT_DIAMETER_MM:
        raise ValueError(f"range_mm={range_mm} is shorter than a body: no two robots link")
    builders = {"lattice": [_lattice], "random": [_grown], "any": [_lattice, _grown]}
    if kind not in builders:
        raise ValueError(f"kind must be 'any', 'lattice' or 'random', got {kind!r}")

    sizes = st.integers(min_robots, max_robots)
    return st.one_of([sizes.flatmap(lambda n, b=b: b(n, range_mm)) for b in builders[kind]]).filter(
        lambda xy: _fits(xy, range_mm, min_neighbours, max_neighbours)
    )


# ------------------------------------------------------------------------------ messages


def _field(code: str, scale: float | None) -> st.SearchStrategy:
    if code == "?":
        return st.booleans()
    if code not in _CODE_RANGES:
        raise ValueError(f"payloads(): struct code {code!r} is not one a Layout field uses")
    lo, hi = _CODE_RANGES[code]
    stored = st.integers(lo, hi)
    return stored if scale is None else stored.map(lambda v: v * scale)


def payloads(layout: Layout) -> st.SearchStrategy[dict[str, Any]]:
    """Field values that fit ``layout`` (``layout.pack(**values)`` never refuses them), over
    each field's whole range; a scaled field's values are multiples of its scale.

    Raises
    ------
    ValueError
        If the layout uses a struct code other than B, b, H, h, I, i, ?.

    Examples
    --------
    >>> from hypothesis import given, settings
    >>> POS = Layout("pos", type=3, fields=[("id", "B"), ("x_mm", "h", 0.5)])
    >>> @settings(max_examples=20, database=None)
    ... @given(payloads(POS))
    ... def round_trip(values):
    ...     assert POS.unpack(POS.pack(**values))._asdict() == values
    >>> round_trip()
    """
    return st.fixed_dictionaries({name: _field(code, scale) for name, code, scale in layout.fields})


def messages(layout: Layout) -> st.SearchStrategy[Message]:
    """Messages of ``layout``, packed from :func:`payloads`."""
    return payloads(layout).map(lambda values: layout.pack(**values))


def raw_messages(limit: PayloadLimit = KILOLIB) -> st.SearchStrategy[Message]:
    """Any message ``limit`` accepts: payloads of up to its bits (little-endian), any program
    type byte if it has one (0-127; kilolib keeps 128 and up for itself; else 0), correct
    CRC."""
    n_bytes = -(-limit.data_bits // 8)
    data = st.integers(0, (1 << limit.data_bits) - 1).flatmap(
        lambda v: st.integers(max(1, -(-v.bit_length() // 8)), n_bytes).map(
            lambda k: v.to_bytes(k, "little")
        )
    )
    kind = st.integers(0, SYSTEM_TYPES - 1) if limit.has_type else st.just(0)
    return st.builds(Message, st.one_of(st.just(b""), data), kind)


# ------------------------------------------------------------------------------ settings


def loss_settings(max_loss_prob: float = 0.3) -> st.SearchStrategy[dict[str, float]]:
    """``{"medium.loss_prob": p}`` with ``0 <= p <= max_loss_prob``."""
    return st.fixed_dictionaries({"medium.loss_prob": st.floats(0.0, max_loss_prob)})


def noise_settings(
    max_sigma_mm: float = 3.0, max_bias_mm: float = 2.0
) -> st.SearchStrategy[dict[str, float]]:
    """``{"ranging.sigma_mm": s, "ranging.bias_sigma_mm": b}``: per-reception noise and the
    spread of per-robot biases, mm."""
    return st.fixed_dictionaries(
        {
            "ranging.sigma_mm": st.floats(0.0, max_sigma_mm),
            "ranging.bias_sigma_mm": st.floats(0.0, max_bias_mm),
        }
    )


def channel_settings(
    max_loss_prob: float = 0.3, max_sigma_mm: float = 3.0, max_bias_mm: float = 2.0
) -> st.SearchStrategy[dict[str, float]]:
    """:func:`loss_settings` and :func:`noise_settings` in one dict."""
    return st.builds(
        lambda a, b: {**a, **b},
        loss_settings(max_loss_prob),
        noise_settings(max_sigma_mm, max_bias_mm),
    )
