"""Every docstring example in the installed ``kilonet`` package runs and prints what it shows.

pytest's ``--doctest-modules`` imports a file by its path, which would load ``protocols/x.py``
as a top-level ``protocols.x`` beside ``kilonet.protocols.x`` (the folders are mapped into the
one namespace by ``pyproject.toml``), so the examples are collected here by import name.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

#: The layers mapped into ``kilonet`` from folders of their own: ``kilonet.__path__`` does not
#: list them, so each is walked from its own package.
SUBLAYERS = ("protocols", "scenarios", "viz", "experiments")


def _modules() -> list[str]:
    names = set()
    for package in ("kilonet", *(f"kilonet.{layer}" for layer in SUBLAYERS)):
        names.add(package)
        path = importlib.import_module(package).__path__
        names.update(info.name for info in pkgutil.walk_packages(path, f"{package}."))
    return sorted(names)


def _with_examples(name: str) -> list[doctest.DocTest]:
    module = importlib.import_module(name)
    tests = doctest.DocTestFinder(exclude_empty=True).find(module, name)
    return [t for t in tests if t.examples]


MODULES = _modules()


def test_the_walk_reaches_every_layer():
    """The mapped folders are walked too, not only ``kilonet/`` itself."""
    tops = {name.split(".")[1] for name in MODULES if name.count(".") >= 1}
    assert {"protocols", "scenarios", "viz", "experiments", "testing"} <= tops


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name: str) -> None:
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for test in _with_examples(name):
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
