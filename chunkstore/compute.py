"""Run the chunks of a job into a :class:`~chunkstore.store.Store`, resuming what is done."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from tqdm.auto import tqdm

from chunkstore.errors import StoreError
from chunkstore.pool import check_executor, execute
from chunkstore.store import Store


@dataclass(frozen=True, eq=False)
class Chunk:
    """One chunk of a run: its key, its arrays, and whether it came from disk."""

    key: str
    arrays: dict[str, np.ndarray]
    reused: bool


def compute(
    store: Store,
    fn: Callable[..., Mapping[str, np.ndarray]],
    tasks: Mapping[str, tuple],
    *,
    executor: str = "inline",
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = False,
    desc: str | None = None,
    unit: str = "chunk",
    sizes: Mapping[str, int] | None = None,
) -> Iterator[Chunk]:
    """Yield every chunk of ``tasks``: the finished ones from ``store`` (checksums checked),
    then the others as ``fn(*tasks[key])`` returns them, each saved before it is yielded
    (by a background thread, so the disk works while the next chunk computes).

    Parameters
    ----------
    fn :
        Computes one chunk: returns a mapping name -> array. Must be picklable for the
        ``"processes"`` and ``"dask"`` executors (a module-level function or a
        ``functools.partial`` of one).
    tasks :
        Chunk key (a file name) -> the arguments of ``fn``.
    executor : "inline" | "processes" | "dask"
        This process; a local pool of ``workers`` (default: every core) that dies
        with this process; a dask.distributed cluster at ``scheduler``.
    progress, desc, unit, sizes :
        A tqdm bar; ``sizes`` (key -> count, default 1) are the units of each chunk.

    A damaged chunk on disk is computed again with a :class:`StoreWarning` that says
    what was wrong with it. If ``fn`` raises, the chunks that had finished are saved
    and the exception gets a note saying that a rerun resumes from them.
    """
    _check_args(store, tasks, executor, workers, scheduler)
    sizes = {key: int(sizes[key]) if sizes else 1 for key in tasks}
    bar = tqdm(total=sum(sizes.values()), desc=desc, unit=unit, disable=not progress, dynamic_ncols=True)
    try:
        pending = {}
        for key, args in tasks.items():
            arrays = store.finished(key)  # one at a time: a run's chunks need not fit in memory twice
            if arrays is None:
                pending[key] = args
                continue
            bar.update(sizes[key])
            yield Chunk(key, arrays, True)
        yield from _computed(store, fn, pending, executor, workers, scheduler, bar, sizes)
    finally:
        bar.close()

def _computed(store, fn, pending, executor, workers, scheduler, bar, sizes) -> Iterator[Chunk]:
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="chunkstore-writer") as writer:
        writes = []
        try:
            for key, result in execute(fn, pending, executor, workers=workers, scheduler=scheduler):
                if not isinstance(result, Mapping) or not result:
                    raise StoreError(f"chunk {key}: the function returned {type(result).__name__}; "
                                     f"expected a non-empty mapping of name -> array")
                arrays = {str(k): np.asarray(v) for k, v in result.items()}
                writes.append(writer.submit(store.save, key, arrays))
                bar.update(sizes[key])
                yield Chunk(key, arrays, False)
            for w in writes:
                w.result()  # a failed write is an error of the run
        except Exception as e:
            for w in writes:  # let started writes finish, so what was computed is kept
                w.exception()
            e.add_note(f"[chunkstore] finished chunks are saved in {store.chunk_dir}; "
                       f"running again with resume computes only the missing ones")
            raise


def _check_args(store, tasks, executor, workers, scheduler) -> None:
    if not isinstance(store, Store):
        raise StoreError(f"store must be a chunkstore Store, got {type(store).__name__}")
    if not isinstance(tasks, Mapping):
        raise StoreError(f"tasks must map chunk keys to argument tuples, got {type(tasks).__name__}")
    for key in tasks:
        store.path(key)  # checks the key
    check_executor(executor, workers, scheduler)
