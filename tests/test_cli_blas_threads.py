"""The console script asks BLAS for one thread before numpy loads, unless the user chose."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

PROGRAM = """
import os

from kilonet.robot import Kilobot


class ShowBlasThreads(Kilobot):
    def setup(self):
        if self.kilo_uid == 0:
            print("BLAS", os.environ.get("OPENBLAS_NUM_THREADS"))
"""


def _kilonet(tmp_path: Path, env: dict[str, str]) -> str:
    program = tmp_path / "show.py"
    program.write_text(PROGRAM)
    script = Path(sys.executable).with_name("kilonet")
    command = [str(script)] if script.exists() else [sys.executable, "-m", "kilonet"]
    done = subprocess.run(
        [*command, "run", "--program", str(program), "--robots", "2", "--duration", "1", "--quiet"],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    )
    return next(line for line in done.stdout.splitlines() if line.startswith("BLAS"))


@pytest.fixture
def clean_env() -> dict[str, str]:
    env = dict(os.environ)
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(name, None)
    return env


def test_a_run_gets_one_blas_thread(tmp_path: Path, clean_env: dict[str, str]) -> None:
    assert _kilonet(tmp_path, clean_env) == "BLAS 1"


def test_the_users_own_count_stands(tmp_path: Path, clean_env: dict[str, str]) -> None:
    assert _kilonet(tmp_path, {**clean_env, "OPENBLAS_NUM_THREADS": "2"}) == "BLAS 2"
