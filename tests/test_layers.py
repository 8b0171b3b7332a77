"""The house's one-way layers, checked on the source.

``kilonet/`` (the kernel) imports no protocol, scenario or experiment; ``protocols/`` use only
the robot API and pure math; ``scenarios/`` glue the two; ``experiments/`` and the command
line's sub-commands sit on top. An import counts wherever it is written: at the top of a
module, inside a function or a ``TYPE_CHECKING`` block, by name
(``importlib.import_module("experiments.cli")``, ``__import__``), or as a string that names a
module of the project (``"scenarios.analyze:register"``); docstrings do not count.
"""

from __future__ import annotations

import ast
import re
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from kilonet.robot import RESERVED_PREFIX

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("kilonet", "protocols", "scenarios", "presentation", "experiments")

#: What a protocol may use of the kernel: the robot API (the Kilobot base class, messages,
#: parameter declarations) and pure math.
ROBOT_API = ("kilonet.robot", "kilonet.message", "kilonet.params")
PURE_MATH_KERNEL = ("kilonet.geometry", "kilonet.alignment")
#: Third-party libraries a protocol may use: array math, linear algebra, graph algorithms.
PURE_MATH = ("numpy", "scipy", "networkx")

_IMPORT_FUNCTIONS = {"import_module", "__import__", "find_spec"}


