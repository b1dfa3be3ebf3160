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
