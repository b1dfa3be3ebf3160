"""User-facing errors.

Every problem a user can cause (a bad file, a typo in a TOML key, an impossible
parameter) is raised as a :class:`UserError`. The CLI turns it into one line on
stderr and a non-zero exit code; it never shows a traceback for these.
"""

from __future__ import annotations

import difflib
import os
import tempfile
from pathlib import Path


class UserError(Exception):
    """A problem with what the user gave us, explained in one line.

    The message should name the file, the field (key, column, row) and what is wrong.
    """


def where(path: str | Path | None, field: str | None = None, row: int | None = None) -> str:
    """Format the location part of an error message: ``file: field (row R)``."""
    parts = []
    if path is not None:
        parts.append(str(path))
    if field is not None:
        parts.append(f"'{field}'" if row is None else f"'{field}' (row {row})")
    return ": ".join(parts)


def did_you_mean(key: str, known) -> str:
    """`` (did you mean 'x'?)`` for the closest known name to a mistyped key, or ``""``."""
    match = difflib.get_close_matches(key, sorted(known), n=1)
    return f" (did you mean '{match[0]}'?)" if match else ""


def output_folder(path: str | Path, files: tuple[str, ...] = (), force: bool = False, create: bool = True,
                  option: str = "--out") -> Path:
    """The folder ``path``, checked before any work is done: a UserError if it is a file, lies
    under a file, cannot be created or written, or already holds one of ``files`` (unless
    ``force``: the user's files are never replaced without being asked). ``create``: also create
    it now (else call again with ``create=True`` once there is something to write, so that a
    refused run leaves no empty folder behind)."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: {option}: is a file, not a folder")
    _check_writable(out, option)
    existing = [f for f in files if (out / f).exists()]
    if existing and not force:
        raise UserError(f"{out}: already holds {', '.join(existing)}; use --force to overwrite, or choose "
                        f"another {option}")
    if create:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UserError(f"{out}: {option}: cannot create the folder ({e.strerror or e})") from None
    return out


def output_file(path: str | Path, force: bool = False, suffixes: tuple[str, ...] = (),
                option: str = "--out") -> Path:
    """The file ``path`` a command will write, checked before any work: its suffix is one of
    ``suffixes`` (if given), it is not a folder, it does not exist (unless ``force``), and its
    folder can be created and written."""
    out = Path(path)
    if suffixes and out.suffix.lower() not in suffixes:
        raise UserError(f"{out}: {option}: the file name must end in one of {', '.join(suffixes)}")
    if out.is_dir():
        raise UserError(f"{out}: {option}: is a folder; give a file name")
    if out.exists() and not force:
        raise UserError(f"{out}: exists; choose another path or pass --force to overwrite it")
    _check_writable(out.parent, option)
    return out


def _check_writable(folder: Path, option: str) -> None:
    """UserError unless ``folder`` exists and can be written, or can be created where it is missing.
    Tried for real (a probe file), not with os.access: that says yes to root on a read-only mount."""
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise UserError(f"{folder}: {option}: {existing} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".samfdi-write-test-")
    except OSError as e:
        what = "the folder is not writable" if existing == folder else f"cannot create it in {existing}"
        raise UserError(f"{folder}: {option}: {what} ({e.strerror or e})") from None
    os.close(fd)
    os.unlink(probe)
