"""Run a sweep's missing runs in parallel and store each one as it finishes.

The same loop drives a local process pool (the default) and a Dask ``distributed`` cluster
(``scheduler="tcp://host:8786"``): both are :class:`concurrent.futures.Executor` s, every run is
one :func:`execute_run` task, and the parent process writes each result to the
:class:`~kilonet.experiments.store.ResultStore` the moment it arrives, so an interrupted sweep loses
at most the runs in flight. Running the same sweep into the same directory again runs only the
runs that are not stored.

A run that raises is stored as failed with its error and the sweep goes on. A progress bar on
stderr shows runs done, failures and the time left.

Interrupts: Ctrl-C (SIGINT) and SIGTERM stop the sweep cleanly: pending runs are cancelled, local
workers are terminated, the stored rows stay, and :class:`KeyboardInterrupt` reaches the caller.
A sweep killed outright (``kill -9``) leaves no process behind: each local worker ends itself
when the sweep's process ends, and the fork server and resource tracker follow. On a Dask
cluster that has had no workers for ``no_workers_timeout_s`` the sweep stops with
:class:`SweepAborted` instead of waiting for ever.

Local workers are started with the ``forkserver`` method, so, as with any non-``fork``
multiprocessing, a script that calls :func:`run_sweep` must do so under
``if __name__ == "__main__":`` (the ``kilonet`` command and notebooks need nothing).
"""

from __future__ import annotations

import concurrent.futures as cf
import datetime as dt
import json
import multiprocessing
import os
import select
import signal
import socket
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from kilonet.experiments.store import ResultStore, RunRecord, StoreError, lock_directory
from kilonet.experiments.sweep import Run, Sweep

__all__ = [
    "SchedulerAddressError",
    "SweepAborted",
    "SweepOutcome",
    "WorkerWatch",
    "check_scheduler_address",
    "default_workers",
    "execute_run",
    "run_sweep",
]


class SweepAborted(RuntimeError):
    """The sweep could not go on (a worker process died, the cluster is unreachable); the runs
    stored so far are kept and the same command resumes."""


class SchedulerAddressError(ValueError):
    """A Dask scheduler address that cannot name a scheduler; the message says why."""


@dataclass(frozen=True)
class SweepOutcome:
    """What one call of :func:`run_sweep` did.

    Attributes
    ----------
    total : int
        Runs in the sweep.
    already_stored : int
        Runs found in the store and not run again.
    ok, failed : int
        Runs finished by this call, by status.
    directory : Path
        The sweep directory.
    """

    total: int
    already_stored: int
    ok: int
    failed: int
    directory: Path


def default_workers() -> int:
    """Processes of the local pool when none is asked for: the CPUs this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def execute_run(run: Run) -> RunRecord:
    """Run one simulation and return its record; any exception becomes a failed record.

    This is the task a worker process (local or Dask) executes.
    """
    from kilonet import scenarios

    started = time.perf_counter()
    summary: dict[str, Any] | None = None
    error: str | None = None
    try:
        result = scenarios.run(scenarios.get(run.scenario), run.overrides, seed=run.seed)
        summary = json.loads(json.dumps(result.summary, default=_to_builtin))
    except Exception as exc:  # a failing run is data for the sweep, not the end of it
        error = describe_error(exc)
    return RunRecord(
        run_id=run.run_id,
        cell=run.cell,
        seed=run.seed,
        status="ok" if error is None else "failed",
        error=error,
        wall_s=round(time.perf_counter() - started, 4),
        worker=f"{socket.gethostname()}:{os.getpid()}",
        finished_at=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        summary=summary,
    )


def describe_error(exc: BaseException) -> str:
    """An exception in one line: type, first line of its message, and where it was raised.

    >>> try:
    ...     1 / 0
    ... except ZeroDivisionError as exc:
    ...     describe_error(exc).split(" (at ")[0]
    'ZeroDivisionError: division by zero'
    """
    message = str(exc).strip().splitlines()
    text = f"{type(exc).__name__}: {message[0]}" if message else type(exc).__name__
    frames = traceback.extract_tb(exc.__traceback__)
    if frames:
        last = frames[-1]
        where = "/".join(Path(last.filename).parts[-2:])
        text += f" (at {where}:{last.lineno})"
    return text


def _to_builtin(value: Any) -> Any:
    """JSON fallback for numpy scalars and arrays in a summary."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"summary value {value!r} of type {type(value).__name__} is not JSON-able")


