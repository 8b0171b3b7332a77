"""A program author's mistakes on ``kilonet run --program``: one line naming the robot, the
callback and the line, exit status 2 (130 for Ctrl-C), nothing written."""

from __future__ import annotations

import json
import re
import textwrap
from pathlib import Path

import pytest

from kilonet.app.cli import main


def program(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "bot.py"
    path.write_text(
        "from kilonet.message import Message\nfrom kilonet.robot import Kilobot\n\n\n"
        + textwrap.dedent(body)
    )
    return path


def run(tmp_path: Path, path: Path, *extra: str) -> int:
    out = tmp_path / "out"
    status = main(
        [
            "run",
            "--program",
            str(path),
            "--robots",
            "3",
            "--duration",
            "3",
            "--out",
            str(out),
            *extra,
        ]
    )
    if status != 0:
        assert not out.exists() and not list(tmp_path.glob(".out.*"))
    return status


@pytest.mark.parametrize(
    ("returns", "shown"),
    [
        ("b'\\x01'", "bytes b'\\x01'"),
        ("'hi'", "str 'hi'"),
        ("7", "int 7"),
        ("(i for i in range(2))", "generator <generator"),
    ],
)
def test_message_tx_returning_no_message(tmp_path, capsys, returns, shown):
    path = program(
        tmp_path,
        f"""
        class Bad(Kilobot):
            def message_tx(self):
                return {returns}
        """,
    )
    assert run(tmp_path, path) == 2
    err = capsys.readouterr().err.split("\r")[-1]
    assert err.count("\n") == 1
    assert f"bot.py: robot 2's message_tx() returned {shown}" in err, err


def test_an_oversized_payload_is_one_line(tmp_path, capsys):
    path = program(
        tmp_path,
        """
        class Big(Kilobot):
            def message_tx(self):
                return Message(bytes(10), 300)
        """,
    )
    assert run(tmp_path, path) == 2
    err = capsys.readouterr().err.split("\r")[-1]
    assert err.startswith("kilonet: error: ") and "bot.py: message type 300 is not a byte" in err


def test_a_busy_loop_is_stopped_naming_the_robot_and_callback(tmp_path, capsys):
    path = program(
        tmp_path,
        """
        class Spin(Kilobot):
            def loop(self):
                while True:
                    pass
        """,
    )
    assert run(tmp_path, path, "--watchdog", "0.2") == 2
    err = capsys.readouterr().err.split("\r")[-1]
    assert re.search(r"robot \d's loop \(bot.py:8\) has run 0.2 s of wall time without", err)


def test_print_in_a_program_leaves_json_output_valid(tmp_path, capsys):
    path = program(
        tmp_path,
        """
        class Talks(Kilobot):
            def setup(self):
                print("hello from", self.kilo_uid)
        """,
    )
    assert main(["run", "--program", str(path), "--robots", "3", "--duration", "1", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["scenario"] == "program"
    assert "hello from 0" in err
