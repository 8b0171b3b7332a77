"""Run directories written whole: checked before a run starts, put in place in one step.

:class:`OutputDir` reserves the directory a run will write to before the simulation starts, so
an unusable ``--out`` (under a file, under ``/proc``, in a read-only folder, already there) is
refused at once instead of after the run. The run writes into a staging directory beside the
target; :meth:`OutputDir.publish` moves it into place whole. A directory that already exists
is never merged into: it is refused, or with ``replace`` swapped for the new one — atomically
where the system can exchange two paths (Linux ``renameat2(RENAME_EXCHANGE)``), else moved
aside in one rename and the new one moved in with the next — and then deleted. An existing
*empty* directory holds nothing to lose and counts as free. Whatever goes wrong (or if the run
is never published), :meth:`OutputDir.discard` removes the staging directory and every parent
directory the reservation created.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from pathlib import Path

from kilonet.errors import UserError

__all__ = ["OutputDir", "OutputDirError", "why_not_written"]


class OutputDirError(UserError):
    """The output directory cannot be used; the message names it and says why."""


def why_not_written(exc: OSError, directory: str | os.PathLike) -> str:
    """Why a file could not be made in ``directory``, in words for the user: the system's
    reason, except where it misleads. A virtual file system (``/proc``, ``/sys``) answers
    "No such file or directory" for a directory that plainly exists.

    Examples
    --------
    >>> why_not_written(OSError(errno.ENOENT, "No such file or directory"), "/")
    'the file system there takes no new files, e.g. /proc or /sys'
    >>> why_not_written(OSError(errno.ENOSPC, "No space left on device"), "/")
    'No space left on device'
    """
    if exc.errno == errno.ENOENT and Path(directory).is_dir():
        return "the file system there takes no new files, e.g. /proc or /sys"
    return exc.strerror or str(exc)


class OutputDir:
    """The directory a run writes to, reserved before the run.

    Parameters
    ----------
    path : str or Path
        Where the run directory goes.
    replace : bool
        Replace an existing non-empty directory (whole, never merged); without it, one is an
        error.

    Attributes
    ----------
    path : Path
        The target.
    staging : Path
        The directory to write into; it becomes ``path`` on :meth:`publish`.

    Raises
    ------
    OutputDirError
        If ``path`` is empty, is the current directory or one that holds it, exists and is
        not a directory, exists and is not empty (without
        ``replace``), lies under something that is not a directory, or its parent cannot be
        created or written to.

    Examples
    --------
    >>> import tempfile
    >>> root = Path(tempfile.mkdtemp())
    >>> with OutputDir(root / "runs" / "one") as out:
    ...     _ = (out.staging / "summary.json").write_text("{}")
    ...     _ = out.publish()
    >>> sorted(p.name for p in (root / "runs" / "one").iterdir())
    ['summary.json']
    >>> try:
    ...     OutputDir(root / "runs" / "one")
    ... except OutputDirError as exc:
    ...     print(str(exc).replace(str(root), "ROOT"))
    ROOT/runs/one already exists; choose another --out or pass --replace to replace it whole
    """

    def __init__(self, path: str | os.PathLike, *, replace: bool = False) -> None:
        self.path = Path(path)
        self._created: list[Path] = []
        self._published = False
        target = self.path
        if not str(path).strip():
            raise OutputDirError("--out needs a directory name, got an empty one")
        if target.is_dir() and Path.cwd().resolve().is_relative_to(target.resolve()):
            raise OutputDirError(
                f"{target} is the current directory or holds it, which a run cannot replace; "
                "choose a new directory for --out (e.g. --out runs/one)"
            )
        if target.is_symlink() or target.exists():
            if not target.is_dir():
                raise OutputDirError(f"{target} exists and is not a directory")
            if not replace and any(target.iterdir()):
                raise OutputDirError(
                    f"{target} already exists; choose another --out or pass --replace to "
                    "replace it whole"
                )
        self._make_parents(target.parent)
        try:
            self.staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
            # mkdtemp makes it 0700; the run directory gets the mode mkdir would give it.
            self.staging.chmod(0o777 & ~_umask())
        except OSError as exc:
            self.discard()
            raise OutputDirError(
                f"--out {target}: cannot write in {target.parent} "
                f"({why_not_written(exc, target.parent)})"
            ) from None

    def _make_parents(self, parent: Path) -> None:
        missing = []
        base = parent
        while not base.exists():
            missing.append(base)
            base = base.parent
        if not base.is_dir():
            raise OutputDirError(f"cannot write under {base}: it is not a directory")
        for directory in reversed(missing):
            try:
                directory.mkdir()
            except OSError as exc:
                self.discard()
                raise OutputDirError(f"cannot create {directory} ({exc.strerror})") from None
            self._created.append(directory)

    def publish(self) -> Path:
        """Put the staging directory in place of :attr:`path` and return the path.

        Raises
        ------
        OutputDirError
            If the move fails (the staging directory is removed).
        """
        target = self.path
        try:
            if target.exists():
                if not _exchange(self.staging, target):
                    aside = Path(tempfile.mkdtemp(prefix=f".{target.name}.old.", dir=target.parent))
                    target.replace(aside / target.name)
                    self.staging.replace(target)
                    self.staging = aside
                shutil.rmtree(self.staging)  # now the old directory
            else:
                self.staging.replace(target)
        except OSError as exc:
            self.discard()
            raise OutputDirError(f"cannot move the run into {target} ({exc.strerror})") from None
        self._published = True
        return target

    def discard(self) -> None:
        """Remove the staging directory and the parents the reservation created."""
        staging = getattr(self, "staging", None)
        if staging is not None and not self._published:
            shutil.rmtree(staging, ignore_errors=True)
        if not self._published:
            for directory in reversed(self._created):
                try:
                    directory.rmdir()
                except OSError:
                    break  # something else was put there meanwhile: keep it
            self._created = []

    def __enter__(self) -> OutputDir:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.discard()


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap the paths ``a`` and ``b`` in one atomic step (Linux ``renameat2`` with
    ``RENAME_EXCHANGE``); ``False`` where the system or file system cannot.

    Raises
    ------
    OSError
        If the exchange is supported but fails (e.g. permission denied).
    """
    import ctypes

    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    done = renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if done == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), os.fspath(b))


def _umask() -> int:
    """The process's umask (reading it means setting it: set it straight back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
