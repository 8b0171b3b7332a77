"""The one exception class the command line reports to the user instead of a traceback.

Every error a user can fix by changing their input (a parameter key or value, a placement
file, a scenario name, an option, a program file) derives from :class:`UserError`; its message
is one line naming what is wrong and where (file, line, key). ``kilonet`` prints it after
``kilonet: error:`` and exits with status 2. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import os

__all__ = ["UserError", "read_text"]


class UserError(Exception):
    """Input the user can fix; ``str()`` is one line saying what is wrong and where."""


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
