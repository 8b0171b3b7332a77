"""Hypothesis profiles: the default run is derandomized so CI sees the same examples every time.

``HYPOTHESIS_PROFILE=explore python -m pytest`` draws fresh random examples (500 where a test
sets no count) to hunt for new counterexamples; a failure prints the example to pin.
"""

import os

from hypothesis import settings

settings.register_profile("default", derandomize=True)
settings.register_profile("explore", derandomize=False, max_examples=500)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))

# pytester's in-process runs (test_testing_docs.py) forget every module first imported inside
# them, and NumPy's compiled modules cannot be loaded twice: load SciPy's spatial module (and
# the NumPy parts it pulls in) once, up front.
import scipy.spatial  # noqa: E402, F401


def pytest_configure(config) -> None:
    """Register ``twin_of``: the default-tier twin of a slow test (tests/test_slow_twins.py)."""
    config.addinivalue_line(
        "markers",
        "twin_of(name): this default-tier test makes the assertions of the slow test `name` "
        "(same file) on a smaller run (docs/testing.md, 'Slow tests and their twins')",
    )
