"""The results store of a sweep: one row per finished run, written the moment it finishes.

A sweep directory holds ``results.sqlite`` (the rows and the sweep definition) and
``sweep.toml`` (a copy of the definition file, for people).

Why SQLite and not Parquet parts
--------------------------------
The store must survive a sweep killed at any instant, resume without running a finished run
again, and never hold a run twice.

* **Durable appends.** Each row is its own SQLite transaction (write-ahead log,
  ``synchronous=FULL``): once :meth:`ResultStore.append` returns the row is on disk, and a
  process killed mid-write leaves the database at its last commit. Parquet is written a whole
  file at a time; a durable Parquet store needs one part file per run (or a buffer that loses
  runs on a crash), write-to-temporary-and-rename for atomicity, and thousands of tiny files
  for a large sweep that must be compacted later.
* **No duplicates by construction.** ``run_id`` is the primary key, so a second copy of a run
  cannot be written even by a buggy caller; with Parquet parts uniqueness rests on file naming
  and on every reader de-duplicating.
* **Cheap resume.** "Which runs are done?" is one indexed query.
* **Rows of any shape.** Scenarios report different figures and a failed run has none, so the
  figures are kept as JSON in one column and become DataFrame columns when read
  (:meth:`ResultStore.frame`); Parquet would need one schema for every part.
* **No new dependency**: ``sqlite3`` is in the standard library, and one file is easy to copy.

Every row carries a SHA-256 checksum of its columns, checked whenever rows are read, and so
does the stored sweep definition, checked whenever it is read, so a value changed outside
kilonet (an edited digit or seed, a damaged disk block) is refused instead of reported or
resumed. A store is created as a temporary file and linked into place complete, so a crash or
a full disk never leaves a half-made store that blocks the directory; a store created by a
sweep that stops before storing any run is removed again. A store is checked before anything is
written to it (a damaged one is refused without a byte written), and readers
(``kilonet report``) open it read-only, so they work on a read-only file system.

Its limits: one writer at a time (the sweep's parent process writes; workers only return
rows), guarded by a lock file (:func:`lock_directory`, taken before anything in the directory
is written) so two sweeps cannot fill one directory at once, and ``kilonet run --out``
cannot replace a directory a sweep holds (:mod:`kilonet.scenarios.output_dir` honours the same
lock); a reader of a store a sweep last wrote may leave SQLite's empty ``-wal``/``-shm`` files
beside it (the next sweep takes them over); and SQLite
locking is unreliable on network file systems, so keep the directory on a local disk (copy it
afterwards). :meth:`ResultStore.frame` hands the table to pandas, so ``frame().to_parquet()``
exports it for analyses that want Parquet.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sqlite3
import urllib.parse
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from kilonet.experiments.sweep import Sweep
from kilonet.scenarios.output_dir import LOCK_NAME, DirectoryInUse, hold_lock

__all__ = [
    "DB_NAME",
    "META_COLUMNS",
    "ResultStore",
    "RunRecord",
    "StoreError",
    "is_sweep_dir",
    "lock_directory",
    "write_atomically",
]

DB_NAME = "results.sqlite"
#: Schema 2 adds the per-row ``checksum``, schema 3 the ``sweep_checksum`` of the definition;
#: an older store is upgraded when opened for writing.
_SCHEMA_VERSION = "3"
#: Files SQLite keeps beside a store in write-ahead-log mode.
_SIDE_FILES = ("-wal", "-shm", "-journal")
#: Columns every row of :meth:`ResultStore.frame` has besides the swept parameters and figures.
META_COLUMNS = ("run_id", "seed", "status", "error", "wall_s", "worker", "finished_at")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS runs (
    run_id      TEXT PRIMARY KEY,
    cell        TEXT NOT NULL,
    seed        INTEGER NOT NULL,
    status      TEXT NOT NULL CHECK (status IN ('ok', 'failed')),
    error       TEXT,
    wall_s      REAL,
    worker      TEXT NOT NULL,
    finished_at TEXT NOT NULL,
    summary     TEXT,
    checksum    TEXT
);
"""
#: The stored columns of a row, in the order :func:`row_checksum` hashes them.
_ROW_COLUMNS = "run_id, cell, seed, status, error, wall_s, worker, finished_at, summary"


