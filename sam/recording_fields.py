"""The shared recording format's columns, and what its readers say about a file
(docs/recordings.md): shared by the CSV reader (:mod:`sam.recording_csv`) and the rest of
:mod:`sam.recording`."""

from __future__ import annotations

import warnings
from pathlib import Path

from sam.errors import UserError, where

SIGNALS = ("t", "u", "pA", "pB", "x", "theta", "pS", "v", "xs")  # known columns, SI units
REQUIRED = ("t", "u", "pA", "pB")  # plus one of POSITIONS
POSITIONS = ("x", "theta")
TRUTH_PREFIX = "true_"
PRESSURES = ("pA", "pB", "pS")


class RecordingError(UserError):
    """A recording file (or a recording about to be written) is unusable."""


class RecordingWarning(UserWarning):
    """Something in a recording was ignored, e.g. an unknown column."""


def keep_known(names: list[str], path: Path) -> list[str]:
    """The names we use; warn once about the rest (the spec says ignore, not refuse)."""
    unknown = [n for n in names if not is_known(n)]
    if unknown:
        listed = ", ".join(f"'{n}'" for n in unknown)
        warnings.warn(f"{path}: ignoring unknown column(s) {listed}", RecordingWarning, stacklevel=4)
    return [n for n in names if is_known(n)]


def is_known(name: str) -> bool:
    return name in SIGNALS or name.startswith(TRUTH_PREFIX)


def parse_metadata(lines: list[str]) -> dict[str, str]:
    """'# key: value' lines -> dict. A repeated key continues the value on a new line.

    A '#' line without ':' is a plain comment and is skipped.
    """
    metadata: dict[str, str] = {}
    for line in lines:
        key, sep, value = line[1:].partition(":")
        key = key.strip()
        if not sep or not key:
            continue
        value = value.strip()
        metadata[key] = f"{metadata[key]}\n{value}" if key in metadata else value
    return metadata


def at(label: str, column: str, i: int, line_of: list[int] | None) -> str:
    """Location of sample index i: data row (1-based) and, for CSV, the file line."""
    line = f", line {line_of[i]}" if line_of is not None else ""
    return f"{where(label, column)} (data row {i + 1}{line})"
