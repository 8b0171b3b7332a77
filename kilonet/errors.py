"""The one exception class the command line reports to the user instead of a traceback.

Every error a user can fix by changing their input (a parameter key or value, a placement
file, a scenario name, an option, a program file) derives from :class:`UserError`; its message
is one line naming what is wrong and where (file, line, key). ``kilonet`` prints it after
``kilonet: error:`` and exits with status 2. Anything else is a bug and keeps its traceback.

A robot program's mistake that the kernel finds (a callback it cannot call, a yield it cannot
run, a kernel name the program took) is a :class:`ProgramFault`: it carries the program's file
and line, and is also the built-in exception a Python caller would expect
(:class:`ProgramTypeError`, :class:`ProgramRuntimeError`).
"""

from __future__ import annotations

import os

__all__ = [
    "ProgramFault",
    "ProgramRuntimeError",
    "ProgramTypeError",
    "UsageError",
    "UserError",
    "exception_line",
    "one_line",
    "read_text",
    "shown",
]


class UserError(Exception):
    """Input the user can fix; ``str()`` is one line saying what is wrong and where."""


class UsageError(UserError):
    """A command-line option or argument the user must change (exit status 2)."""


class ProgramFault(UserError):
    """A robot program's mistake found by the kernel, at ``file``:``line`` of the program.

    ``str()`` is ``file:line: message`` (the message alone when the place is not known). The
    arguments are kept in ``args``, so a copy made as SimPy makes one of a failed process's
    exception (``type(e)(*e.args)``) is the same fault.
    """

    def __init__(self, message: str, file: str | None = None, line: int | None = None) -> None:
        super().__init__(message, file, line)
        self.message, self.file, self.line = message, file, line

    def __str__(self) -> str:
        if self.file is None:
            return self.message
        return f"{self.file}:{self.line}: {self.message}"


class ProgramTypeError(ProgramFault, TypeError):
    """A :class:`ProgramFault` of the program's shape: a callback or attribute of the wrong
    kind, a yield of something other than a delay, a kernel name taken."""


class ProgramRuntimeError(ProgramFault, RuntimeError):
    """A :class:`ProgramFault` of what the program did while it ran (a delay it did not
    yield)."""


def one_line(text: str) -> str:
    """``text`` on one line: its non-blank lines, stripped, joined with `` | ``.

    Examples
    --------
    >>> one_line("first\\nsecond\\r\\n  third")
    'first | second | third'
    """
    return " | ".join(part.strip() for part in text.splitlines() if part.strip())


def shown(value: object, limit: int = 80) -> str:
    """``repr(value)`` for an error message about a program's value: on one line, cut to
    ``limit`` characters, and a note instead when the program's ``__repr__`` raises.

    Examples
    --------
    >>> shown("x"), shown(list(range(100)), 20)
    ("'x'", '[0, 1, 2, 3, 4, 5...')
    """
    try:
        text = one_line(repr(value))
    except BaseException as failed:  # any error of the program's __repr__
        return f"<{type(value).__name__}: repr() raised {type(failed).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def exception_line(exc: BaseException) -> str:
    """``Type: message`` of ``exc`` on one line: the lines of a multi-line message joined with
    `` | ``, the type alone for an empty message, and a note in place of the message when
    ``str()`` itself raises (text for an error report, which must not fail in turn).

    Examples
    --------
    >>> exception_line(ValueError("first\\nsecond\\r\\n  third"))
    'ValueError: first | second | third'
    >>> exception_line(GeneratorExit())
    'GeneratorExit'
    """
    name = type(exc).__name__
    try:
        text = one_line(str(exc))
    except BaseException as failed:  # any error of the program's __str__
        return f"{name} (its message cannot be shown: str() raised {type(failed).__name__})"
    return f"{name}: {text}" if text else name


def read_text(
    path: str | os.PathLike,
    error: type[UserError],
    what: str,
    *,
    encoding: str = "utf-8",
    newline: str | None = None,
) -> str:
    """The text of a file the user named, or ``error`` saying in one line why not.

    Parameters
    ----------
    path : str or path-like
        The file.
    error : UserError subclass
        What to raise.
    what : str
        What the file is for the message (``"run file"``: ``x.toml: no such run file``).
    encoding, newline
        As for :func:`open` (``newline=""`` for the :mod:`csv` module).

    Raises
    ------
    UserError
        ``error``, if the file is missing, a directory, unreadable or not text in ``encoding``.
    """
    try:
        with open(path, encoding=encoding, newline=newline) as f:
            return f.read()
    except FileNotFoundError:
        raise error(f"{os.fspath(path)}: no such {what}") from None
    except IsADirectoryError:
        raise error(f"{os.fspath(path)}: is a directory, not a {what}") from None
    except OSError as exc:
        raise error(f"{os.fspath(path)}: cannot read the {what} ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise error(f"{os.fspath(path)}: not a UTF-8 text file ({exc.reason})") from None