class StoreError(ValueError):
    """A directory is not a sweep store, holds a different sweep, or is in use."""


@dataclass(frozen=True)
class RunRecord:
    """One finished run, as a worker returns it and the store keeps it.

    Attributes
    ----------
    run_id, cell, seed
        The run (see :class:`kilonet.experiments.sweep.Run`).
    status : str
        ``"ok"`` or ``"failed"``.
    error : str or None
        For a failed run: the exception in one line (type, message, where it was raised).
    wall_s : float or None
        Wall-clock seconds the run took in its worker, including building the simulation;
        ``None`` if the worker was lost before it reported.
    worker : str
        ``host:pid`` of the process that ran it.
    finished_at : str
        UTC time the run finished (ISO 8601).
    summary : dict or None
        The run's summary figures (JSON-able); ``None`` for a failed run.
    """

    run_id: str
    cell: dict[str, Any]
    seed: int
    status: str
    error: str | None
    wall_s: float | None
    worker: str
    finished_at: str
    summary: dict[str, Any] | None


def is_sweep_dir(path: str | Path) -> bool:
    """Whether ``path`` holds a results store."""
    return (Path(path) / DB_NAME).is_file()


class ResultStore:
    """The results of one sweep in ``directory``; open with :meth:`create_or_open` or
    :meth:`open`.

    Every method raises :class:`StoreError` (one line naming the file) when the database cannot
    be read or written: a damaged file, a full disk, a row whose checksum fails.
    """

    def __init__(self, directory: Path, connection: sqlite3.Connection, schema: str) -> None:
        self.directory = directory
        self._db = connection
        self._schema = schema
        #: Whether :meth:`create_or_open` created the store (then :meth:`__exit__` removes it
        #: if the block fails before a run is stored).
        self.created = False

    # ---------------------------------------------------------------------------- opening

    @classmethod
    def create_or_open(
        cls, directory: str | Path, sweep: Sweep, *, source: str | None = None
    ) -> ResultStore:
        """Open the store of ``sweep`` in ``directory``, creating both if needed.

        ``source`` is the sweep file's text, copied to ``sweep.toml`` for people to read. A
        sweep that writes must hold :func:`lock_directory` first: the description, ``[report]``
        and ``sweep.toml`` of a store in use must not change under it.

        Raises
        ------
        StoreError
            If ``directory`` exists but is not a directory, is a non-empty directory without a
            store, holds a sweep whose runs differ from ``sweep``'s, or cannot be written.
        """
        directory = Path(directory)
        if directory.exists() and not directory.is_dir():
            raise StoreError(f"{directory} exists and is not a directory")
        created = False
        if not is_sweep_dir(directory):
            if directory.exists() and _foreign_entries(directory):
                raise StoreError(f"{directory} is not empty and holds no sweep results")
            try:
                directory.mkdir(parents=True, exist_ok=True)
                _remove_stale_creations(directory)
                _create_database(directory / DB_NAME, sweep)
                created = True
            except FileExistsError:
                pass  # another process created it at this instant: open theirs
            except (OSError, sqlite3.DatabaseError) as exc:
                raise StoreError(
                    f"{directory}: cannot create the results store ({_reason(exc)})"
                ) from None
        try:
            store = cls.open(directory)
        except BaseException:
            if created:  # e.g. a full disk refused the write-ahead log: no half-made store
                _remove_store(directory)
            raise
        store.created = created
        try:
            stored = store.sweep()
            differences = stored.differences(sweep)
            if differences:
                raise StoreError(
                    f"{directory} holds sweep {stored.name!r} with a different "
                    f"{', '.join(differences)}; use another --out directory"
                )
            # Same runs: the newer file's name, description and [report] take over.
            store._write_meta(sweep, source)
        except BaseException as exc:
            store.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return store

    def _write_meta(self, sweep: Sweep, source: str | None) -> None:
        text = json.dumps(sweep.to_dict())
        with self._guard("cannot write the sweep definition"), self._db:
            self._db.execute("INSERT OR REPLACE INTO meta VALUES ('sweep', ?)", (text,))
            self._db.execute(
                "INSERT OR REPLACE INTO meta VALUES ('sweep_checksum', ?)", (_text_checksum(text),)
            )
            if source is not None:
                self._db.execute("INSERT OR REPLACE INTO meta VALUES ('source', ?)", (source,))
        if source:
            try:
                write_atomically(self.directory / "sweep.toml", source)
            except OSError as exc:
                raise StoreError(
                    f"{self.directory / 'sweep.toml'}: cannot write ({_reason(exc)})"
                ) from None

    @classmethod
    def open(cls, directory: str | Path, *, read_only: bool = False) -> ResultStore:
        """Open an existing store, checked read-only before anything is written to it.

        For writing (the default), a store made by an older kilonet is upgraded in place: a
        schema-1 store's rows and a schema-1 or 2 store's definition are checksummed as they
        are. ``read_only`` opens it with SQLite's ``mode=ro`` (on a read-only file system, as
        immutable) and never writes; a schema-2 store is then read with its definition
        unchecked, a schema-1 store (rows without checksums) is refused.

        Raises
        ------
        StoreError
            If ``directory`` holds no store, a damaged one, or a store of an unknown schema.
        """
        directory = Path(directory)
        if not is_sweep_dir(directory):
            raise StoreError(f"{directory}: no sweep results here (no {DB_NAME})")
        path = directory / DB_NAME
        db = None
        try:
            _check_header(path)
            db = _connect_read_only(path)
            row = db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
            schema = row[0] if row is not None else None
            if schema not in ("1", "2", _SCHEMA_VERSION):
                raise StoreError(f"{path}: unknown store schema {schema!r}")
            if not read_only:
                db.close()
                db = None
                db = _connect(path)
                if schema != _SCHEMA_VERSION:
                    _upgrade(db, schema)
                    schema = _SCHEMA_VERSION
            elif schema == "1":
                raise StoreError(
                    f"{path}: made by an older kilonet (store schema 1); "
                    f"`kilonet sweep --resume --out {directory}` upgrades it"
                )
        except sqlite3.DatabaseError as exc:
            if db is not None:
                db.close()
            damaged = getattr(exc, "sqlite_errorname", "") in ("SQLITE_NOTADB", "SQLITE_CORRUPT")
            if damaged or str(exc).startswith("no such table"):
                raise _unreadable(path, _reason(exc)) from None
            raise StoreError(f"{path}: cannot open the store ({_reason(exc)})") from None
        except BaseException:
            if db is not None:
                db.close()
            raise
        return cls(directory, db, schema)

    def close(self) -> None:
        """Close the database (rows are already on disk)."""
        self._db.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        """Close; a store :meth:`create_or_open` created is removed again (with its
        ``sweep.toml``) if the block ends in an exception before any run was stored, so a
        sweep that could not start leaves no empty store behind."""
        remove = False
        if exc_type is not None and self.created:
            try:
                remove = self._fetch("SELECT COUNT(*) FROM runs")[0][0] == 0
            except StoreError:
                remove = False  # cannot tell: keep it
        self.close()
        if remove:
            _remove_store(self.directory)

    def lock(self) -> contextlib.AbstractContextManager[None]:
        """:func:`lock_directory` of this store's directory."""
        return lock_directory(self.directory)

    @contextmanager
    def _guard(self, doing: str) -> Iterator[None]:
        """SQLite's errors (damaged file, disk full) as one-line :class:`StoreError` s."""
        try:
            yield
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.directory / DB_NAME}: {doing} ({_reason(exc)})") from None

    def _fetch(self, query: str, params: Sequence[Any] = ()) -> list[tuple]:
        with self._guard("cannot read the store"):
            return self._db.execute(query, params).fetchall()

    # ---------------------------------------------------------------------------- reading

    def sweep(self) -> Sweep:
        """The sweep this store belongs to, checked against its checksum.

        Raises
        ------
        StoreError
            If the stored definition does not match its checksum (it was changed outside
            kilonet) or cannot be read.
        """
        meta = dict(self._fetch("SELECT key, value FROM meta WHERE key LIKE 'sweep%'"))
        text = meta.get("sweep")
        if self._schema == _SCHEMA_VERSION and (
            text is None or meta.get("sweep_checksum") != _text_checksum(text)
        ):
            raise StoreError(
                f"{self.directory / DB_NAME}: the stored sweep definition does not match its "
                "checksum (changed outside kilonet); restore the file from a copy or run the "
                "sweep into a new directory"
            )
        try:
            return Sweep.from_dict(json.loads(text))
        except (ValueError, KeyError, TypeError) as exc:
            raise StoreError(
                f"{self.directory / DB_NAME}: the stored sweep definition is damaged "
                f"({type(exc).__name__}: {exc})"
            ) from None

    def source(self) -> str:
        """The text of the sweep file the store was created from ('' if unknown)."""
        rows = self._fetch("SELECT value FROM meta WHERE key = 'source'")
        return rows[0][0] if rows else ""

    def finished_ids(self, *, include_failed: bool = True) -> set[str]:
        """``run_id`` of every stored run (of the successful ones only if not
        ``include_failed``)."""
        query = "SELECT run_id FROM runs"
        if not include_failed:
            query += " WHERE status = 'ok'"
        return {row[0] for row in self._fetch(query)}

    def counts(self) -> dict[str, int]:
        """Stored runs by status: ``{"ok": n, "failed": m}``."""
        out = {"ok": 0, "failed": 0}
        for status, n in self._fetch("SELECT status, COUNT(*) FROM runs GROUP BY status"):
            out[status] = n
        return out

    def records(self) -> list[RunRecord]:
        """Every stored run, in the order they finished, each checked against its checksum.

        Raises
        ------
        StoreError
            If a row does not match its checksum (it was changed outside kilonet).
        """
        records = []
        for *columns, checksum in self._fetch(
            f"SELECT {_ROW_COLUMNS}, checksum FROM runs ORDER BY rowid"
        ):
            if checksum != row_checksum(columns):
                raise StoreError(
                    f"{self.directory / DB_NAME}: the row of run {columns[0]} does not match "
                    "its checksum (changed outside kilonet); restore the file from a copy or "
                    "run the sweep into a new directory"
                )
            r = columns
            records.append(
                RunRecord(
                    run_id=r[0],
                    cell=json.loads(r[1]),
                    seed=r[2],
                    status=r[3],
                    error=r[4],
                    wall_s=r[5],
                    worker=r[6],
                    finished_at=r[7],
                    summary=json.loads(r[8]) if r[8] is not None else None,
                )
            )
        return records

    def frame(self) -> pd.DataFrame:
        """One row per stored run: the swept parameters (dotted names), the meta columns
        (``run_id, seed, status, error, wall_s, worker, finished_at``) and every summary figure.

        A figure whose name clashes with a parameter or meta column is prefixed ``summary.``;
        the summary's own ``seed`` (always equal to the run's) is dropped. Nested figures are
        flattened: a mapping ``{"phase_times_s": {"ids": 8.0}}`` becomes the column
        ``phase_times_s.ids``, and a list becomes its JSON text.
        """
        swept = self.sweep().swept
        taken = set(swept) | set(META_COLUMNS)
        rows = []
        for rec in self.records():
            row: dict[str, Any] = {k: rec.cell.get(k) for k in swept}
            row.update(
                run_id=rec.run_id,
                seed=rec.seed,
                status=rec.status,
                error=rec.error,
                wall_s=rec.wall_s,
                worker=rec.worker,
                finished_at=rec.finished_at,
            )
            for key, value in _flat_summary(rec.summary or {}).items():
                if key == "seed":
                    continue
                row[f"summary.{key}" if key in taken else key] = value
            rows.append(row)
        columns = [*swept, *META_COLUMNS]
        frame = pd.DataFrame(rows)
        if frame.empty:
            return pd.DataFrame(columns=columns)
        return frame[columns + [c for c in frame.columns if c not in columns]]

    # ---------------------------------------------------------------------------- writing

    def append(self, record: RunRecord) -> bool:
        """Store ``record`` durably with its checksum; returns whether it was written.

        A run already stored as ``ok`` is never overwritten (returns ``False``); a run stored
        as ``failed`` is replaced by its new result (a retry).

        Raises
        ------
        StoreError
            If the row cannot be written (e.g. the disk is full); the store keeps its last row.
        """
        summary = None if record.summary is None else json.dumps(record.summary)
        columns = (
            record.run_id,
            json.dumps(record.cell),
            record.seed,
            record.status,
            record.error,
            record.wall_s,
            record.worker,
            record.finished_at,
            summary,
        )
        with self._guard(f"cannot store run {record.run_id}"), self._db:
            cursor = self._db.execute(
                f"INSERT INTO runs ({_ROW_COLUMNS}, checksum) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
                "ON CONFLICT (run_id) DO UPDATE SET cell = excluded.cell, seed = excluded.seed, "
                "status = excluded.status, error = excluded.error, wall_s = excluded.wall_s, "
                "worker = excluded.worker, finished_at = excluded.finished_at, "
                "summary = excluded.summary, checksum = excluded.checksum "
                "WHERE runs.status != 'ok'",
                (*columns, row_checksum(columns)),
            )
        return cursor.rowcount == 1


