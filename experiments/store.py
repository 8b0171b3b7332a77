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

Its limits: one writer at a time (the sweep's parent process writes; workers only return
rows), guarded by a lock file so two sweeps cannot fill one directory at once; and SQLite
locking is unreliable on network file systems, so keep the directory on a local disk (copy it
afterwards). :meth:`ResultStore.frame` hands the table to pandas, so ``frame().to_parquet()``
exports it for analyses that want Parquet.
"""

from __future__ import annotations

import fcntl
import json
import os
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from experiments.sweep import Sweep

__all__ = [
    "DB_NAME",
    "META_COLUMNS",
    "ResultStore",
    "RunRecord",
    "StoreError",
    "is_sweep_dir",
    "write_atomically",
]

DB_NAME = "results.sqlite"
_LOCK_NAME = ".sweep.lock"
_SCHEMA_VERSION = "1"
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
    summary     TEXT
);
"""


class StoreError(ValueError):
    """A directory is not a sweep store, holds a different sweep, or is in use."""


@dataclass(frozen=True)
class RunRecord:
    """One finished run, as a worker returns it and the store keeps it.

    Attributes
    ----------
    run_id, cell, seed
        The run (see :class:`experiments.sweep.Run`).
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
    :meth:`open`."""

    def __init__(self, directory: Path, connection: sqlite3.Connection) -> None:
        self.directory = directory
        self._db = connection

    # ---------------------------------------------------------------------------- opening

    @classmethod
    def create_or_open(
        cls, directory: str | Path, sweep: Sweep, *, source: str | None = None
    ) -> ResultStore:
        """Open the store of ``sweep`` in ``directory``, creating both if needed.

        ``source`` is the sweep file's text, copied to ``sweep.toml`` for people to read.

        Raises
        ------
        StoreError
            If ``directory`` exists but is not a directory, is a non-empty directory without a
            store, or holds a sweep whose runs differ from ``sweep``'s.
        """
        directory = Path(directory)
        if directory.exists() and not directory.is_dir():
            raise StoreError(f"{directory} exists and is not a directory")
        if is_sweep_dir(directory):
            store = cls.open(directory)
            stored = store.sweep()
            differences = stored.differences(sweep)
            if differences:
                store.close()
                raise StoreError(
                    f"{directory} holds sweep {stored.name!r} with a different "
                    f"{', '.join(differences)}; use another --out directory"
                )
            # Same runs: the newer file's name, description and [report] take over.
            store._write_meta(sweep, source)
            return store
        if directory.exists() and any(directory.iterdir()):
            raise StoreError(f"{directory} is not empty and holds no sweep results")
        directory.mkdir(parents=True, exist_ok=True)
        store = cls(directory, _connect(directory / DB_NAME))
        with store._db:
            store._db.executescript(_SCHEMA)
            store._db.execute("INSERT INTO meta VALUES ('schema', ?)", (_SCHEMA_VERSION,))
        store._write_meta(sweep, source)
        return store

    def _write_meta(self, sweep: Sweep, source: str | None) -> None:
        with self._db:
            self._db.execute(
                "INSERT OR REPLACE INTO meta VALUES ('sweep', ?)", (json.dumps(sweep.to_dict()),)
            )
            if source is not None:
                self._db.execute("INSERT OR REPLACE INTO meta VALUES ('source', ?)", (source,))
        if source:
            write_atomically(self.directory / "sweep.toml", source)

    @classmethod
    def open(cls, directory: str | Path) -> ResultStore:
        """Open an existing store.

        Raises
        ------
        StoreError
            If ``directory`` holds no store or a store of another schema.
        """
        directory = Path(directory)
        if not is_sweep_dir(directory):
            raise StoreError(f"{directory}: no sweep results here (no {DB_NAME})")
        db = _connect(directory / DB_NAME)
        try:
            row = db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
        except sqlite3.DatabaseError as exc:
            db.close()
            raise StoreError(f"{directory / DB_NAME}: not a sweep store ({exc})") from None
        if row is None or row[0] != _SCHEMA_VERSION:
            db.close()
            raise StoreError(f"{directory / DB_NAME}: unknown store schema {row}")
        return cls(directory, db)

    def close(self) -> None:
        """Close the database (rows are already on disk)."""
        self._db.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the directory's lock while a sweep writes to it.

        The operating system releases it when the process ends, however it ends.

        Raises
        ------
        StoreError
            If another process holds it.
        """
        with open(self.directory / _LOCK_NAME, "a+") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.seek(0)
                holder = handle.read().strip() or "another process"
                raise StoreError(
                    f"{self.directory} is in use by a running sweep ({holder})"
                ) from None
            handle.seek(0)
            handle.truncate()
            handle.write(f"pid {os.getpid()}\n")
            handle.flush()
            try:
                yield
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)

    # ---------------------------------------------------------------------------- reading

    def sweep(self) -> Sweep:
        """The sweep this store belongs to."""
        (text,) = self._db.execute("SELECT value FROM meta WHERE key = 'sweep'").fetchone()
        return Sweep.from_dict(json.loads(text))

    def source(self) -> str:
        """The text of the sweep file the store was created from ('' if unknown)."""
        row = self._db.execute("SELECT value FROM meta WHERE key = 'source'").fetchone()
        return row[0] if row else ""

    def finished_ids(self, *, include_failed: bool = True) -> set[str]:
        """``run_id`` of every stored run (of the successful ones only if not
        ``include_failed``)."""
        query = "SELECT run_id FROM runs"
        if not include_failed:
            query += " WHERE status = 'ok'"
        return {row[0] for row in self._db.execute(query)}

    def counts(self) -> dict[str, int]:
        """Stored runs by status: ``{"ok": n, "failed": m}``."""
        out = {"ok": 0, "failed": 0}
        for status, n in self._db.execute("SELECT status, COUNT(*) FROM runs GROUP BY status"):
            out[status] = n
        return out

    def records(self) -> list[RunRecord]:
        """Every stored run, in the order they finished."""
        rows = self._db.execute(
            "SELECT run_id, cell, seed, status, error, wall_s, worker, finished_at, summary "
            "FROM runs ORDER BY rowid"
        )
        return [
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
            for r in rows
        ]

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
        """Store ``record`` durably; returns whether it was written.

        A run already stored as ``ok`` is never overwritten (returns ``False``); a run stored
        as ``failed`` is replaced by its new result (a retry).
        """
        summary = None if record.summary is None else json.dumps(record.summary)
        with self._db:
            cursor = self._db.execute(
                "INSERT INTO runs (run_id, cell, seed, status, error, wall_s, worker, "
                "finished_at, summary) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?) "
                "ON CONFLICT (run_id) DO UPDATE SET cell = excluded.cell, seed = excluded.seed, "
                "status = excluded.status, error = excluded.error, wall_s = excluded.wall_s, "
                "worker = excluded.worker, finished_at = excluded.finished_at, "
                "summary = excluded.summary WHERE runs.status != 'ok'",
                (
                    record.run_id,
                    json.dumps(record.cell),
                    record.seed,
                    record.status,
                    record.error,
                    record.wall_s,
                    record.worker,
                    record.finished_at,
                    summary,
                ),
            )
        return cursor.rowcount == 1


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


def _connect(path: Path) -> sqlite3.Connection:
    db = sqlite3.connect(path, isolation_level="DEFERRED")
    # WAL + FULL: a committed row survives the process being killed and a power cut.
    db.execute("PRAGMA journal_mode = WAL")
    db.execute("PRAGMA synchronous = FULL")
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
