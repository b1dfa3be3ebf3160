"""Where chunks are computed: this process, a local process pool, or a dask cluster.

Each executor takes ``fn`` and ``tasks`` (key -> argument tuple) and yields
``(key, fn(*args))`` as tasks finish, in any order. On the first failing task it
cancels what has not started, still yields the tasks that had already finished
(so that they are saved), then raises that task's exception with a note naming it.

Each local worker gets its share of the cores for BLAS and OpenMP threads (cores // workers,
at least 1): a worker's own small matrix calls (scipy's filters, LAPACK) otherwise start a thread
per core in every worker, and those threads spin against the other workers.

The local pool's workers die with their parent: on Linux the kernel sends them
SIGKILL when the thread that started them ends (``prctl(PR_SET_PDEATHSIG)``),
elsewhere a thread in each worker exits when its parent is gone. A ``kill -9``
of the run therefore leaves no worker behind holding memory and cores.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import numbers
import os
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor, as_completed

from threadpoolctl import threadpool_limits

from chunkstore.errors import StoreError

EXECUTORS = ("inline", "processes", "dask")
_PR_SET_PDEATHSIG = 1  # linux/prctl.h
_WATCH_PERIOD_S = 0.5  # how often a worker without prctl looks for its parent
_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A ``ProcessPoolExecutor`` of ``workers`` fresh interpreters ("spawn": safe with the
    threads of tqdm, BLAS or OpenMP in the parent) that die with this process and share the
    cores' BLAS/OpenMP threads between them."""
    return ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=start_worker,
        initargs=(os.getpid(), max(1, (os.cpu_count() or 1) // workers)),
    )


def start_worker(parent_pid: int, threads: int) -> None:
    """Worker initializer: die with ``parent_pid``; at most ``threads`` BLAS/OpenMP threads."""
    die_with_parent(parent_pid)
    for name in _THREAD_VARIABLES:  # libraries loaded later (scipy's own OpenBLAS) read these
        os.environ[name] = str(threads)
    threadpool_limits(limits=threads)  # those already loaded; kept for the worker's life


def die_with_parent(parent_pid: int) -> None:
    """Worker initializer: end this process when ``parent_pid`` ends, even by SIGKILL."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            _watch_parent(parent_pid)
    else:
        _watch_parent(parent_pid)
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(1)


def _watch_parent(parent_pid: int) -> None:
    def watch():
        while os.getppid() == parent_pid:
            time.sleep(_WATCH_PERIOD_S)
        os._exit(1)

    threading.Thread(target=watch, name="chunkstore-parent-watch", daemon=True).start()


def check_executor(executor: str, workers: int | None = None, scheduler: str | None = None) -> None:
    """StoreError unless ``executor`` is known, ``workers`` is None or an integer >= 1, and a
    scheduler address is given exactly when the executor is "dask"."""
    if executor not in EXECUTORS:
        raise StoreError(f"unknown executor {executor!r} (known: {', '.join(EXECUTORS)})")
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, numbers.Integral) or workers < 1
    ):
        raise StoreError(f"workers must be an integer >= 1, got {workers!r}")
    if executor == "dask" and not scheduler:
        raise StoreError("executor 'dask' needs a scheduler address, e.g. tcp://127.0.0.1:8786")
    if scheduler and executor != "dask":
        raise StoreError(f"a scheduler address is only used by executor 'dask', not {executor!r}")


def execute(
    fn: Callable,
    tasks: Mapping[str, tuple],
    executor: str = "inline",
    *,
    workers: int | None = None,
    scheduler: str | None = None,
) -> Iterator[tuple[str, object]]:
    """Yield ``(key, fn(*tasks[key]))`` as the tasks finish (see the module docstring)."""
    check_executor(executor, workers, scheduler)
    return _EXECUTE[executor](fn, tasks, workers=workers, scheduler=scheduler)


def _inline(fn, tasks, **_) -> Iterator[tuple[str, object]]:
    for key, args in tasks.items():
        try:
            result = fn(*args)
        except Exception as e:
            e.add_note(f"[chunkstore] raised in chunk {key}")
            raise
        yield key, result


def _processes(fn, tasks, *, workers=None, **_) -> Iterator[tuple[str, object]]:
    if not tasks:
        return
    pool = process_pool(workers or os.cpu_count() or 1)
    try:
        futures = {pool.submit(fn, *args): key for key, args in tasks.items()}
        yield from _drain(futures, as_completed)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _dask(fn, tasks, *, scheduler=None, **_) -> Iterator[tuple[str, object]]:
    if not tasks:
        return
    if not scheduler:
        raise StoreError("executor 'dask' needs a scheduler address, e.g. tcp://127.0.0.1:8786")
    try:
        from distributed import Client
        from distributed import as_completed as dask_as_completed
    except ImportError:
        raise StoreError("executor 'dask' needs the dask[distributed] package") from None
    try:
        client = Client(scheduler, set_as_default=False, timeout="30s")
    except (OSError, TimeoutError) as e:
        raise StoreError(f"cannot reach the dask scheduler at {scheduler}: {e}") from None
    try:
        token = uuid.uuid4().hex[:8]
        futures = {client.submit(fn, *args, pure=False, key=f"chunk-{key}-{token}"): key
                   for key, args in tasks.items()}
        yield from _drain(futures, lambda fs: dask_as_completed(fs, loop=client.loop))
    finally:
        client.close()  # only our connection: the cluster is someone else's


def _drain(futures: dict, as_completed_) -> Iterator[tuple[str, object]]:
    yielded = set()
    for fut in as_completed_(list(futures)):
        try:
            result = fut.result()
        except Exception as e:
            e.add_note(f"[chunkstore] raised in chunk {futures[fut]}")
            for other in futures:
                other.cancel()
            for other in futures:
                if other not in yielded and other is not fut and _finished_ok(other):
                    yield futures[other], other.result()
            raise
        yielded.add(fut)
        yield futures[fut], result


def _finished_ok(fut) -> bool:
    if not fut.done() or fut.cancelled():
        return False
    try:
        fut.result()
    except Exception:
        return False
    return True


_EXECUTE = {"inline": _inline, "processes": _processes, "dask": _dask}