def row_checksum(columns: Sequence[Any]) -> str:
    """SHA-256 (hex) of a row's stored columns (``run_id, cell, seed, status, error, wall_s,
    worker, finished_at, summary``, the JSON ones as their stored text).

    >>> row = ("ab12", '{"p": 0.1}', 3, "ok", None, 0.25, "h:1", "2026-01-01T00:00:00", "{}")
    >>> row_checksum(row) == row_checksum(list(row))
    True
    >>> row_checksum(row) == row_checksum(row[:5] + (0.26,) + row[6:])
    False
    """
    return _text_checksum(json.dumps(list(columns)))


def _text_checksum(text: str) -> str:
    """SHA-256 (hex) of ``text`` (UTF-8)."""
    return hashlib.sha256(text.encode()).hexdigest()


@contextmanager
def lock_directory(directory: str | Path) -> Iterator[None]:
    """Hold the lock of sweep directory ``directory`` (created if missing) while a sweep writes
    to it.

    The lock is an ``flock`` on ``.sweep.lock``, which the operating system releases when the
    process ends however it ends; the file is removed when the lock is given back, and so is
    the directory if this call created it and nothing else was put in it.

    Raises
    ------
    StoreError
        If another process holds it, or ``directory`` or the lock file cannot be created.
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise StoreError(f"{directory} exists and is not a directory")
    created = not directory.exists()
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StoreError(f"{directory}: cannot create the directory ({_reason(exc)})") from None
    path = directory / LOCK_NAME
    try:
        handle = _acquire(path)
    except BaseException:
        if created:
            _remove_if_empty(directory)
        raise
    try:
        yield
    finally:
        # Unlinked while still held, so a process waiting on the old file sees it is gone.
        path.unlink(missing_ok=True)
        os.close(handle)
        if created:
            _remove_if_empty(directory)


def _acquire(path: Path) -> int:
    """:func:`kilonet.scenarios.output_dir.hold_lock` with its errors as :class:`StoreError`."""
    try:
        return hold_lock(path)
    except DirectoryInUse as exc:
        raise StoreError(str(exc)) from None
    except OSError as exc:
        raise StoreError(f"{path}: cannot create the lock file ({_reason(exc)})") from None


def _remove_if_empty(directory: Path) -> None:
    with contextlib.suppress(OSError):
        directory.rmdir()


def _foreign_entries(directory: Path) -> list[str]:
    """Entries of ``directory`` that are not a sweep's own (lock file, unfinished store)."""
    return [
        p.name
        for p in directory.iterdir()
        if p.name != LOCK_NAME
        and not (
            p.name.startswith(f".{DB_NAME}.")
            and p.name.endswith((".tmp", *(f".tmp{side}" for side in _SIDE_FILES)))
        )
    ]