def run_sweep(
    sweep: Sweep,
    directory: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    retry_failed: bool = False,
    progress: bool = True,
    source: str | None = None,
    no_workers_timeout_s: float = 300.0,
) -> SweepOutcome:
    """Run every run of ``sweep`` that ``directory`` does not hold yet.

    Parameters
    ----------
    sweep : Sweep
        What to run.
    directory : path
        The sweep directory (created if missing; resumed if it holds this sweep).
    workers : int, optional
        Local worker processes (default: :func:`default_workers`). Not used with ``scheduler``.
    scheduler : str, optional
        Address of a Dask ``distributed`` scheduler; its workers run the runs.
    retry_failed : bool
        Run again the runs stored as failed (their rows are replaced).
    progress : bool
        Show the progress bar on stderr.
    source : str, optional
        The sweep file's text, copied into a new directory.
    no_workers_timeout_s : float
        With ``scheduler``: seconds the cluster may have no workers at all before the sweep
        stops (:class:`SweepAborted`; ``math.inf``: wait for workers however long).

    Returns
    -------
    SweepOutcome

    Raises
    ------
    kilonet.experiments.store.StoreError
        If ``directory`` holds another sweep or is in use.
    SchedulerAddressError
        If ``scheduler`` cannot be a scheduler's address (checked before anything starts).
    SweepAborted
        If a local worker process died or could not start, the scheduler is unreachable or
        had no workers for ``no_workers_timeout_s``, or the store cannot take a row (full
        disk).
    KeyboardInterrupt
        On Ctrl-C or SIGTERM, after cancelling the pending runs; finished runs stay stored.
    """
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be at least 1, not {workers}")
    if not no_workers_timeout_s > 0:
        raise ValueError(f"no_workers_timeout_s must be > 0, not {no_workers_timeout_s}")
    if scheduler is not None:
        check_scheduler_address(scheduler)
    runs = sweep.runs()
    with (
        lock_directory(directory),
        ResultStore.create_or_open(directory, sweep, source=source) as store,
    ):
        store.records()  # every stored row checked against its checksum before resuming
        done = store.finished_ids(include_failed=not retry_failed)
        todo = [r for r in runs if r.run_id not in done]
        ok = failed = 0
        # the bar counts every stored run, so it starts at the runs kept from before
        failed_before = 0 if retry_failed else store.counts()["failed"]
        if todo:
            with (
                _sigterm_as_interrupt(),
                _progress_bar(len(runs), len(runs) - len(todo), failed_before, progress) as bar,
                _executor(workers, scheduler, len(todo)) as (executor, count_workers),
            ):
                futures = _submit_all(executor, todo)
                pending = set(futures)
                watch = WorkerWatch(no_workers_timeout_s)
                while pending:
                    done, pending = cf.wait(pending, _POLL_S, cf.FIRST_COMPLETED)
                    for future in sorted(done, key=lambda f: futures[f][0]):
                        record = _record_of(future, futures[future][1])
                        _store(store, record)
                        if record.status == "ok":
                            ok += 1
                        else:
                            failed += 1
                        bar.set_postfix_str(f"{failed_before + failed} failed", refresh=False)
                        bar.update()
                    if count_workers is not None and pending:
                        now = time.monotonic()
                        watch = watch.observe(count_workers(), now)
                        if watch.expired(now):
                            raise SweepAborted(
                                f"the Dask cluster at {scheduler} has had no workers for "
                                f"{watch.timeout_s:g} s ({len(pending)} runs waiting); start "
                                "workers, then run the same command to resume"
                            )
        return SweepOutcome(len(runs), len(runs) - len(todo), ok, failed, Path(directory))


#: Seconds between looks at the cluster while no run finishes.
_POLL_S = 1.0


@dataclass(frozen=True)
class WorkerWatch:
    """How long a cluster has had no workers: the state of the sweep's no-workers rule.

    Attributes
    ----------
    timeout_s : float
        Seconds without any worker after which the sweep gives up.
    empty_since_s : float or None
        Monotonic time (s) of the first look that found no worker since the last look that
        found one; ``None`` while workers are there.

    Examples
    --------
    >>> w = WorkerWatch(10.0).observe(0, now_s=100.0)
    >>> w.expired(109.0), w.expired(110.0)
    (False, True)
    >>> w.observe(2, now_s=105.0).expired(200.0)  # a worker came back: the wait starts over
    False
    """

    timeout_s: float
    empty_since_s: float | None = None

    def observe(self, workers: int, now_s: float) -> WorkerWatch:
        """The watch after a look at ``now_s`` found ``workers`` workers."""
        if workers > 0:
            return WorkerWatch(self.timeout_s)
        if self.empty_since_s is None:
            return WorkerWatch(self.timeout_s, now_s)
        return self

    def expired(self, now_s: float) -> bool:
        """Whether at ``now_s`` the cluster has had no workers for ``timeout_s``."""
        return self.empty_since_s is not None and now_s - self.empty_since_s >= self.timeout_s


