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

A directory that a running sweep holds (its ``.sweep.lock``, see :func:`hold_lock`) is never
replaced or written into: it is refused when reserved, and ``replace`` takes that lock itself
for the swap, so a sweep starting meanwhile cannot lose its store. The target is made absolute
when reserved, so a run that changes its working directory still publishes where it was asked
to. A staging directory carries its process's id in its name
(``.NAME.PID.XXXXXXXX``); one whose process is gone (killed outright) is removed by the next
reservation beside it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import shutil
import tempfile
from pathlib import Path

from kilonet.errors import UserError

__all__ = [
    "LOCK_NAME",
    "DirectoryInUse",
    "OutputDir",
    "OutputDirError",
    "hold_lock",
    "lock_holder",
    "why_not_written",
]

#: The lock file a running sweep holds (``flock``) in its directory.
LOCK_NAME = ".sweep.lock"


class OutputDirError(UserError):
    """The output directory cannot be used; the message names it and says why."""


class DirectoryInUse(OutputDirError):
    """Another process holds the lock of a directory (a running sweep).

    Attributes
    ----------
    lock : Path
        The lock file.
    holder : str
        Who holds it, as the holder noted in the file (``"pid 1234"``).
    """

    def __init__(self, lock: Path, holder: str) -> None:
        self.lock = lock
        self.holder = holder
        super().__init__(
            f"{lock.parent} is in use by a running sweep ({holder}) holding its lock {lock}; "
            "let it finish or choose another --out"
        )


def hold_lock(path: Path) -> int:
    """Open (creating it if missing) and ``flock`` the lock file at ``path``; returns its file
    descriptor, which holds the lock until closed (the system releases it when the process
    ends, however it ends). The holder's pid is noted in the file for others' messages.

    Retries if the holder removed the file between our open and our lock (we would then hold a
    file nobody else can find).

    Raises
    ------
    DirectoryInUse
        If another process holds it.
    OSError
        If the file cannot be created (a missing directory, a read-only or full disk).
    """
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _note(fd)
            os.close(fd)
            raise DirectoryInUse(path, holder) from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if not same:
            os.close(fd)
            continue
        with contextlib.suppress(OSError):  # a full disk: the lock holds without its note
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()}\n".encode(), 0)
        return fd


def lock_holder(directory: Path) -> str | None:
    """Who holds the lock of ``directory`` (``"pid 1234"``), or ``None`` if nobody does; looks
    without creating or changing anything."""
    try:
        fd = os.open(directory / LOCK_NAME, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _note(fd)
    finally:
        os.close(fd)  # also gives back a lock we got: the file is a dead holder's
    return None


def _note(fd: int) -> str:
    return os.pread(fd, 100, 0).decode(errors="replace").strip() or "another process"


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
    DirectoryInUse
        If ``path`` is held by a running sweep (with or without ``replace``).
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
        if not str(path).strip():
            raise OutputDirError("--out needs a directory name, got an empty one")
        self._given = Path(path)  # as the user wrote it, for messages
        self.path = Path(path).absolute()
        self._replace = replace
        self._created: list[Path] = []
        self._published = False
        target, given = self.path, self._given
        if target.is_dir() and Path.cwd().resolve().is_relative_to(target.resolve()):
            raise OutputDirError(
                f"{given} is the current directory or holds it, which a run cannot replace; "
                "choose a new directory for --out (e.g. --out runs/one)"
            )
        if target.is_symlink() or target.exists():
            if not target.is_dir():
                raise OutputDirError(f"{given} exists and is not a directory")
            holder = lock_holder(target)
            if holder is not None:
                raise DirectoryInUse(given / LOCK_NAME, holder)
            if not replace and any(target.iterdir()):
                raise OutputDirError(
                    f"{given} already exists; choose another --out or pass --replace to "
                    "replace it whole"
                )
        self._make_parents(target.parent)
        _remove_stale_staging(target)
        try:
            self.staging = Path(
                tempfile.mkdtemp(prefix=f".{target.name}.{os.getpid()}.", dir=target.parent)
            )
            # mkdtemp makes it 0700; the run directory gets the mode mkdir would give it.
            self.staging.chmod(0o777 & ~_umask())
        except OSError as exc:
            self.discard()
            raise OutputDirError(
                f"--out {given}: cannot write in {given.parent} "
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

        A directory found at :attr:`path` now is replaced only with ``replace``, and then under
        its lock (:func:`hold_lock`), so a sweep cannot start in it during the swap; without
        ``replace`` only an empty one is (one that appeared during the run and holds
        something is refused).

        Raises
        ------
        DirectoryInUse
            If a sweep started in :attr:`path` during the run (the staging directory is
            removed).
        OutputDirError
            If the move fails, or a non-empty directory appeared at :attr:`path` during the
            run and ``replace`` is not set (the staging directory is removed).
        """
        target = self.path
        try:
            if self._replace and target.exists():
                self._swap_in(target)
            else:
                self.staging.replace(target)  # rename(2): onto an empty directory only
        except DirectoryInUse:
            self.discard()
            raise
        except OSError as exc:
            self.discard()
            if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
                raise OutputDirError(
                    f"{self._given} appeared during the run and is not empty; the run is not "
                    "written (pass --replace to replace it whole)"
                ) from None
            raise OutputDirError(
                f"cannot move the run into {self._given} ({exc.strerror})"
            ) from None
        self._published = True
        return target

    def _swap_in(self, target: Path) -> None:
        """Exchange the staging directory with the existing ``target`` under ``target``'s lock,
        then delete the old one (lock file and all)."""
        fd = hold_lock(target / LOCK_NAME)
        try:
            if not _exchange(self.staging, target):
                aside = Path(
                    tempfile.mkdtemp(prefix=f".{target.name}.{os.getpid()}.", dir=target.parent)
                )
                target.replace(aside / target.name)
                self.staging.replace(target)
                self.staging = aside
        except BaseException:
            (target / LOCK_NAME).unlink(missing_ok=True)  # the swap did not happen
            raise
        finally:
            os.close(fd)
        shutil.rmtree(self.staging)  # now the old directory

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


def _remove_stale_staging(target: Path) -> None:
    """Remove the staging directories of ``target`` (``.NAME.PID.XXXXXXXX`` beside it) whose
    process no longer exists: left by a run killed outright. A live process's, and anything
    not named exactly so, is kept."""
    pattern = re.compile(rf"\.{re.escape(target.name)}\.(\d+)\.[a-z0-9_]{{8}}")
    try:
        entries = list(target.parent.iterdir())
    except OSError:
        return
    for entry in entries:
        match = pattern.fullmatch(entry.name)
        if match is None or entry.is_symlink() or not entry.is_dir():
            continue
        if not _alive(int(match.group(1))):
            shutil.rmtree(entry, ignore_errors=True)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists (signal 0 checks without sending anything)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # someone else's, or not a pid we can ask about: keep it
    return True


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
