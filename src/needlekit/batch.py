"""Batch execution: one interface for running many independent tasks in this process, on a
local process pool, or on a Dask cluster.

Studies (direction sweeps, many cases, many trials) are lists of independent tasks. They
run through a :class:`concurrent.futures.Executor`, so the same code scales from a laptop
to a cluster:

- ``"serial"``: one after the other in this process (debuggable, no pickling);
- ``"process"``: a local process pool (``spawn`` start method, safe with numba's and
  BLAS's threads);
- ``"dask"``: a Dask ``distributed`` client, either connected to a running scheduler
  (``address="tcp://host:8786"``) or to a local cluster it starts and stops itself
  (``pip install 'needlekit[dask]'``).

Tasks that need heavy shared inputs (a patient's distance fields) should not carry them:
pass a small picklable *source* and let each worker build the input once through
:func:`worker_cached`.

Examples
--------
>>> with open_executor("serial") as ex:
...     sorted(as_completed_indexed(ex, abs, [-2, 3]))
[(0, 2), (1, 3)]
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any

from needlekit.errors import InvalidInputError, raise_if_interrupt

__all__ = [
    "EXECUTORS",
    "SerialExecutor",
    "as_completed_indexed",
    "clear_worker_cache",
    "executor_workers",
    "open_executor",
    "worker_builds",
    "worker_cached",
    "worker_name",
]

#: Names accepted by :func:`open_executor`.
EXECUTORS = ("serial", "process", "dask")
#: How long to wait for a Dask scheduler to answer (s): an address that does not answer
#: is an input error, said at once rather than after Dask's own 30 s.
SCHEDULER_TIMEOUT_S: float = 5.0


class SerialExecutor(Executor):
    """An executor that runs every task at submission, in the calling thread.

    A task's exception is stored in the returned future, as with a pool; Ctrl-C
    (``KeyboardInterrupt``, or the ``SystemError`` a compiled kernel turns it into:
    :func:`~needlekit.errors.is_interrupt`) is not a task's failure and stops the caller
    at once, as ``KeyboardInterrupt``.
    """

    #: Tasks run in the caller's process: they need not be picklable.
    in_process = True

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        """Run ``fn(*args, **kwargs)`` now.

        Parameters
        ----------
        fn : callable
        *args, **kwargs
            Its arguments.

        Returns
        -------
        concurrent.futures.Future
            Already done.
        """
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:
            raise_if_interrupt(exc)  # Ctrl-C inside a compiled kernel (a SystemError)
            fut.set_exception(exc)
        return fut


#: How long a stopped worker process gets to end after SIGTERM before it is killed (s).
STOP_GRACE_S: float = 0.5


def _ignore_sigint() -> None:
    """A pool worker leaves Ctrl-C to the main process (a terminal sends it to the whole
    process group): the main process stops the workers, and no worker prints a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """End a process pool at once: queued tasks cancelled, running ones abandoned, every
    worker terminated (killed if it does not end within :data:`STOP_GRACE_S`)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    # a stopped worker makes the pool's manager thread fail every pending task; on Python
    # 3.11 it raises (and prints a thread traceback) at a task already cancelled: give
    # those a fresh future to fail instead (list() copies the dict under the GIL)
    for item in list((getattr(pool, "_pending_work_items", None) or {}).values()):
        if item.future.cancelled():
            item.future = Future()
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(STOP_GRACE_S)
    # the pool's manager thread closes its wake-up pipe as it ends; at the interpreter's
    # exit, concurrent.futures wakes every manager still registered, and on Python 3.11 a
    # pipe the manager closes between the waker's check and its write prints "Exception
    # ignored ... Bad file descriptor" and a traceback after the command's one line (seen
    # on a Ctrl-C early in a study with workers; a join's grace narrows the window, it
    # cannot close it): a closed pipe means the manager is ending, nothing is left to wake
    _wakeup_tolerates_a_closed_pipe(getattr(pool, "_executor_manager_thread_wakeup", None))
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown() forgets it
    pool.shutdown(wait=False, cancel_futures=True)
    if manager is not None:  # let it end first, bounded
        manager.join(STOP_GRACE_S)


def _wakeup_tolerates_a_closed_pipe(waker) -> None:
    """Make ``waker.wakeup()`` (a process pool's ``_ThreadWakeup``) a no-op once its pipe
    is closed, instead of an ``OSError`` in the interpreter's exit hook."""
    if waker is None or not callable(getattr(waker, "wakeup", None)):
        return
    wakeup = waker.wakeup

    def safe_wakeup() -> None:
        try:
            wakeup()
        except (OSError, ValueError):  # closed meanwhile: the manager has ended
            pass

    waker.wakeup = safe_wakeup


def _check_workers(workers) -> int | None:
    if workers is None:
        return None
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InvalidInputError("workers", f"expected a whole number >= 1, got {workers!r}")
    return workers


def _capped(workers: int | None) -> int | None:
    """More local workers than cores only share the cores (each worker holds its own copy
    of the anatomy): capped at the CPU count, with a warning."""
    cores = os.cpu_count() or 1
    if workers is not None and workers > cores:
        logging.getLogger(__name__).warning(
            "%d workers asked for, this machine has %d cores: using %d", workers, cores, cores
        )
        return cores
    return workers


#: Dask's HTTP routes emptied: its nodes start an HTTP server whatever they are told
#: (scheduler, nanny and worker), and these settings leave it serving nothing (no
#: dashboard, metrics, health or JSON pages) unless a dashboard is asked for.
_NO_HTTP_ROUTES = {
    "distributed.scheduler.http.routes": [],
    "distributed.worker.http.routes": [],
    "distributed.nanny.http.routes": [],
}


@contextmanager
def _local_dask_cluster(workers: int | None, dashboard: bool):
    """A local Dask cluster no one else can use: every listener on 127.0.0.1, its comms
    under TLS with credentials made for this run alone (``Security.temporary()``: a fresh
    CA and certificate, in memory), so another local process cannot connect or submit;
    no dashboard or other HTTP page unless ``dashboard``."""
    import dask
    from distributed import Client, LocalCluster
    from distributed.security import Security

    try:
        security = Security.temporary()
    except ImportError:
        raise InvalidInputError(
            "executor",
            "a local Dask cluster runs under TLS, which needs the cryptography package: "
            "pip install 'needlekit[dask]'",
        ) from None
    with (
        dask.config.set({} if dashboard else _NO_HTTP_ROUTES),
        LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            security=security,
            # the scheduler's HTTP server: Dask's usual port when asked for, else any
            dashboard_address="127.0.0.1:8787" if dashboard else "127.0.0.1:0",
            scheduler_kwargs={"dashboard": dashboard},
            silence_logs=logging.WARNING,
        ) as cluster,
        Client(cluster) as client,
    ):
        if dashboard:
            logging.getLogger(__name__).warning("Dask dashboard: %s", client.dashboard_link)
        yield client