def _remove_stale_creations(directory: Path) -> None:
    """Remove the unfinished stores (``.results.sqlite.PID.tmp`` and its journal) that a
    process killed while creating one left behind: those whose process is gone."""
    for tmp in directory.glob(f".{DB_NAME}.*.tmp"):
        pid = tmp.name[len(DB_NAME) + 2 : -len(".tmp")]
        if not pid.isdigit() or _alive(int(pid)):
            continue
        _unlink_with_side_files(tmp)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists (signal 0 checks without sending anything)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _create_database(path: Path, sweep: Sweep) -> None:
    """Create the store at ``path`` with its schema and ``sweep``'s definition, complete or not
    at all: built in a temporary file (already in write-ahead-log mode, so opening it later
    changes nothing in it) and hard-linked into place.

    Raises
    ------
    FileExistsError
        If ``path`` appeared meanwhile (another sweep created it).
    OSError, sqlite3.DatabaseError
        If it cannot be written; nothing is left behind.
    """
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    _unlink_with_side_files(tmp)
    text = json.dumps(sweep.to_dict())
    try:
        db = sqlite3.connect(tmp, isolation_level="DEFERRED")
        try:
            db.execute("PRAGMA journal_mode = WAL")
            db.execute("PRAGMA synchronous = FULL")
            with db:
                db.executescript(_SCHEMA)
                db.execute("INSERT INTO meta VALUES ('schema', ?)", (_SCHEMA_VERSION,))
                db.execute("INSERT INTO meta VALUES ('sweep', ?)", (text,))
                db.execute("INSERT INTO meta VALUES ('sweep_checksum', ?)", (_text_checksum(text),))
        finally:
            db.close()  # the last connection: the log is folded into the file and removed
        if any(Path(f"{tmp}{side}").exists() for side in _SIDE_FILES):
            raise OSError(f"{tmp}: SQLite could not fold its log into the file")
        os.link(tmp, path)
    finally:
        _unlink_with_side_files(tmp)


