"""A folder of finished chunks: manifest, atomic writes, checksums.

Layout::

    FOLDER/manifest.json          format, the run's fingerprint, a layout note for people
    FOLDER/chunks/<key>.npz       one finished chunk: named float/int arrays
    FOLDER/chunks/SHA256SUMS      sha256 of every finished chunk (``sha256sum -c`` reads it)
    FOLDER/.lock                  held while a run writes here (:mod:`chunkstore.lock`)

A chunk is written under a temporary name and renamed over its final one
(``os.replace``, atomic on POSIX), then its checksum is appended to
``SHA256SUMS``: a chunk file that exists is complete, and one that is listed was
written by this store. A chunk is *finished* when it is listed and its bytes
still hash to the listed sum; anything else (killed between rename and record,
damaged on disk, edited by hand, a power loss before the disk wrote it) is
reported in words and computed again.

The fingerprint is what the chunks depend on (study, seeds, sizes, ...): a folder
whose manifest holds another fingerprint is never resumed, so results of two
different runs cannot be mixed.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from chunkstore.errors import StoreError, StoreWarning
from chunkstore.lock import FolderLock

FORMAT = "chunkstore/1"
MANIFEST = "manifest.json"
CHUNK_DIR = "chunks"
SUMS = "SHA256SUMS"
SUFFIX = ".npz"
_KEY = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_HASH_BLOCK = 1 << 22  # bytes read per hash update


class Store:
    """A locked run folder. Open it with :meth:`Store.open` (a context manager).

    Attributes
    ----------
    folder : Path
        The run folder.
    fingerprint : dict
        JSON-able identity of the run (what the chunks depend on).
    """

    def __init__(self, folder: Path, fingerprint: dict, lock: FolderLock):
        self.folder = folder
        self.fingerprint = fingerprint
        self._lock = lock
        self._sums = _read_sums(self.chunk_dir / SUMS)

    # -- opening ------------------------------------------------------------------
    @classmethod
    def open(
        cls,
        folder: str | os.PathLike,
        fingerprint: Mapping,
        *,
        resume: bool = False,
        layout: Mapping | None = None,
    ) -> Store:
        """Create or reopen the run folder ``folder`` and take its lock.

        Parameters
        ----------
        fingerprint :
            JSON-able mapping; a folder made with another one is refused.
        resume :
            A folder that already holds this run is continued only when set; without
            it such a folder is refused (nothing is deleted).
        layout :
            Free-form, JSON-able description of the chunks for a person reading the
            manifest (not compared).

        Raises
        ------
        StoreError
            The folder is a file, cannot be created or written, holds another run or
            a run without ``resume``; :class:`LockedError` if another process is
            writing into it.
        """
        folder = Path(folder)
        if folder.exists() and not folder.is_dir():
            raise StoreError(f"{folder}: exists and is not a folder")
        fp = _jsonable(dict(fingerprint), "fingerprint")
        lock = FolderLock(folder).acquire()
        try:
            _prepare(folder, fp, resume, layout)
            return cls(folder, fp, lock)
        except BaseException:
            lock.release()
            raise

    def close(self) -> None:
        """Release the folder's lock (chunks are already on disk)."""
        self._lock.release()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- chunks -------------------------------------------------------------------
    @property
    def chunk_dir(self) -> Path:
        return self.folder / CHUNK_DIR

    def path(self, key: str) -> Path:
        """File of chunk ``key``."""
        return self.chunk_dir / (_check_key(key) + SUFFIX)

    def __contains__(self, key: str) -> bool:
        """Whether chunk ``key`` was finished (listed); :meth:`load` checks its bytes."""
        return _check_key(key) + SUFFIX in self._sums and self.path(key).is_file()

    def keys(self) -> list[str]:
        """Keys of the listed chunks, sorted."""
        return sorted(k for k in (n[: -len(SUFFIX)] for n in self._sums) if k in self)

    def load(self, key: str) -> dict[str, np.ndarray]:
        """The arrays of a finished chunk, after checking its checksum.

        Raises :class:`StoreError` saying what happened if the chunk is missing,
        unlisted, or no longer holds the bytes that were written.
        """
        path = self.path(key)
        want = self._sums.get(path.name)
        if want is None:
            raise StoreError(f"{path}: not a finished chunk of this run (no checksum was recorded for it: "
                             f"the run stopped between writing it and recording it)")
        try:
            got, size = _sha256(path)
        except OSError as e:
            raise StoreError(f"{path}: cannot be read ({e.strerror or e})") from None
        if got != want:
            raise StoreError(
                f"{path}: damaged: its {size} bytes do not hash to the sha256 recorded when it was written "
                f"({got[:12]}... instead of {want[:12]}...); it was changed or truncated on disk afterwards"
            )
        try:
            with np.load(path, allow_pickle=False) as z:
                return {name: z[name] for name in z.files}
        except Exception as e:  # the bytes are ours, so this is a bug or a library change
            raise StoreError(f"{path}: written by this store but unreadable ({type(e).__name__}: {e})") from None

    def finished(self, key: str) -> dict[str, np.ndarray] | None:
        """:meth:`load` for a chunk that may be missing or damaged: None if it is not
        there, None with a :class:`StoreWarning` saying what was wrong if it is damaged
        (the caller then computes it again)."""
        if key not in self:
            return None
        try:
            return self.load(key)
        except StoreError as e:
            warnings.warn(f"{e}; computing it again", StoreWarning, stacklevel=2)
            return None

    def save(self, key: str, arrays: Mapping[str, np.ndarray]) -> Path:
        """Write chunk ``key`` atomically and record its checksum; returns its path.

        No fsync: a run's chunks can be GBs and waiting for the disk doubles its
        time; a chunk a power loss spoils fails its checksum and is computed again.
        """
        path = self.path(key)
        if not isinstance(arrays, Mapping) or not arrays:
            raise StoreError(f"chunk {key!r}: expected a non-empty mapping of name -> array")
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        try:
            with open(tmp, "wb") as f:
                hashed = _HashingWriter(f)  # hashed as written: no second pass over a chunk of GBs
                _write_npz(hashed, arrays)
            digest = hashed.sha256.hexdigest()
            os.replace(tmp, path)
            with open(self.chunk_dir / SUMS, "a") as f:
                f.write(f"{digest}  {path.name}\n")
        except OSError as e:
            tmp.unlink(missing_ok=True)
            raise StoreError(f"{path}: cannot be written ({e.strerror or e})") from None
        self._sums[path.name] = digest
        return path


