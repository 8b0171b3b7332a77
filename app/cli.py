"""The ``kilonet`` command line: a dispatcher that knows no command of its own.

Every sub-command registers itself as an entry point of the group ``kilonet.commands``
(``[project.entry-points."kilonet.commands"]`` in ``pyproject.toml``, created when the package
is installed): the entry's name is the command, its value a function ``register(subparsers)``
that adds that command's parser (``subparsers.add_parser(name, ...)``, a
:class:`CommandParser`) with ``set_defaults(func=handler)``. A handler returns the exit
status. Adding a sub-command means writing its module and one line in ``pyproject.toml``; this
file does not change.

Errors the user can fix (:class:`kilonet.errors.UserError`: a bad parameter, placement,
scenario, option or program file) print one line on stderr and exit with status 2, leaving no
partial output behind; an interrupt exits with 130.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import threading
from collections.abc import Callable, Sequence
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from kilonet import __version__
from kilonet.errors import UserError, one_line

__all__ = ["BLAS_THREAD_VARIABLES", "COMMANDS", "CommandParser", "main", "one_blas_thread"]

#: Entry-point group of the sub-commands.
COMMANDS = "kilonet.commands"


class CommandParser(argparse.ArgumentParser):
    """A sub-command's parser whose costly arguments may wait until they are needed.

    ``register`` functions get their parsers from ``subparsers.add_parser``, which makes them
    of this class: :meth:`defer` takes a function that adds arguments (say, the options every
    scenario declares, which loads every scenario and its protocol), called only when this
    command is parsed or its help or usage is shown, so that ``kilonet --help`` or another
    command does not pay for it.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._deferred: list[Callable[[argparse.ArgumentParser], None]] = []

    def defer(self, add_arguments: Callable[[argparse.ArgumentParser], None]) -> None:
        """Call ``add_arguments(self)`` before this parser is first used."""
        self._deferred.append(add_arguments)

    def _complete(self) -> None:
        while self._deferred:
            self._deferred.pop(0)(self)

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        self._complete()
        return super().parse_known_args(args, namespace)

    def format_help(self) -> str:
        self._complete()
        return super().format_help()

    def format_usage(self) -> str:
        self._complete()
        return super().format_usage()


def _commands(argv: Sequence[str]) -> list[EntryPoint]:
    """The commands to load: only the one named in ``argv`` when it is known (so
    ``kilonet params`` imports nothing of ``run``), else all (for help and error listings)."""
    found = list(entry_points(group=COMMANDS))
    named = next((a for a in argv if not a.startswith("-")), None)
    chosen = [ep for ep in found if ep.name == named]
    return chosen or found


def _parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="kilonet",
        description="Discrete-event simulator for Kilobot swarms and the protocols they run.",
        epilog="Start with `kilonet run` (the default scenario) or `kilonet run --help`.",
    )
    parser.add_argument("--version", action="version", version=f"kilonet {__version__}")
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=CommandParser
    )
    for command in _commands(argv):
        command.load()(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``kilonet`` console script; returns the exit status.

    As the console script (``argv`` not given), a failed command ends the process at once
    when a thread that is not a daemon still runs (one a robot program started, already
    refused in one line): the interpreter would otherwise wait for it at exit, forever.
    """
    if argv is None:
        one_blas_thread()
    status = _main(argv)
    if argv is None and status != 0 and _threads_left():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status


#: Environment variables that set the thread count of the BLAS libraries numpy and scipy load.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """Ask the BLAS library numpy will load for one thread, unless the user chose a count.

    A run's linear algebra (the scenarios' scoring, the protocols' small least-squares fits)
    works on matrices far too small for threads to pay: OpenBLAS's threads spin on the other
    core and cost CPU (``docs/performance.md``), and a threaded sum's order varies, so the
    reference metrics' last digits would vary between runs of one seed. Only effective before
    numpy is imported, which the console script does not do before this; sweep workers inherit
    the setting.
    """
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


def _threads_left() -> bool:
    """Whether a thread other than the main one, not a daemon, still runs."""
    main_thread = threading.main_thread()
    return any(t is not main_thread and not t.daemon for t in threading.enumerate())


def _main(argv: Sequence[str] | None) -> int:
    """:func:`main` but for what it does at the end."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not list(entry_points(group=COMMANDS)):
        print(
            f"kilonet: error: no commands registered ({COMMANDS} entry points); install the "
            "package: pip install -e .",
            file=sys.stderr,
        )
        return 2
    args = _parser(argv).parse_args(argv)
    try:
        return args.func(args)
    except UserError as exc:
        print(f"kilonet: error: {one_line(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        where = f" {exc}" if str(exc) else ""  # the robot and callback it stopped, if known
        print(f"kilonet: interrupted{where}", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # Whoever read the output stopped (``kilonet params | head``): end quietly, as Unix
        # tools do, with the shell's status for SIGPIPE.
        _silence_stdout()
        return 141


def _silence_stdout() -> None:
    """Point stdout at the null device, so the interpreter's last flush at exit cannot fail
    on the closed pipe again."""
    with contextlib.suppress(OSError, ValueError):  # stdout without a file descriptor
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


if __name__ == "__main__":
    sys.exit(main())
