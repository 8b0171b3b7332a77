"""Every mistake a program author can make on ``kilonet run --program`` is one line on stderr
naming their file and line (and the robot and callback where known), exit status 2, no
traceback and nothing left in ``--out`` (issues 43 and 45).

Each case of the corpus is a small faulty program; the line the error must name is marked
``# <-`` in it.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from kilonet.app.cli import main

HEADER = (
    "import math, sys, threading\nimport numpy, simpy\n"
    "from kilonet.message import Message\nfrom kilonet.robot import Kilobot\n\n\n"
)

#: name -> (program body, what the line must also say)
CORPUS: dict[str, tuple[str, str]] = {
    "message_rx takes one argument": (
        """
        class Bad(Kilobot):
            def message_tx(self):
                return Message(b"hi")

            def message_rx(self, m):  # <-
                pass
        """,
        "Bad.message_rx(self, m) cannot take the arguments message_rx(message, distance)",
    ),
    "message_rx takes none": (
        """
        class Bad(Kilobot):
            def message_rx(self):  # <-
                pass
        """,
        "Bad.message_rx(self) cannot take",
    ),
    "loop takes an argument": (
        """
        class Bad(Kilobot):
            def loop(self, x):  # <-
                pass
        """,
        "Bad.loop(self, x) cannot take the arguments loop()",
    ),
    "loop is None": (
        """
        class Bad(Kilobot):
            loop = None  # <-
        """,
        "Bad.loop = None is not a method",
    ),
    "loop is a number": (
        """
        class Bad(Kilobot):
            loop = 5  # <-
        """,
        "Bad.loop = 5 is not a method",
    ),
    "loop is a property": (
        """
        class Bad(Kilobot):
            loop = property(lambda self: 5)  # <-
        """,
        "Bad.loop = <property object at",
    ),
    "LED_KEY is a number": (
        """
        class Bad(Kilobot):
            LED_KEY = 5  # <-
        """,
        "Bad.LED_KEY = 5: give ((r, g, b), meaning) pairs",
    ),
    "LED_KEY with a level above 3": (
        """
        class Bad(Kilobot):
            LED_KEY = (((9, 0, 0), "red"),)  # <-
        """,
        "Bad.LED_KEY = (((9, 0, 0), 'red'),): give",
    ),
    "async loop": (
        """
        class Bad(Kilobot):
            async def loop(self):  # <-
                pass
        """,
        "Bad.loop is a coroutine function (async def)",
    ),
    "yield 5": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield 5  # <-
        """,
        "robot 0's loop yielded 5; a program may only yield self.delay(ms)",
    ),
    "yield None": (
        """
        class Bad(Kilobot):
            def setup(self):
                yield  # <-
        """,
        "robot 0's setup yielded None",
    ),
    "yield a SimPy event": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield simpy.Environment().timeout(1)  # <-
        """,
        "robot 0's loop yielded <Timeout(1) object at",
    ),
    "yield a value shown on several lines": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield numpy.zeros((2, 2))  # <-
        """,
        "robot 0's loop yielded array([[0., 0.], | [0., 0.]]); a program may only",
    ),
    "yield a value whose repr raises": (
        """
        class Odd:
            def __repr__(self):
                raise ValueError("no")


        class Bad(Kilobot):
            def loop(self):
                yield Odd()  # <-
        """,
        "robot 0's loop yielded <Odd: repr() raised ValueError>; a program may only",
    ),
    "delay not yielded before another": (
        """
        class Bad(Kilobot):
            def loop(self):
                self.delay(5)
                yield self.delay(5)  # <-
        """,
        "in loop: RuntimeError: robot 0: delay() was called without `yield`",
    ),
    "delay not yielded in a plain loop of a generator program": (
        """
        class Bad(Kilobot):
            def setup(self):
                yield self.delay(1)

            def loop(self):  # <-
                self.delay(5)
        """,
        "robot 0's loop called delay() without `yield`",
    ),
    "delay overridden": (
        """
        class Bad(Kilobot):
            def delay(self, ms):  # <-
                return None
        """,
        "Bad.delay replaces Kilobot.delay",
    ),
    "StopIteration in a generator": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield self.delay(5)
                raise StopIteration  # <-
        """,
        "in loop: RuntimeError: generator raised StopIteration",
    ),
    "yield delay(-5)": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield self.delay(-5)  # <-
        """,
        "in loop: ValueError: delay(ms) needs a number of ms >= 0, got -5",
    ),
    "delay(-1) in setup": (
        """
        class Bad(Kilobot):
            def setup(self):
                yield self.delay(-1)  # <-
        """,
        "in setup: ValueError: delay(ms) needs a number of ms >= 0, got -1",
    ),
    "delay('5')": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield self.delay('5')  # <-
        """,
        "got '5'",
    ),
    "delay(nan)": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield self.delay(math.nan)  # <-
        """,
        "got nan",
    ),
    "an error after a delay": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield self.delay(5)
                1 / 0  # <-
        """,
        "in loop: ZeroDivisionError: division by zero (robot 0",
    ),
    "an error in a generator setup": (
        """
        class Bad(Kilobot):
            def setup(self):
                yield self.delay(5)
                {}["missing"]  # <-
        """,
        "in setup: KeyError: 'missing'",
    ),
    "an exception that needs constructor arguments": (
        """
        class Oops(Exception):
            def __init__(self, a, b):
                super().__init__(f"{a} and {b}")


        class Bad(Kilobot):
            def loop(self):
                yield self.delay(5)
                raise Oops(1, 2)  # <-
        """,
        "in loop: Oops: 1 and 2",
    ),
    "a kernel name as a class attribute": (
        """
        class Bad(Kilobot):
            _kuid = 3  # <-
        """,
        "Bad._kuid: names starting with '_k' are the kernel's",
    ),
    "a kernel name set in setup": (
        """
        class Bad(Kilobot):
            def setup(self):
                self._kenv = None  # <-
        """,
        "Bad.setup sets self._kenv: names starting with '_k' are the kernel's",
    ),
    "a kernel name set in loop": (
        """
        class Bad(Kilobot):
            def loop(self):
                self._krate = 0.0  # <-
        """,
        "Bad.loop sets self._krate",
    ),
    "a kernel name set through setattr": (
        """
        class Bad(Kilobot):
            def loop(self):
                setattr(self, "_krate", 0.0)  # <-
        """,
        "Bad.loop sets self._krate",
    ),
    "a kernel name set under another name": (
        """
        class Bad(Kilobot):  # <-
            def loop(self):
                setattr(self, "_k" + "rate", 0.0)
        """,
        "robot 0 (Bad) set _krate",
    ),
    "_attach overridden": (
        """
        class Bad(Kilobot):
            def _attach(self, *args):  # <-
                pass
        """,
        "Bad._attach replaces Kilobot._attach",
    ),
    "position_estimate returns text": (
        """
        class Bad(Kilobot):
            def position_estimate(self):  # <-
                return "x"
        """,
        "robot 0's position_estimate() returned 'x', not (x_mm, y_mm, frame) or None",
    ),
    "position_estimate returns two numbers": (
        """
        class Bad(Kilobot):
            def position_estimate(self):  # <-
                return (1.0, 2.0)
        """,
        "returned (1.0, 2.0), not (x_mm, y_mm, frame)",
    ),
    "an exception whose str raises": (
        """
        class Odd(Exception):
            def __str__(self):
                raise ValueError("no")


        class Bad(Kilobot):
            def loop(self):
                raise Odd()  # <-
        """,
        "in loop: Odd (its message cannot be shown: str() raised ValueError)",
    ),
    "raise BaseException": (
        """
        class Bad(Kilobot):
            def loop(self):
                raise BaseException("deep")  # <-
        """,
        "in loop: BaseException: deep",
    ),
    "raise GeneratorExit in a generator": (
        """
        class Bad(Kilobot):
            def loop(self):
                yield self.delay(1)
                raise GeneratorExit  # <-
        """,
        "in loop: GeneratorExit",
    ),
    "a message over several lines": (
        """
        class Bad(Kilobot):
            def setup(self):
                raise ValueError("first\\nsecond\\r\\nthird")  # <-
        """,
        "in setup: ValueError: first | second | third",
    ),
    "sys.exit in loop": (
        """
        class Bad(Kilobot):
            def loop(self):
                sys.exit(3)  # <-
        """,
        "in loop: SystemExit: 3 (a robot program cannot end kilonet; return from the callback)",
    ),
}


def write(tmp_path: Path, body: str) -> tuple[Path, int]:
    """The program file and the line marked ``# <-`` in it."""
    source = HEADER + textwrap.dedent(body).lstrip("\n")
    path = tmp_path / "bot.py"
    path.write_text(source)
    (line,) = [n for n, text in enumerate(source.splitlines(), 1) if text.endswith("# <-")]
    return path, line