def _unlink_with_side_files(path: Path) -> None:
    """Remove the database file ``path`` and SQLite's files beside it."""
    for suffix in ("", *_SIDE_FILES):
        Path(f"{path}{suffix}").unlink(missing_ok=True)


def _remove_store(directory: Path) -> None:
    """Remove the store of ``directory`` that this process created (its database, SQLite's
    files beside it and ``sweep.toml``); the caller holds the directory's lock."""
    _unlink_with_side_files(directory / DB_NAME)
    (directory / "sweep.toml").unlink(missing_ok=True)


def _upgrade(db: sqlite3.Connection, schema: str) -> None:
    """Bring an older store to the current schema: a schema-1 store gets the ``checksum``
    column, its rows checksummed as they are; both schema 1 and 2 get the definition's
    ``sweep_checksum``, of the definition as it is."""
    with db:
        if schema == "1":
            db.execute("ALTER TABLE runs ADD COLUMN checksum TEXT")
            rows = db.execute(f"SELECT rowid, {_ROW_COLUMNS} FROM runs").fetchall()
            for rowid, *columns in rows:
                db.execute(
                    "UPDATE runs SET checksum = ? WHERE rowid = ?", (row_checksum(columns), rowid)
                )
        (text,) = db.execute("SELECT value FROM meta WHERE key = 'sweep'").fetchone() or (None,)
        if text is not None:
            db.execute(
                "INSERT OR REPLACE INTO meta VALUES ('sweep_checksum', ?)", (_text_checksum(text),)
            )
        db.execute("UPDATE meta SET value = ? WHERE key = 'schema'", (_SCHEMA_VERSION,))
        db.execute("INSERT OR REPLACE INTO meta VALUES ('upgraded_from_schema', ?)", (schema,))


