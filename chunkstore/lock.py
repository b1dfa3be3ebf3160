"""One run per folder: an advisory lock on ``FOLDER/.lock``.

The lock is an ``flock`` (``msvcrt.locking`` on Windows) on an open file, so the
operating system drops it when the process ends, however it ends (kill -9
included): there is never a stale lock to delete by hand. The file records who
holds it (pid, host, start time) for the message a second run gets.

Locks are re-entrant within a process: a command that holds a folder while it
writes its report may call a function that takes the same folder's lock again.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path

from chunkstore.errors import LockedError, StoreError

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None
    import msvcrt

LOCK_FILE = ".lock"

_held: dict[str, list] = {}  # realpath of the folder -> [open file, depth]
_guard = threading.Lock()


class FolderLock:
    """Context manager holding the lock of ``folder`` (created if missing).

    Raises :class:`LockedError` at once, naming the holder, if another process
    holds it.
    """

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        self._key = None

    def acquire(self) -> FolderLock:
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise StoreError(f"{self.folder}: cannot create the folder ({e.strerror or e})") from None
        key = os.path.realpath(self.folder)
        with _guard:
            if key in _held:
                _held[key][1] += 1
                self._key = key
                return self
            path = Path(key) / LOCK_FILE
            try:
                f = open(path, "a+")
            except OSError as e:
                raise StoreError(f"{self.folder}: cannot write in the folder ({e.strerror or e})") from None
            if not _try_lock(f):
                f.seek(0)
                holder = f.read().strip() or "another process"
                f.close()
                raise LockedError(
                    f"{self.folder}: another run is writing into this folder ({holder}); "
                    f"wait for it to finish, or choose another folder"
                )
            f.seek(0)
            f.truncate()
            f.write(f"pid {os.getpid()} on {socket.gethostname()}, since "
                    f"{time.strftime('%Y-%m-%d %H:%M:%S')}\n")
            f.flush()
            _held[key] = [f, 1]
            self._key = key
        return self

    def release(self) -> None:
        if self._key is None:
            return
        with _guard:
            entry = _held[self._key]
            entry[1] -= 1
            if entry[1] == 0:
                del _held[self._key]
                _unlock(entry[0])
                entry[0].close()
        self._key = None

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _try_lock(f) -> bool:
    try:
        if fcntl is not None:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        else:
            f.seek(0)
            msvcrt.locking(f.fileno(), msvcrt.LK_NBLCK, 1)
    except OSError:
        return False
    return True


def _unlock(f) -> None:
    if fcntl is not None:
        fcntl.flock(f.fileno(), fcntl.LOCK_UN)
    else:
        f.seek(0)
        msvcrt.locking(f.fileno(), msvcrt.LK_UNLCK, 1)