def refused_line(tmp_path: Path, capsys: pytest.CaptureFixture, *argv: str) -> str:
    """Run ``kilonet run`` with ``argv``; the one line it printed, after checking the exit
    status 2 and that nothing was written."""
    out = tmp_path / "out"
    status = main(["run", *argv, "--duration", "2", "--progress", "none", "--out", str(out)])
    captured = capsys.readouterr()
    assert status == 2, captured.err
    assert not out.exists() and not list(tmp_path.glob(".out*"))
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and "Traceback" not in captured.err, captured.err
    return captured.err.rstrip("\n")


@pytest.mark.parametrize("case", list(CORPUS))
def test_a_program_mistake_is_one_line_naming_the_file_and_line(tmp_path, capsys, case):
    body, says = CORPUS[case]
    path, line = write(tmp_path, body)
    err = refused_line(tmp_path, capsys, "--program", str(path), "--robots", "1")
    assert err.startswith(f"kilonet: error: {path}:{line}: "), err
    assert says in err, err


@pytest.mark.parametrize(
    ("value", "says"),
    [
        ("inf", "--watchdog inf"),
        ("1e10", "--watchdog 1e+10"),
        ("nan", "--watchdog nan"),
        ("-1", "--watchdog -1"),
    ],
)
def test_a_watchdog_that_cannot_be_set_is_refused(tmp_path, capsys, value, says):
    path, _ = write(tmp_path, "class Fine(Kilobot):\n    pass  # <-\n")
    err = refused_line(
        tmp_path, capsys, "--program", str(path), "--robots", "1", "--watchdog", value
    )
    assert err.startswith(f"kilonet: error: {says}: "), err