def _reason(exc: BaseException) -> str:
    """The one-line reason of an OS or SQLite error."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _flat_summary(summary: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Summary figures as one level of columns.

    >>> _flat_summary({"a": 1, "t": {"ids": 8.0, "seeds": 33.0}, "phases": ["ids", "seeds"]})
    {'a': 1, 't.ids': 8.0, 't.seeds': 33.0, 'phases': '["ids", "seeds"]'}
    """
    out: dict[str, Any] = {}
    for key, value in summary.items():
        if isinstance(value, dict):
            out.update(_flat_summary(value, f"{prefix}{key}."))
        elif isinstance(value, list):
            out[f"{prefix}{key}"] = json.dumps(value)
        else:
            out[f"{prefix}{key}"] = value
    return out


#: The first 16 bytes of every SQLite database file.
_SQLITE_MAGIC = b"SQLite format 3\x00"


def _check_header(path: Path) -> None:
    """Refuse, without opening it in SQLite (which would write its side files beside it), a
    file that is not a whole SQLite database: another kind of file, or one cut short of the
    size its header gives. An empty file passes (SQLite reads it as an empty database, which
    then has no tables).

    Raises
    ------
    StoreError
        If the file is not a whole database or cannot be read.
    """
    try:
        with open(path, "rb") as f:
            header = f.read(100)
            size = os.fstat(f.fileno()).st_size
    except OSError as exc:
        raise StoreError(f"{path}: cannot open the store ({_reason(exc)})") from None
    if not header:
        return
    if len(header) < 100 or not header.startswith(_SQLITE_MAGIC):
        raise _unreadable(path, "file is not a database")
    page_size = int.from_bytes(header[16:18], "big")
    page_size = 65536 if page_size == 1 else page_size
    pages = int.from_bytes(header[28:32], "big")
    pages_valid = header[24:28] == header[92:96]  # as SQLite decides whether to trust it
    if pages_valid and pages and size < pages * page_size:
        raise _unreadable(
            path, f"cut short: {size} bytes of the {pages * page_size} its header gives"
        )