# -- folder ----------------------------------------------------------------------------


def _prepare(folder: Path, fp: dict, resume: bool, layout) -> None:
    """Check (or start) the folder's manifest; never deletes a chunk."""
    manifest = folder / MANIFEST
    chunks = folder / CHUNK_DIR
    existing = sorted(chunks.glob("*" + SUFFIX)) if chunks.is_dir() else []
    if manifest.exists():
        try:
            old = json.loads(manifest.read_text())
        except (OSError, ValueError) as e:
            raise StoreError(f"{manifest}: not a readable run manifest ({e}); refusing to touch the folder") from None
        if not isinstance(old, dict) or old.get("format") != FORMAT:
            raise StoreError(
                f"{folder} holds a run of another layout ({manifest} says format "
                f"{old.get('format') if isinstance(old, dict) else None!r}, this version writes {FORMAT!r}); "
                f"choose another folder"
            )
        if not resume:
            raise StoreError(
                f"{folder} already holds a run ({len(existing)} finished chunks); resume it "
                f"(--resume) or choose another folder. Nothing was deleted."
            )
        diffs = differences(old.get("fingerprint", {}), fp)
        if diffs:
            raise StoreError(
                f"{folder} holds a different run, refusing to mix results: " + "; ".join(diffs)
                + ". Choose another folder, or rerun with the folder's settings."
            )
    elif existing:
        raise StoreError(
            f"{chunks} holds {len(existing)} chunk files but {manifest} is missing, so their origin "
            f"is unknown; choose another folder"
        )
    try:
        chunks.mkdir(exist_ok=True)
        for stale in chunks.glob(".*.tmp-*"):  # half-written files of a killed run (we hold the lock)
            stale.unlink(missing_ok=True)
        if not manifest.exists():
            _write_json_atomic(manifest, {"format": FORMAT, "fingerprint": fp, "layout": layout or {}})
        _compact_sums(chunks)
    except OSError as e:
        raise StoreError(f"{folder}: cannot write the run's files ({e.strerror or e})") from None