def test_a_program_left_running_a_thread_does_not_keep_kilonet_waiting(tmp_path):
    path, line = write(
        tmp_path,
        """
        class Bad(Kilobot):
            def setup(self):
                threading.Thread(target=self.wait, name="waiter").start()

            def wait(self):
                threading.Event().wait()  # <-
        """,
    )
    out = tmp_path / "out"
    argv = ["run", "--program", str(path), "--robots", "1", "--duration", "1"]
    done = subprocess.run(
        [sys.executable, "-m", "kilonet.app.cli", *argv, "--progress", "none", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith(f"kilonet: error: {path}:{line}: "), done.stderr
    assert "thread 'waiter'" in done.stderr
    assert not out.exists()


def test_a_mistake_in_a_module_beside_the_program_names_that_module(tmp_path, capsys):
    (tmp_path / "faults_helper_base.py").write_text(
        "from kilonet.robot import Kilobot\n\n\nclass Base(Kilobot):\n"
        "    def loop(self):\n        yield self.delay(1)\n        [][1]\n"
    )
    path, _ = write(
        tmp_path, "from faults_helper_base import Base\n\n\nclass Bot(Base):  # <-\n    pass\n"
    )
    err = refused_line(tmp_path, capsys, "--program", str(path), "--robots", "1")
    helper = tmp_path / "faults_helper_base.py"
    assert err.startswith(f"kilonet: error: {helper}:7: in loop: IndexError: list index"), err


def test_the_kernels_refusals_keep_their_builtin_types_and_carry_the_line():
    from kilonet.errors import ProgramFault
    from kilonet.params import Params
    from kilonet.robot import Kilobot
    from kilonet.simulation import Simulation

    class Deaf(Kilobot):
        def message_rx(self):
            pass

    class Yields(Kilobot):
        def loop(self):
            yield 5

    with pytest.raises(TypeError) as refused:
        Simulation([[0, 0]], Deaf, Params(seed=1))
    assert isinstance(refused.value, ProgramFault)
    assert (refused.value.file, refused.value.line) == (
        __file__,
        Deaf.message_rx.__code__.co_firstlineno,
    )
    with pytest.raises(TypeError, match=r"test_program_faults.py:\d+: robot 0's loop yielded 5"):
        Simulation([[0, 0]], Yields, Params(seed=1)).run(1.0)


def test_a_watchdog_outside_the_command_line_is_refused_as_a_value_error():
    from kilonet.watchdog import busy_watchdog

    refused = pytest.raises(ValueError, match=r"^watchdog_s nan: give 0 \(no watchdog\)")
    with refused, busy_watchdog(float("nan")):
        pass