def _unreadable(path: Path, reason: str) -> StoreError:
    return StoreError(
        f"{path}: not a readable sweep store ({reason}); move it away or use another --out "
        "directory"
    )


def _connect_read_only(path: Path) -> sqlite3.Connection:
    """A connection that cannot write ``path`` (SQLite ``mode=ro``). Where its directory
    cannot be written (a read-only file system) SQLite cannot make the shared-memory file a
    write-ahead-log database needs, and nobody can be writing the store there, so it is
    opened as immutable."""
    uri = f"file:{urllib.parse.quote(str(path.absolute()))}?mode=ro"
    db = sqlite3.connect(uri, uri=True)
    try:
        db.execute("SELECT 1 FROM sqlite_master LIMIT 1").fetchall()
    except sqlite3.DatabaseError as exc:
        db.close()
        cannot_open = getattr(exc, "sqlite_errorname", "") == "SQLITE_CANTOPEN"
        if not cannot_open or os.access(path.parent, os.W_OK):
            raise
        db = sqlite3.connect(f"{uri}&immutable=1", uri=True)
    return db


def _connect(path: Path) -> sqlite3.Connection:
    db = sqlite3.connect(path, isolation_level="DEFERRED")
    try:
        # WAL + FULL: a committed row survives the process being killed and a power cut.
        db.execute("PRAGMA journal_mode = WAL")
        db.execute("PRAGMA synchronous = FULL")
    except BaseException:
        db.close()
        raise
    return db


def write_atomically(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename, so readers see the old
    file or the whole new one, never a part."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