@contextmanager
def open_executor(
    kind: str = "serial",
    *,
    workers: int | None = None,
    address: str | None = None,
    dashboard: bool = False,
) -> Iterator[Executor]:
    """An executor of the given kind, shut down on leaving the ``with`` block.

    Parameters
    ----------
    kind : {"serial", "process", "dask"}
    workers : int, optional
        Worker processes (default: the machine's CPU count; ignored for ``"serial"`` and
        for a remote Dask scheduler). More than the CPU count is capped to it, with a
        warning.
    address : str, optional
        Dask scheduler address; without one, ``"dask"`` starts a local cluster of
        ``workers`` single-threaded processes, on 127.0.0.1 under TLS with credentials
        made for this run (no other process can use it).
    dashboard : bool
        Serve the local Dask cluster's dashboard (its link is logged); without it the
        cluster's nodes serve no HTTP page.

    Yields
    ------
    concurrent.futures.Executor

    Raises
    ------
    InvalidInputError
        Unknown kind, bad worker count, Dask (or, for a local cluster, cryptography) not
        installed, or no scheduler answering at ``address`` within
        :data:`SCHEDULER_TIMEOUT_S` (named ``--scheduler``).
    """
    workers = _check_workers(workers)
    if kind != "serial" and address is None:
        workers = _capped(workers)
    if kind == "serial":
        yield SerialExecutor()
    elif kind == "process":
        pool = ProcessPoolExecutor(
            max_workers=workers or os.cpu_count() or 1,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_ignore_sigint,
        )
        try:
            yield pool
        except BaseException:  # Ctrl-C, or an error: stop the workers now, not after their tasks
            _stop_pool(pool)
            raise
        pool.shutdown(wait=True)
    elif kind == "dask":
        try:
            from distributed import Client
        except ImportError as exc:
            raise InvalidInputError(
                "executor", "'dask' needs Dask distributed: pip install 'needlekit[dask]'"
            ) from exc
        # Dask logs its start-up at INFO on its own logger: follow the caller's verbosity
        dask_log = logging.getLogger("distributed")
        old_level = dask_log.level
        if logging.getLogger().getEffectiveLevel() > logging.INFO:
            dask_log.setLevel(logging.WARNING)
        try:
            if address is not None:
                with _connect(Client, address) as client:
                    yield client.get_executor()
            else:
                with _local_dask_cluster(workers, dashboard) as client:
                    yield client.get_executor()
        finally:
            dask_log.setLevel(old_level)
    else:
        raise InvalidInputError("executor", f"expected one of {', '.join(EXECUTORS)}, got {kind!r}")


