"""User-facing errors.

Every problem a user can cause (a bad file, a typo in a TOML key, an impossible
parameter) is raised as a :class:`UserError`. The CLI turns it into one line on
stderr and a non-zero exit code; it never shows a traceback for these.
"""

from __future__ import annotations

import difflib
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


def output_folder(path: str | Path, files: tuple[str, ...] = (), force: bool = False, create: bool = True) -> Path:
    """The folder ``path``, checked before any work is done: a UserError if it is a file, lies
    under a file, cannot be created, or already holds one of ``files`` (unless ``force``: the
    user's files are never replaced without being asked). ``create``: also create it now (else
    call again with ``create=True`` once there is something to write, so that a refused run
    leaves no empty folder behind)."""
    out = Path(path)
    existing_parent = out
    while not existing_parent.exists() and existing_parent != existing_parent.parent:
        existing_parent = existing_parent.parent
    if not existing_parent.is_dir():
        raise UserError(f"{out}: --out: {existing_parent} is a file, not a folder")
    existing = [f for f in files if (out / f).exists()]
    if existing and not force:
        raise UserError(f"{out}: already holds {', '.join(existing)}; use --force to overwrite")
    if create:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UserError(f"{out}: --out: cannot create the folder ({e.strerror or e})") from None
    return out
