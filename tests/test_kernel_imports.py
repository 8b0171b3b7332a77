"""The kernel's modules import one another without a circle, counting imports made only for
type checking (issue 42): a circle ties modules together so that none can be read, tested or
replaced alone, even when ``TYPE_CHECKING`` keeps it from failing at run time."""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx

import kilonet

KERNEL = Path(kilonet.__file__).parent


def _kernel_modules() -> dict[str, Path]:
    """Every module of the kernel package itself (``kilonet/*.py``), by dotted name."""
    modules = {
        f"kilonet.{path.stem}": path for path in KERNEL.glob("*.py") if path.stem != "__init__"
    }
    modules["kilonet"] = KERNEL / "__init__.py"
    return modules


def _imported(tree: ast.Module) -> set[str]:
    """Every module named by an ``import`` or ``from ... import`` anywhere in ``tree``, under
    ``if TYPE_CHECKING:`` and inside functions included; ``from P import m`` names ``P.m`` as
    well as ``P`` (``m`` may be a module)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def kernel_import_graph() -> nx.DiGraph:
    """The directed graph importer -> imported among the kernel's modules."""
    modules = _kernel_modules()
    graph = nx.DiGraph()
    graph.add_nodes_from(modules)
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for target in _imported(tree) & modules.keys():
            if target != name:
                graph.add_edge(name, target)
    return graph


def test_the_graph_sees_type_checking_imports() -> None:
    # The medium reads the world's positions only under TYPE_CHECKING: the edge must be there,
    # or the acyclicity test below would pass by seeing too little.
    graph = kernel_import_graph()
    assert graph.has_edge("kilonet.medium", "kilonet.world")
    assert graph.has_edge("kilonet.simulation", "kilonet.medium")


def test_kernel_imports_are_acyclic() -> None:
    graph = kernel_import_graph()
    try:
        cycle = nx.find_cycle(graph)
    except nx.NetworkXNoCycle:
        return
    raise AssertionError("kernel import circle: " + " -> ".join(a for a, _ in cycle))


def test_the_medium_knows_no_program():
    # The medium hands deliveries to the receive ports (kilonet.port) and gets each robot's
    # transmit callables as plain data: it imports neither the robot API nor the simulation.
    graph = kernel_import_graph()
    assert not graph.has_edge("kilonet.medium", "kilonet.robot")
    assert not graph.has_edge("kilonet.medium", "kilonet.simulation")
    assert not graph.has_edge("kilonet.port", "kilonet.robot")
