"""The CSV container of a recording (docs/recordings.md): text -> named float64 columns.

Part of :mod:`sam.recording` (which checks what this returns); apart only to keep each module
short. Files come from other labs' loggers, spreadsheets, R and pandas, so what they commonly
write within the format is read (a byte-order mark, CRLF, a column without a name, ``NA``), and
anything else is refused in one line naming the file, the column and the row.
"""

from __future__ import annotations

import csv
import math
import warnings
from pathlib import Path

import numpy as np

from .errors import where
from .recording_fields import (
    RecordingError,
    RecordingWarning,
    at,
    keep_known,
    parse_metadata,
)

#: field texts that mean a missing sample besides an empty field and 'nan': R's write.csv writes
#: NA, a spreadsheet #N/A; pandas reads all of them as missing too
_MISSING = frozenset({"na", "n/a", "#n/a"})

#: separators a spreadsheet or logger may use instead of the format's comma, and their names
_OTHER_SEPARATORS = {";": "semicolons", "\t": "tabs", "|": "vertical bars", " ": "spaces"}


def read_csv(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str], list[int], list[str]]:
    """Known columns, metadata, the file line number of each data row, all column names."""
    lines = _read_text(path).splitlines()
    while lines and not lines[-1].strip():  # blank trailing lines are allowed
        lines.pop()
    header_at = _find_header(lines, path)
    metadata = parse_metadata([ln for ln in lines[:header_at] if ln.strip()])
    names = _parse_header(lines[header_at], path, header_at + 1)
    data_lines = lines[header_at + 1 :]
    line_of = list(range(header_at + 2, header_at + 2 + len(data_lines)))
    known = keep_known([n for n in names if n], path)
    table = _fast_table(data_lines, len(names))
    if table is not None:
        return {name: table[:, names.index(name)].copy() for name in known}, metadata, line_of, names
    rows = _split_rows(data_lines, names, path, first_line=header_at + 2)
    columns = {}
    for name in known:
        j = names.index(name)
        columns[name] = _parse_column(name, [r[j] for r in rows], str(path), line_of)
    return columns, metadata, line_of, names


def _fast_table(data_lines: list[str], n_cols: int) -> np.ndarray | None:
    """(rows, n_cols) float64 from the data lines of a plain numeric CSV, parsed by numpy's C
    reader (np.loadtxt), or None when the file needs the careful reader (empty fields, text,
    quotes, a row of the wrong width): that reader then reads it or names the problem. Why: the
    careful reader parses each field in Python, 7 s for a 3-minute 1 kHz recording, np.loadtxt 1 s."""
    if not data_lines:
        return None
    try:
        table = np.loadtxt(data_lines, delimiter=",", comments=None, ndmin=2, dtype=np.float64)
    except ValueError:
        return None
    return table if table.shape == (len(data_lines), n_cols) else None


def _read_text(path: Path) -> str:
    # utf-8-sig: spreadsheet programs put a byte-order mark in front of UTF-8 CSV files
    try:
        return path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise RecordingError(f"{path}: not UTF-8 text (byte {e.start}); save the CSV as UTF-8") from None


def _find_header(lines: list[str], path: Path) -> int:
    """Index of the header: the first line that is neither blank nor '#' metadata."""
    for i, line in enumerate(lines):
        if line.strip() and not line.startswith("#"):
            return i
    raise RecordingError(f"{path}: no header row (the file holds only '#' metadata or blank lines)")


def _parse_header(line: str, path: Path, line_no: int) -> list[str]:
    """Column names; '' for a column without a name (ignored, like any unknown column)."""
    names = [n.strip() for n in next(csv.reader([line]))]
    if len(names) == 1:
        for sep, word in _OTHER_SEPARATORS.items():
            if len(line.strip().split(sep)) > 1:
                raise RecordingError(
                    f"{path}: header (line {line_no}) is one column, {line.strip()[:40]!r}: the file is separated "
                    f"by {word} ({sep!r}), the format by commas with '.' as the decimal mark (docs/recordings.md); "
                    f"save or export it as CSV with ',' as the separator")
    if not any(names):
        raise RecordingError(f"{path}: header (line {line_no}) has no column names")
    if all(_is_number(n) for n in names if n):
        raise RecordingError(f"{path}: header row missing: line {line_no} holds numbers, expected column names")
    for i, name in enumerate(names):
        if name and names.index(name) != i:
            raise RecordingError(f"{where(path, name)}: duplicate column name in the header (line {line_no})")
    unnamed = [str(i + 1) for i, name in enumerate(names) if not name]
    if unnamed:  # pandas' and R's row index, or a comma ending every line
        warnings.warn(f"{path}: ignoring column(s) {', '.join(unnamed)} of {len(names)}: no name in the header "
                      f"(line {line_no})", RecordingWarning, stacklevel=5)
    return names


def _split_rows(lines: list[str], names: list[str], path: Path, first_line: int) -> list[list[str]]:
    if not lines:
        raise RecordingError(f"{path}: no data rows after the header (line {first_line - 1})")
    rows = list(csv.reader(lines))
    for i, row in enumerate(rows):
        if len(row) != len(names):
            raise RecordingError(_wrong_width(path, names, row, i, first_line + i))
    return rows


def _wrong_width(path: Path, names: list[str], row: list[str], i: int, line_no: int) -> str:
    loc = f"{path}: data row {i + 1} (line {line_no})"
    if not any(field.strip() for field in row):
        return f"{loc}: blank line inside the data (only trailing blank lines are allowed)"
    if len(row) < len(names):
        return f"{loc}: {len(row)} fields, header has {len(names)} (no value for '{names[len(row)] or len(row) + 1}')"
    return f"{loc}: {len(row)} fields, header has {len(names)} (check the decimal mark: it must be '.')"


def _parse_column(name: str, texts: list[str], label: str, line_of: list[int]) -> np.ndarray:
    """Field texts -> float64; an empty field, 'nan' or a _MISSING marker (any case) is NaN."""
    try:
        return np.array([_number(s) for s in texts], dtype=np.float64)
    except ValueError:
        pass
    # slow path only to say where: the first field that is not a number
    i = next(i for i, s in enumerate(texts) if not _is_number(s))
    hint = ""
    if i == 0 and len(texts) > 1 and _is_number(texts[1]):  # text over numbers: a units or second header row
        hint = ("; a row of units or names under the header? the format's units are SI (docs/recordings.md): "
                "delete the row, or make it a '# units: ...' line above the header")
    raise RecordingError(f"{at(label, name, i, line_of)}: non-numeric value '{texts[i].strip()}'{hint}") from None


def _number(text: str) -> float:
    text = text.strip()
    return float(text) if text and text.lower() not in _MISSING else math.nan


def _is_number(text: str) -> bool:
    try:
        _number(text)
    except ValueError:
        return False
    return True
