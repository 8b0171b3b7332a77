"""The house's one-way layers, checked on the source.

One package, ``kilonet``; the repository's top-level folders are its layers (folder ``F/`` is
``kilonet.F``; ``kilonet/`` itself is the kernel). The kernel imports no protocol, scenario,
picture or experiment; ``kilonet.protocols`` use only the robot API and pure math;
``kilonet.scenarios`` glue the two; ``kilonet.viz`` draws finished runs; ``kilonet.experiments``
sweep and report; ``kilonet.app``, the command line, sits on top and nothing imports it. An
import counts wherever it is written: at the top of a module, inside a function or a
``TYPE_CHECKING`` block, by name
(``importlib.import_module("kilonet.experiments.cli")``, ``__import__``), or as a string that
names a module of the project (``"kilonet.scenarios.analyze:register"``); docstrings do not
count.
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
#: The layers above the kernel: each is a top-level folder, installed as ``kilonet.<folder>``.
SUBLAYERS = ("protocols", "scenarios", "viz", "experiments", "app")
#: The test kit (``kilonet/testing/``): a tool for users' tests that builds swarms with the
#: scenarios' placement generators, so it sits above the scenarios though it lives in the
#: kernel's folder; nothing but tests imports it.
TEST_KIT = "kilonet.testing"
#: ``python -m kilonet``: the command line's launcher, in the kernel's folder because Python
#: looks for ``__main__`` there; it belongs to the application (it runs ``kilonet.app.cli``).
LAUNCHER = "kilonet.__main__"

#: What a protocol may use of the kernel: the robot API (the Kilobot base class, messages,
#: parameter declarations). Its math is its own (``kilonet.protocols.common.geometry``, …).
ROBOT_API = ("kilonet.robot", "kilonet.message", "kilonet.params")
#: Third-party libraries a protocol may use: array math, linear algebra, graph algorithms.
PURE_MATH = ("numpy", "scipy", "networkx")

_IMPORT_FUNCTIONS = {"import_module", "__import__", "find_spec"}


def module_name(path: Path) -> str:
    """``app/cli.py`` -> ``kilonet.app.cli``; ``scenarios/__init__.py`` -> ``kilonet.scenarios``."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    if parts[0] in SUBLAYERS:
        parts.insert(0, "kilonet")
    return ".".join(parts)


def source_path(name: str) -> Path:
    """Where the dotted project module ``name`` lives, less its suffix: ``kilonet.scenarios.gcs``
    -> ``ROOT/scenarios/gcs``, ``kilonet.medium`` -> ``ROOT/kilonet/medium``."""
    parts = name.split(".")
    if len(parts) > 1 and parts[0] == "kilonet" and parts[1] in SUBLAYERS:
        parts = parts[1:]
    return ROOT.joinpath(*parts)


def is_project_module(name: str) -> bool:
    """Whether ``name`` (dotted) is a module or package of the installed ``kilonet``."""
    if name.split(".")[0] != "kilonet":
        return False
    base = source_path(name)
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def layer_of(name: str) -> str | None:
    """The layer of the dotted module ``name``, or ``None`` outside ``kilonet``.

    >>> layer_of("kilonet.protocols.gcs.program"), layer_of("kilonet.medium"), layer_of("numpy")
    ('protocols', 'kernel', None)
    """
    parts = name.split(".")
    if parts[0] != "kilonet":
        return None
    if name == TEST_KIT or name.startswith(TEST_KIT + "."):
        return "testing"
    if name == LAUNCHER:
        return "app"
    return parts[1] if len(parts) > 1 and parts[1] in SUBLAYERS else "kernel"


def _docstrings(tree: ast.AST) -> set[int]:
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                found.add(id(body[0].value))
    return found


def _named_module(text: str) -> str | None:
    """The project module a string names (``"kilonet.experiments.cli"``,
    ``"kilonet.scenarios.gcs:SCENARIO"``), or ``None``."""
    name = text.partition(":")[0]
    if "." not in name or not all(part.isidentifier() for part in name.split(".")):
        return None
    return name if is_project_module(name) else None