def module_name(path: Path) -> str:
    """``kilonet/cli.py`` -> ``kilonet.cli``; ``scenarios/__init__.py`` -> ``scenarios``."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def is_project_module(name: str) -> bool:
    """Whether ``name`` (dotted) is a module or package of the project."""
    base = ROOT.joinpath(*name.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def _docstrings(tree: ast.AST) -> set[int]:
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                found.add(id(body[0].value))
    return found


def _named_module(text: str) -> str | None:
    """The project module a string names (``"experiments.cli"``, ``"scenarios.gcs:SCENARIO"``),
    or ``None``."""
    name = text.partition(":")[0]
    if name.split(".")[0] not in LAYERS or "." not in text.strip(":"):
        return None
    if not all(part.isidentifier() for part in name.split(".")):
        return None
    return name if is_project_module(name) else None


def imports_of(source: str, module: str) -> Iterator[tuple[int, str]]:
    """``(line, imported module)`` for every import in ``source`` (the text of ``module``).

    Relative imports are resolved; ``from package import name`` also yields
    ``package.name`` when that is a project module.

    Examples
    --------
    >>> sorted(imports_of("import os\\nfrom . import base\\n", "scenarios.gcs"))
    [(1, 'os'), (2, 'scenarios'), (2, 'scenarios.base')]
    """
    tree = ast.parse(source)
    package = module if is_project_module(module + ".__init__") else module.rpartition(".")[0]
    docstrings = _docstrings(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, node.module] if node.module else anchor)
            else:
                base = node.module or ""
            yield node.lineno, base
            for alias in node.names:
                if is_project_module(f"{base}.{alias.name}"):
                    yield node.lineno, f"{base}.{alias.name}"
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            arg = node.args[0] if node.args else None
            if (
                name in _IMPORT_FUNCTIONS
                and isinstance(arg, ast.Constant)
                and isinstance(arg.value, str)
            ):
                yield node.lineno, arg.value
        elif (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and id(node) not in docstrings
            and (named := _named_module(node.value))
        ):
            yield node.lineno, named


def _within(name: str, modules: tuple[str, ...]) -> bool:
    return any(name == m or name.startswith(m + ".") for m in modules)


def layer_rule_broken(importer: str, imported: str) -> str | None:
    """Why ``importer`` may not import ``imported``, or ``None`` if it may."""
    layer, top = importer.split(".")[0], imported.split(".")[0]
    if layer == "kilonet" and top in ("protocols", "scenarios", "presentation", "experiments"):
        return "the kernel imports no protocol, scenario, presentation or experiment"
    if layer == "protocols":
        if top in ("scenarios", "presentation", "experiments"):
            return "protocols import no scenario, presentation or experiment"
        if top == "kilonet" and not _within(imported, ROBOT_API + PURE_MATH_KERNEL):
            return (
                "protocols use only the robot API "
                f"({', '.join(ROBOT_API)}) and pure math ({', '.join(PURE_MATH_KERNEL)})"
            )
        if top not in LAYERS and top not in sys.stdlib_module_names and top not in PURE_MATH:
            return f"protocols use only the standard library and pure math ({', '.join(PURE_MATH)})"
    if layer == "scenarios" and top in ("presentation", "experiments"):
        return "scenarios import no presentation or experiment (they sit above)"
    if layer == "presentation" and top == "experiments":
        return "presentation imports no experiment (experiments sit on top)"
    return None


def violations_in(path: Path, source: str) -> list[str]:
    """One ``file:line: imports X: rule`` line per import in ``source`` (the text of the
    project file ``path``) that breaks a layer."""
    module = module_name(path)
    found = []
    for line, imported in sorted(set(imports_of(source, module))):
        why = layer_rule_broken(module, imported)
        if why is not None:
            found.append(f"{path.relative_to(ROOT)}:{line}: imports {imported}: {why}")
    return found


def _project_files() -> list[Path]:
    return sorted(p for layer in LAYERS for p in (ROOT / layer).rglob("*.py"))


def test_every_import_keeps_to_its_layer():
    violations = [v for path in _project_files() for v in violations_in(path, path.read_text())]
    assert not violations, f"{len(violations)} imports break the one-way layers:\n" + "\n".join(
        violations
    )


# -- the checker itself -----------------------------------------------------------------------
def _check(source: str, module: str) -> list[tuple[int, str | None]]:
    found = sorted(set(imports_of(source, module)))
    return [(line, layer_rule_broken(module, name)) for line, name in found]


def test_the_checker_sees_static_imports_in_functions_and_type_checking_blocks():
    source = (
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n"
        "    from scenarios.base import Scenario\n"
        "def f():\n"
        "    import experiments.sweep\n"
    )
    broken = [line for line, why in _check(source, "kilonet.cli") if why]
    assert broken == [3, 5]  # scenarios.base, experiments.sweep


def test_the_checker_sees_imports_by_name_and_module_strings():
    source = (
        '"""Mentions scenarios.analyze in a docstring, which is fine."""\n'
        "import importlib\n"
        'importlib.import_module("experiments.cli")\n'
        '__import__("protocols.gcs.program")\n'
        'PLUGINS = ["scenarios.analyze:register", "not.a.module", "scenarios"]\n'
    )
    found = [(line, name) for line, name in imports_of(source, "kilonet.cli")]
    assert (3, "experiments.cli") in found
    assert (4, "protocols.gcs.program") in found
    assert (5, "scenarios.analyze") in found
    assert all(line != 1 for line, _ in found)
    assert [line for line, why in _check(source, "kilonet.cli") if why] == [3, 4, 5]


@pytest.mark.parametrize(
    ("imported", "allowed"),
    [
        ("kilonet.robot", True),
        ("kilonet.message", True),
        ("kilonet.params", True),
        ("kilonet.geometry", True),
        ("numpy", True),
        ("scipy.spatial.transform", True),
        ("math", True),
        ("protocols.gcs.base", True),
        ("kilonet.simulation", False),
        ("kilonet.medium", False),
        ("kilonet.motion", False),
        ("kilonet", False),  # the package re-exports Simulation
        ("pandas", False),
        ("simpy", False),
        ("scenarios.base", False),
    ],
)
def test_protocols_use_only_the_robot_api_and_pure_math(imported, allowed):
    assert (layer_rule_broken("protocols.gradient", imported) is None) is allowed


def test_a_violation_names_file_line_and_rule():
    source = "def main():\n    import scenarios\n"
    assert violations_in(ROOT / "kilonet" / "cli.py", source) == [
        "kilonet/cli.py:2: imports scenarios: the kernel imports no protocol, scenario, "
        "presentation or experiment"
    ]


# -- inside the protocols: phases in order, math apart from robot parts ------------------------
#: Protocol modules that are pure math: they may import only the standard library, pure math
#: and one another, never a robot part (a program, a phase, a message layout).
PROTOCOL_MATH = (
    "protocols.localize.island_solve",
    "protocols.follower.pivot_turns",
    "protocols.gcs.merging_rules",
    "protocols.gcs.frame_keys",
)


def _phase_number(module: str) -> int | None:
    """``protocols.gcs.phase7_refinement`` -> 7, ``….phase5b_pause`` -> 5; None if no phase."""
    found = re.match(r"phase(\d+)", module.rpartition(".")[2])
    return int(found.group(1)) if found else None


def test_no_phase_imports_a_later_phase():
    """``protocols/<protocol>/phaseN_*.py`` imports no ``phaseM_*`` of its protocol with M > N."""
    later = []
    for path in sorted((ROOT / "protocols").rglob("phase*_*.py")):
        module = module_name(path)
        own = _phase_number(module)
        package = module.rpartition(".")[0]
        for line, imported in imports_of(path.read_text(), module):
            other = _phase_number(imported)
            if imported.rpartition(".")[0] == package and other is not None and other > own:
                later.append(f"{path.relative_to(ROOT)}:{line}: imports {imported}")
    assert not later, "phases import later phases:\n" + "\n".join(later)
    assert _phase_number("protocols.gcs.phase7_refinement") == 7
    assert _phase_number("protocols.gcs.phase5b_pause") == 5
    assert _phase_number("protocols.gcs.program") is None


def test_protocol_math_imports_no_robot_part():
    allowed = PURE_MATH_KERNEL + PROTOCOL_MATH
    found = []
    for module in PROTOCOL_MATH:
        path = ROOT.joinpath(*module.split(".")).with_suffix(".py")
        for line, imported in imports_of(path.read_text(), module):
            top = imported.split(".")[0]
            if top in LAYERS:
                broken = imported != "protocols" and not _within(imported, allowed)
            else:
                broken = top not in sys.stdlib_module_names and top not in PURE_MATH
            if broken:
                found.append(f"{path.relative_to(ROOT)}:{line}: imports {imported}")
    assert not found, "math modules import robot parts:\n" + "\n".join(found)


# -- protocols keep out of the kernel's handles -----------------------------------------------
def kernel_names_in(source: str) -> list[tuple[int, str]]:
    """``(line, name)`` for every attribute or ``getattr``/``setattr`` name in ``source`` that
    starts with the kernel's reserved prefix ``_k`` (the simulation's
    handles in a robot, ``robot._kservices``, the clock's ``env._kt``)."""
    tree = ast.parse(source)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith(RESERVED_PREFIX):
            found.append((node.lineno, node.attr))
        elif (
            isinstance(node, ast.Call)
            and getattr(node.func, "id", "") in ("getattr", "setattr", "hasattr", "delattr")
            and len(node.args) > 1
            and isinstance(node.args[1], ast.Constant)
            and str(node.args[1].value).startswith(RESERVED_PREFIX)
        ):
            found.append((node.lineno, node.args[1].value))
    return sorted(found)


def test_protocols_never_touch_the_kernels_handles():
    found = [
        f"{path.relative_to(ROOT)}:{line}: {name}"
        for path in sorted((ROOT / "protocols").rglob("*.py"))
        for line, name in kernel_names_in(path.read_text())
    ]
    assert not found, "protocols reach into the kernel's handles:\n" + "\n".join(found)
    assert kernel_names_in("x = self._ksim.world\ngetattr(r, '_kindex')\ny = self._known") == [
        (1, "_ksim"),
        (2, "_kindex"),
        (3, "_known"),
    ]
    assert kernel_names_in("self._index = self.kilo_uid") == []
