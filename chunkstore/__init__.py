"""A resumable chunked run in a folder.

A long job (a Sobol' study, a Monte Carlo tuning) is split into chunks with keys;
each finished chunk is saved at once, so a run killed at any moment continues
where it stopped, and its result equals an uninterrupted run's bit for bit::

    from chunkstore import Store, compute

    def work(seed, n):                       # module level: picklable for worker processes
        rng = np.random.default_rng(seed)
        return {"y": rng.normal(size=n)}

    tasks = {f"part_{i:03d}": (i, 1000) for i in range(20)}
    with Store.open("out/mc", fingerprint={"job": "mc", "n": 1000}, resume=True) as store:
        for chunk in compute(store, work, tasks, executor="processes", workers=2, progress=True):
            total += chunk.arrays["y"].sum()  # reused chunks come from disk, checked

What the folder guarantees (``chunkstore.store``):

* **atomic writes**: a chunk file that exists is complete, even after kill -9;
* **a manifest** with the run's fingerprint: a folder holding another run is never
  mixed in, and a folder holding this run is only continued when asked to (``resume``);
* **checksums** (``chunks/SHA256SUMS``, readable by ``sha256sum -c``): a chunk changed
  or truncated on disk is named as such and computed again, never read as data;
* **a lock** (``chunkstore.lock``): a second run into the same folder stops at once
  with a message naming the run that holds it; the OS releases it when a run dies.

Where chunks run (``chunkstore.pool``): ``"inline"``; ``"processes"``, a local pool
whose workers die with their parent (also after kill -9); ``"dask"``, a
dask.distributed scheduler for more than one machine.

Errors are :class:`StoreError` (a ValueError) with one message for the end user;
this package imports nothing of the application.
"""

from chunkstore.compute import Chunk, compute
from chunkstore.errors import LockedError, StoreError, StoreWarning
from chunkstore.lock import FolderLock
from chunkstore.pool import EXECUTORS, check_executor, die_with_parent, execute, process_pool
from chunkstore.store import CHUNK_DIR, MANIFEST, SUMS, Store, differences

__all__ = [
    "CHUNK_DIR",
    "EXECUTORS",
    "MANIFEST",
    "SUMS",
    "Chunk",
    "FolderLock",
    "LockedError",
    "Store",
    "StoreError",
    "StoreWarning",
    "check_executor",
    "compute",
    "die_with_parent",
    "differences",
    "execute",
    "process_pool",
]
