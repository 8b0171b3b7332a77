"""Installing kilonet installs one top-level package, ``kilonet``, whose layers are the
repository's folders (``protocols/`` is ``kilonet.protocols``): a user's own ``experiments/``
or ``scenarios/`` can never shadow ours."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _source_folder(package: str) -> Path:
    """The folder ``pyproject.toml`` maps ``package`` to (its nearest mapped parent's folder
    plus the rest of its name)."""
    mapping = CONFIG["package-dir"]
    parts = package.split(".")
    for cut in range(len(parts), 0, -1):
        parent = ".".join(parts[:cut])
        if parent in mapping:
            return ROOT / mapping[parent] / Path(*parts[cut:])
    raise AssertionError(f"{package} is under no mapped folder")


def test_every_package_folder_is_listed_and_every_listed_package_exists():
    listed = set(CONFIG["packages"])
    folders = {_source_folder(p) for p in listed}
    on_disk = {
        init.parent
        for top in set(CONFIG["package-dir"].values())
        for init in (ROOT / top).rglob("__init__.py")
    }
    assert on_disk - folders == set(), "package folders missing from pyproject.toml's packages"
    assert all((f / "__init__.py").is_file() for f in folders)


def test_each_folder_maps_to_kilonet_dot_its_name():
    for package, folder in CONFIG["package-dir"].items():
        assert package == "kilonet" if folder == "kilonet" else package == f"kilonet.{folder}"


def _wheel(tmp_path: Path) -> Path:
    source = tmp_path / "source"
    shutil.copytree(
        ROOT,
        source,
        ignore=shutil.ignore_patterns(
            ".git", ".venv*", "runs", "build", "dist", "*.egg-info", "__pycache__", ".*_cache"
        ),
    )
    out = tmp_path / "wheel"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(source)],
        check=True,
        capture_output=True,
    )
    (wheel,) = out.glob("kilonet-*.whl")
    return wheel


def test_the_wheel_installs_kilonet_alone_into_a_fresh_venv(tmp_path):
    wheel = _wheel(tmp_path)
    names = zipfile.ZipFile(wheel).namelist()
    assert "kilonet/viz/replay.html" in names  # package data travels with the mapped folder
    assert "kilonet/protocols/gcs/program.py" in names

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = Path(
        subprocess.run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
    )
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "--no-deps",
            "-q",
            str(wheel),
        ],
        check=True,
        capture_output=True,
    )
    top_level = sorted(
        p.name
        for p in site.iterdir()
        if not p.name.endswith(".dist-info") and p.name != "__pycache__"
    )
    assert top_level == ["kilonet"]
    assert (venv / "bin" / "kilonet").is_file()  # the command line comes with it
