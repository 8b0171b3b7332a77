"""Run directories: reserved before a run, put in place whole, never merged, and nothing left
behind when a run fails."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from kilonet.scenarios.output_dir import OutputDir, OutputDirError, _exchange


def tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_a_failed_run_leaves_neither_staging_nor_the_parents_it_made(tmp_path):
    (tmp_path / "runs").mkdir()  # there before: stays
    with (
        pytest.raises(RuntimeError, match="the run failed"),
        OutputDir(tmp_path / "runs" / "2024" / "june" / "one") as out,
    ):
        (out.staging / "robots.csv").write_text("robot\n0\n")
        raise RuntimeError("the run failed")
    assert tree(tmp_path) == ["runs"]


def test_a_run_never_published_is_discarded(tmp_path):
    with OutputDir(tmp_path / "one") as out:
        (out.staging / "summary.json").write_text("{}")
    assert tree(tmp_path) == []


def test_publish_replaces_the_old_directory_whole(tmp_path):
    target = tmp_path / "run"
    target.mkdir()
    (target / "old.png").write_text("stale")
    (target / "summary.json").write_text('{"old": true}')
    with OutputDir(target, replace=True) as out:
        (out.staging / "summary.json").write_text('{"new": true}')
        assert out.publish() == target
    assert tree(tmp_path) == ["run", "run/summary.json"]
    assert (target / "summary.json").read_text() == '{"new": true}'


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="renameat2 is Linux's")
def test_the_exchange_is_one_atomic_swap_on_linux(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "from_a").touch()
    (b / "from_b").touch()
    inode_a = a.stat().st_ino
    assert _exchange(a, b) is True
    assert (b / "from_a").exists() and (a / "from_b").exists()
    assert b.stat().st_ino == inode_a


def test_refusals_name_the_path(tmp_path):
    (tmp_path / "file").write_text("x")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    cases = [
        (tmp_path / "file", "file exists and is not a directory"),
        (tmp_path / "file" / "run", "cannot write under"),
        (tmp_path / "full", "full already exists; choose another --out or pass --replace"),
    ]
    for path, message in cases:
        with pytest.raises(OutputDirError, match=message):
            OutputDir(path)
    assert tree(tmp_path) == ["file", "full", "full/x"]


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes anywhere")
def test_a_read_only_parent_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        with pytest.raises(OutputDirError, match="cannot write in"):
            OutputDir(locked / "run")
    finally:
        locked.chmod(0o700)


def test_a_run_directory_gets_the_mode_the_umask_gives(tmp_path, capsys):
    import os
    import stat

    from kilonet.app.cli import main

    old = os.umask(0o027)
    try:
        assert (
            main(
                [
                    "run",
                    "gradient",
                    "--robots",
                    "3",
                    "--duration",
                    "1",
                    "--out",
                    str(tmp_path / "r"),
                ]
            )
            == 0
        )
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "r").stat().st_mode) == 0o750  # not mkdtemp's 0700