def imports_of(source: str, module: str) -> Iterator[tuple[int, str]]:
    """``(line, imported module)`` for every import in ``source`` (the text of ``module``).

    Relative imports are resolved; ``from package import name`` also yields
    ``package.name`` when that is a project module.

    Examples
    --------
    >>> sorted(imports_of("import os\\nfrom . import base\\n", "kilonet.scenarios.gcs"))
    [(1, 'os'), (2, 'kilonet.scenarios'), (2, 'kilonet.scenarios.base')]
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
    layer, other = layer_of(importer), layer_of(imported)
    top = imported.split(".")[0]
    if top in SUBLAYERS:
        return f"{top} is not installed top-level: import kilonet.{top}"
    if layer == "kernel" and other in (*SUBLAYERS, "testing"):
        return (
            "the kernel imports no protocol, scenario, picture, experiment, application or test kit"
        )
    if other == "app" and layer != "app":
        return "nothing imports the application (kilonet.app): it is the top layer"
    if other == "testing" and layer != "testing":
        return "only tests import the test kit"
    if layer == "testing" and other in ("protocols", "viz", "experiments"):
        return "the test kit uses the kernel and the scenarios' placements only"
    if layer == "protocols":
        if other in ("scenarios", "viz", "experiments"):
            return "protocols import no scenario, picture or experiment"
        if other == "kernel" and not _within(imported, ROBOT_API):
            return f"protocols use only the robot API of the kernel ({', '.join(ROBOT_API)})"
        if other is None and top not in sys.stdlib_module_names and top not in PURE_MATH:
            return f"protocols use only the standard library and pure math ({', '.join(PURE_MATH)})"
    if layer == "scenarios" and other in ("viz", "experiments"):
        return "scenarios import no picture or experiment (they sit above)"
    if layer == "viz" and other == "experiments":
        return "kilonet.viz imports no experiment (experiments sit on top)"
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
    return sorted(p for folder in ("kilonet", *SUBLAYERS) for p in (ROOT / folder).rglob("*.py"))


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
        "    from kilonet.scenarios.base import Scenario\n"
        "def f():\n"
        "    import kilonet.experiments.sweep\n"
    )
    broken = [line for line, why in _check(source, "kilonet.simulation") if why]
    assert broken == [3, 5]  # kilonet.scenarios.base, kilonet.experiments.sweep


def test_the_checker_sees_imports_by_name_and_module_strings():
    source = (
        '"""Mentions kilonet.scenarios.analyze in a docstring, which is fine."""\n'
        "import importlib\n"
        'importlib.import_module("kilonet.experiments.cli")\n'
        '__import__("kilonet.protocols.gcs.program")\n'
        'PLUGINS = ["kilonet.scenarios.analyze:register", "not.a.module", "scenarios"]\n'
    )
    found = [(line, name) for line, name in imports_of(source, "kilonet.simulation")]
    assert (3, "kilonet.experiments.cli") in found
    assert (4, "kilonet.protocols.gcs.program") in found
    assert (5, "kilonet.scenarios.analyze") in found
    assert all(line != 1 for line, _ in found)
    assert [line for line, why in _check(source, "kilonet.simulation") if why] == [3, 4, 5]


@pytest.mark.parametrize(
    ("imported", "allowed"),
    [
        ("kilonet.robot", True),
        ("kilonet.message", True),
        ("kilonet.params", True),
        ("kilonet.protocols.common.geometry", True),
        ("numpy", True),
        ("scipy.spatial.transform", True),
        ("math", True),
        ("kilonet.protocols.gcs.base", True),
        ("kilonet.simulation", False),
        ("kilonet.medium", False),
        ("kilonet.motion", False),
        ("kilonet", False),  # the package re-exports Simulation
        ("pandas", False),
        ("simpy", False),
        ("kilonet.scenarios.base", False),
    ],
)
def test_protocols_use_only_the_robot_api_and_pure_math(imported, allowed):
    assert (layer_rule_broken("kilonet.protocols.gradient", imported) is None) is allowed


def test_a_violation_names_file_line_and_rule():
    source = "def main():\n    import kilonet.scenarios\n    import scenarios\n"
    assert violations_in(ROOT / "kilonet" / "simulation.py", source) == [
        "kilonet/simulation.py:2: imports kilonet.scenarios: the kernel imports no protocol, "
        "scenario, picture, experiment, application or test kit",
        "kilonet/simulation.py:3: imports scenarios: scenarios is not installed top-level: "
        "import kilonet.scenarios",
    ]


# -- inside the protocols: phases in order, math apart from robot parts ------------------------
#: Protocol modules that are pure math: they may import only the standard library, pure math
#: and one another, never a robot part (a program, a phase, a message layout).
PROTOCOL_MATH = (
    "kilonet.protocols.common.geometry",
    "kilonet.protocols.common.alignment",
    "kilonet.protocols.localize.island_solve",
    "kilonet.protocols.follower.pivot_turns",
    "kilonet.protocols.gcs.merging_rules",
    "kilonet.protocols.gcs.frame_keys",
)


def _phase_number(module: str) -> int | None:
    """``kilonet.protocols.gcs.phase7_refinement`` -> 7, ``….phase5b_pause`` -> 5; None if no
    phase."""
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
    assert _phase_number("kilonet.protocols.gcs.phase7_refinement") == 7
    assert _phase_number("kilonet.protocols.gcs.phase5b_pause") == 5
    assert _phase_number("kilonet.protocols.gcs.program") is None


def test_protocol_math_imports_no_robot_part():
    allowed = PROTOCOL_MATH
    found = []
    for module in PROTOCOL_MATH:
        path = source_path(module).with_suffix(".py")
        for line, imported in imports_of(path.read_text(), module):
            top = imported.split(".")[0]
            if top == "kilonet":
                broken = imported != "kilonet.protocols" and not _within(imported, allowed)
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


@pytest.mark.parametrize(
    ("importer", "imported", "allowed"),
    [
        ("kilonet.app.commands", "kilonet.experiments.sweep", True),
        ("kilonet.app.commands", "kilonet.viz.cli", True),
        ("kilonet.__main__", "kilonet.app.cli", True),  # the launcher is the app's
        ("kilonet.experiments.cli", "kilonet.app.cli", False),
        ("kilonet.viz.cli", "kilonet.app.commands", False),
        ("kilonet.scenarios.base", "kilonet.app", False),
        ("kilonet.errors", "kilonet.app.cli", False),
    ],
)
def test_the_application_is_the_top_layer_and_nothing_imports_it(importer, imported, allowed):
    assert (layer_rule_broken(importer, imported) is None) is allowed