def _connect(client_cls, address: str):
    """A client of the scheduler at ``address``; one input error when it does not answer."""
    try:
        return client_cls(address, timeout=SCHEDULER_TIMEOUT_S)
    except (OSError, ValueError, TypeError) as exc:  # unreachable, refused, malformed
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InvalidInputError(
            "--scheduler", f"no Dask scheduler answers at {address!r} ({why})"
        ) from None


def executor_workers(executor: Executor | None) -> int:
    """How many tasks an executor runs at once (its worker processes or Dask threads).

    Parameters
    ----------
    executor : concurrent.futures.Executor or None
        None and in-process executors run one task at a time.

    Returns
    -------
    int
    """
    if executor is None or getattr(executor, "in_process", False):
        return 1
    client = getattr(executor, "_client", None)  # Dask's ClientExecutor
    if client is not None:
        return max(1, sum(client.nthreads().values()))
    return max(1, int(getattr(executor, "_max_workers", 1) or 1))


def as_completed_indexed(
    executor: Executor, fn: Callable, items: Iterable
) -> Iterator[tuple[int, Any]]:
    """Submit ``fn(item)`` for every item and yield ``(index, result)`` as tasks finish.

    Parameters
    ----------
    executor : concurrent.futures.Executor
    fn : callable
        Must be picklable (a module-level function) for process and Dask executors.
    items : iterable
        Task arguments (picklable).

    Yields
    ------
    tuple of (int, object)
        The item's position and ``fn``'s result, in completion order. A task's exception
        propagates when its result is reached; the remaining tasks are cancelled. An
        in-process executor (:class:`SerialExecutor`) runs each task when the previous
        result has been taken, so a caller sees (and can keep) every result as it comes.
    """
    if getattr(executor, "in_process", False):
        for i, item in enumerate(items):
            yield i, executor.submit(fn, item).result()
        return
    futures = {executor.submit(fn, item): i for i, item in enumerate(items)}
    try:
        for fut in as_completed(futures):
            yield futures[fut], fut.result()
    finally:
        for fut in futures:
            fut.cancel()


_CACHE: dict = {}
#: Re-entrant: a value's build may itself use the cache (a scenario's problem and, inside
#: it, the patient's prepared anatomy).
_CACHE_LOCK = threading.RLock()
#: What this process built through :func:`worker_cached`, in order: (kind, seconds).
_BUILDS: list = []


def _kind(key) -> str:
    return key[0] if isinstance(key, tuple) and key and isinstance(key[0], str) else str(key)


def worker_cached(key, build: Callable[[], Any]) -> Any:
    """The value built for ``key`` in this process, building it on first use.

    Workers of a pool live across tasks, so a task that needs a heavy input (a scenario's
    scene and distance fields) builds it once per worker, not once per task.

    Parameters
    ----------
    key : hashable
        Identifies the input (e.g. a scenario path and its overrides).
    build : callable
        Makes the value; called at most once per key and process.

    Returns
    -------
    object
    """
    with _CACHE_LOCK:
        if key in _CACHE:
            return _CACHE[key]
        t0 = time.perf_counter()
        value = build()
        _CACHE[key] = value
        _BUILDS.append((_kind(key), time.perf_counter() - t0))
        return value


def worker_builds() -> list[tuple[str, float]]:
    """What :func:`worker_cached` built in this process, in order.

    A build that uses the cache itself is listed after the builds it caused, each with its
    own seconds (which include those of the inner builds).

    Returns
    -------
    list of (str, float)
        Per build, the kind (a key's first item when it is a string, e.g.
        ``"ScenarioSource"``, ``"MedradCase"``) and the seconds it took.
    """
    with _CACHE_LOCK:
        return list(_BUILDS)


def worker_name() -> str:
    """This process, as ``host:pid`` (unique over the machines of a cluster).

    Returns
    -------
    str
    """
    return f"{socket.gethostname()}:{os.getpid()}"


def clear_worker_cache() -> None:
    """Forget every value :func:`worker_cached` holds in this process.

    Returns
    -------
    None
    """
    with _CACHE_LOCK:
        _CACHE.clear()
        _BUILDS.clear()