def differences(old: Mapping, new: Mapping) -> list[str]:
    """What differs between two fingerprints, one phrase per key."""
    diffs = []
    for key in list(new) + [k for k in old if k not in new]:
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        if isinstance(a, (dict, list)) or isinstance(b, (dict, list)) or len(repr(a)) + len(repr(b)) > 80:
            diffs.append(f"{key} differs")
        else:
            diffs.append(f"{key} is {a!r} there, {b!r} here")
    return diffs


def _check_key(key) -> str:
    if not isinstance(key, str) or not _KEY.match(key):
        raise StoreError(f"chunk key {key!r}: use letters, digits, '_', '.', '-' (a file name)")
    return key


def _jsonable(obj: dict, what: str) -> dict:
    try:
        return json.loads(json.dumps(obj, allow_nan=False))
    except (TypeError, ValueError) as e:
        raise StoreError(f"{what}: must be plain JSON (numbers, strings, lists, dicts): {e}") from None


def _write_npz(stream, arrays: Mapping[str, np.ndarray]) -> None:
    """What np.savez writes (a zip of .npy members, read back by np.load), to a stream that
    cannot seek (np.savez insists on a file name or a readable file)."""
    with zipfile.ZipFile(stream, mode="w", compression=zipfile.ZIP_STORED) as z:
        for name, value in arrays.items():
            with z.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asarray(value), allow_pickle=False)


class _HashingWriter:
    """A write-only stream that hashes what passes through it. It has no seek or tell, so
    zipfile (np.savez) writes it front to back and the hash is the file's."""

    def __init__(self, f):
        self._f = f
        self.sha256 = hashlib.sha256()

    def write(self, data) -> int:
        self.sha256.update(data)
        return self._f.write(data)

    def flush(self) -> None:
        self._f.flush()


def _sha256(path: Path) -> tuple[str, int]:
    h, size = hashlib.sha256(), 0
    with open(path, "rb") as f:
        while block := f.read(_HASH_BLOCK):
            h.update(block)
            size += len(block)
    return h.hexdigest(), size


def _read_sums(path: Path) -> dict[str, str]:
    """file name -> sha256 from a SHA256SUMS file; a later line wins, a torn line is skipped."""
    sums = {}
    try:
        text = path.read_text()
    except FileNotFoundError:
        return sums
    for line in text.splitlines():
        digest, sep, name = line.partition("  ")
        if sep and len(digest) == 64 and all(c in "0123456789abcdef" for c in digest) and name.endswith(SUFFIX):
            sums[name] = digest
    return sums


def _compact_sums(chunks: Path) -> None:
    """Rewrite SHA256SUMS with one line per chunk file that exists (``sha256sum -c`` passes)."""
    path = chunks / SUMS
    if not path.exists():
        path.touch()
        return
    sums = {n: d for n, d in _read_sums(path).items() if (chunks / n).is_file()}
    tmp = path.with_name(f".{SUMS}.tmp-{os.getpid()}")
    tmp.write_text("".join(f"{d}  {n}\n" for n, d in sorted(sums.items())))
    os.replace(tmp, path)


def _write_json_atomic(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=2)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