def _submit_all(executor: cf.Executor, todo: list[Run]) -> dict[cf.Future, tuple[int, Run]]:
    """Submit every run; each future maps to (submission index, run)."""
    try:
        return {executor.submit(execute_run, run): (i, run) for i, run in enumerate(todo)}
    except (BrokenProcessPool, EOFError, OSError) as exc:
        raise SweepAborted(
            f"the worker processes could not start ({type(exc).__name__}: {exc}); nothing was run"
        ) from None


def _store(store: ResultStore, record: RunRecord) -> None:
    """Append ``record``; a store that cannot take it (a full disk) ends the sweep."""
    try:
        store.append(record)
    except StoreError as exc:
        raise SweepAborted(
            f"{exc}; the runs stored so far are kept: fix that, then run the same command to resume"
        ) from None


def _record_of(future: cf.Future, run: Run) -> RunRecord:
    """The record a finished future carries; a task the executor itself lost (a Dask worker
    killed while running it) is a failed run, a broken local pool ends the sweep."""
    try:
        return future.result()
    except BrokenProcessPool as exc:
        raise SweepAborted(
            f"a worker process died unexpectedly ({exc}); finished runs are stored, "
            "run the same command to resume"
        ) from None
    except Exception as exc:
        return RunRecord(
            run_id=run.run_id,
            cell=run.cell,
            seed=run.seed,
            status="failed",
            error=describe_error(exc),
            wall_s=None,
            worker="lost",
            finished_at=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            summary=None,
        )


@contextmanager
def _progress_bar(total: int, initial: int, failed: int, enabled: bool) -> Iterator[tqdm]:
    with tqdm(
        total=total,
        initial=initial,
        unit="run",
        file=sys.stderr,
        disable=not enabled,
        dynamic_ncols=True,
        bar_format="{l_bar}{bar}| {n}/{total} runs{postfix} [{elapsed}<{remaining}]",
        postfix=f"{failed} failed",
    ) as bar:
        yield bar


@contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """While the sweep runs, SIGTERM stops it like Ctrl-C does (so workers are cleaned up)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def _executor(
    workers: int | None, scheduler: str | None, runs: int
) -> Iterator[tuple[cf.Executor, Callable[[], int] | None]]:
    """The executor and, for a cluster, a function counting its workers now."""
    if scheduler is not None:
        with _dask_executor(scheduler) as (executor, count_workers):
            yield executor, count_workers
    else:
        with _local_executor(min(workers or default_workers(), runs)) as executor:
            yield executor, None


@contextmanager
def _local_executor(workers: int) -> Iterator[cf.Executor]:
    # forkserver: workers start from a clean process with the scenarios already imported (the
    # parent may hold threads and open files, which fork would copy), and start fast.
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["scenarios", "kilonet.experiments.runner"])
    _start_forkserver()
    executor = cf.ProcessPoolExecutor(
        max_workers=workers,
        mp_context=context,
        initializer=_prepare_worker,
        initargs=(os.getpid(),),
    )
    try:
        yield executor
    except BaseException:
        _terminate_local(executor)
        raise
    executor.shutdown(wait=True)


def _start_forkserver() -> None:
    """Start the fork server (if it is not running) without the working directory on its
    ``sys.path``.

    The server is a ``python -c`` process, so Python puts the working directory first on its
    path, and the preloaded packages would be imported from a folder there named like one of
    them (``scenarios/``, ``experiments/``) instead of kilonet's; every worker would then die.
    ``PYTHONSAFEPATH`` (Python >= 3.11) tells the new interpreter not to add it; the sweep's
    own environment is restored at once.
    """
    from multiprocessing import forkserver

    previous = os.environ.get("PYTHONSAFEPATH")
    os.environ["PYTHONSAFEPATH"] = "1"
    try:
        forkserver.ensure_running()
    finally:
        if previous is None:
            del os.environ["PYTHONSAFEPATH"]
        else:
            os.environ["PYTHONSAFEPATH"] = previous


def _prepare_worker(parent_pid: int) -> None:
    """Set up a local worker process of the sweep running in process ``parent_pid``.

    Workers leave Ctrl-C to the parent, which cancels the sweep and terminates them. tqdm (the
    runs' disabled progress bars) would otherwise create a named multiprocessing lock here that
    a terminated worker never releases; a thread lock serves a worker's single thread. A worker
    ends itself when the sweep's process ends however it ends (``kill -9`` included), see
    :func:`_die_with`; once the workers are gone the fork server and the resource tracker end
    too, as they do when their last client closes.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    tqdm.set_lock(threading.RLock())
    _die_with(parent_pid)


def _die_with(pid: int, poll_s: float = 1.0) -> None:
    """Start a daemon thread that ends this process the moment process ``pid`` has ended.

    A worker's parent is the fork server, not the sweep, so ``PR_SET_PDEATHSIG`` and
    ``os.getppid`` cannot see the sweep die. On Linux the thread waits on a pidfd of ``pid``
    (readable when it ends; no polling, immune to pid reuse); elsewhere it polls every
    ``poll_s`` seconds whether ``pid`` still exists.
    """
    try:
        pidfd: int | None = os.pidfd_open(pid)
    except ProcessLookupError:
        os._exit(1)  # the sweep ended before this worker started
    except (AttributeError, OSError):  # not Linux >= 5.3
        pidfd = None

    def watch() -> None:
        if pidfd is not None:
            select.select([pidfd], [], [])
        else:
            while True:
                time.sleep(poll_s)
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:
                    continue
        os._exit(1)

    threading.Thread(target=watch, name="kilonet-sweep-watch", daemon=True).start()


def _terminate_local(executor: cf.ProcessPoolExecutor) -> None:
    """Cancel pending runs and end the workers now rather than after their current run.

    The pool's manager thread is then waited for (at most :data:`_MANAGER_JOIN_S`): left
    running, it closes its wake-up pipe while the interpreter's exit wakes it, which prints
    ``Exception ignored ... Bad file descriptor`` after the sweep's message. The executor
    forgets the thread on its first shutdown, so it is taken first.
    """
    manager = executor._executor_manager_thread
    if hasattr(executor, "terminate_workers"):  # Python >= 3.14
        executor.terminate_workers()
    else:
        processes = list((executor._processes or {}).values())
        executor.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            if process.is_alive():
                process.terminate()
        for process in processes:
            process.join()
    if manager is not None:  # the workers are gone, so it ends at once
        manager.join(_MANAGER_JOIN_S)


#: Seconds to wait for a terminated pool's manager thread (it ends once its workers have).
_MANAGER_JOIN_S = 10.0


def check_scheduler_address(address: str) -> None:
    """Refuse an address that cannot name a Dask scheduler, before anything starts (Dask's
    client would print a traceback from its event loop and never exit): it must be
    ``[scheme://]host:port`` with a scheme Dask knows and a port from 1 to 65535 (an
    ``inproc://`` address is taken as it is).

    Raises
    ------
    SweepAborted
        If Dask ``distributed`` is not installed.
    SchedulerAddressError
        Saying what is wrong with ``address``.

    Examples
    --------
    >>> check_scheduler_address("tcp://127.0.0.1:8786")
    >>> try:
    ...     check_scheduler_address("tcp://127.0.0.1:notaport")
    ... except SchedulerAddressError as exc:
    ...     print(str(exc).split(";")[0])
    --scheduler 'tcp://127.0.0.1:notaport': the port 'notaport' is not a number
    """
    try:
        from distributed.comm.addressing import parse_address
        from distributed.comm.registry import get_backend
    except ImportError:
        raise SweepAborted(
            "--scheduler needs Dask distributed: pip install 'kilonet[cluster]'"
        ) from None

    def refuse(why: str) -> SchedulerAddressError:
        return SchedulerAddressError(
            f"--scheduler {address!r}: {why}; give [tcp://]HOST:PORT, e.g. tcp://127.0.0.1:8786"
        )

    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
    except ValueError as exc:
        raise refuse(str(exc)) from None
    if scheme == "inproc":
        return
    host, sep, port = location.rpartition(":")
    if not sep or not host.strip("[]"):
        raise refuse("it needs a host and a port")
    if not port.isdigit():
        raise refuse(f"the port {port!r} is not a number")
    if not 1 <= int(port) <= 65535:
        raise refuse(f"the port {port} is not from 1 to 65535")


@contextmanager
def _dask_executor(scheduler: str) -> Iterator[tuple[cf.Executor, Callable[[], int]]]:
    from distributed import Client

    try:
        client = Client(scheduler, set_as_default=False)
    except OSError as exc:
        raise SweepAborted(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    executor = client.get_executor(pure=False)

    def count_workers() -> int:
        # the client's copy of the scheduler's state, refreshed every couple of seconds
        return len(client.scheduler_info().get("workers", {}))

    try:
        yield executor, count_workers
    except BaseException:
        executor.shutdown(wait=False)  # cancels the runs not finished yet
        client.close()
        raise
    executor.shutdown(wait=True)
    client.close()
