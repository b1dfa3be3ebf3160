"""Recordings: one run of the valve-controlled cylinder, as CSV or MATLAB ``.mat``.

The file format is the contract in ``docs/recordings.md``: SI units, exact
column names, ``true_*`` columns for simulator ground truth. Files may come
from any data logger, so the reader trusts nothing and refuses a bad file with
one :class:`RecordingError` that names the file, the column and, where it
applies, the row.

Row numbers in messages are *data rows*, counted from 1 (the first sample is
data row 1). For CSV files the message also gives the line number in the file,
so the user can jump to it in an editor.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.io

from sam.errors import where

from .recording_csv import read_csv
from .recording_fields import (
    POSITIONS, PRESSURES, REQUIRED, SIGNALS, TRUTH_PREFIX, RecordingError, RecordingWarning, at, keep_known,
    parse_metadata,
)

__all__ = [  # the format's fields are re-exported: readers of this module find them here
    "POSITIONS", "PRESSURES", "REQUIRED", "SIGNALS", "TRUTH_PREFIX", "Recording", "RecordingError",
    "RecordingWarning", "read_recording", "write_recording",
]


# Plausibility limits for the "unit obviously wrong" checks. They are far from
# any real value in the right unit and close to typical values in the wrong one.
PRESSURE_MIN_PA = 1e4  # 0.1 bar: real runs in Pa peak far above; runs in bar (< ~400) or MPa stay below
THETA_MAX_RAD = 2 * math.pi  # more than a full turn: degrees
X_MAX_M = 5.0  # no cylinder of this kind strokes 5 m; mm data does
U_MAX_V = 10.5  # +-10 V valve input, with room for noise
XS_MAX = 1.5  # spool fraction is -1..+1; percent data is far above
SAMPLING_TOLERANCE = 0.01  # each step within 1 % of the median step

_MAT_DESCRIPTION = "description"
_TRUTH_NAME = re.compile(r"true_[A-Za-z0-9_]*")  # must also be a valid MATLAB variable name


@dataclass(frozen=True, eq=False)  # eq=False: arrays have no single truth value
class Recording:
    """One run of the cylinder, sampled uniformly.

    Attributes:
        t: sample times, shape (n,), seconds, strictly increasing, uniform step.
        signals: measured columns present, name -> (n,) float64 array in SI
            units (see SIGNALS; 't' is not in here). NaN marks a missing sample.
        truth: simulator ground truth, full column name (e.g. 'true_K_int')
            -> (n,) float64 array. Estimators must never see these; use
            :meth:`measured`.
        metadata: free-form text, key -> value ('# key: value' lines of a CSV
            file, or the 'description' variable of a .mat file).
        source: the file this was read from, if any.
    """

    t: np.ndarray
    signals: dict[str, np.ndarray]
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)
    source: Path | None = None

    @property
    def dt(self) -> float:
        """Sampling step in seconds: the median of the time steps (NaN if n < 2)."""
        if len(self.t) < 2:
            return float("nan")
        return float(np.median(np.diff(self.t)))

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.t)

    def has(self, name: str) -> bool:
        """True if column `name` ('t', a measured signal or a 'true_*' column) is present."""
        return name == "t" or name in self.signals or name in self.truth

    def measured(self) -> Recording:
        """A copy without ground truth: the only view an estimator may get.

        The signal arrays are shared with this recording, not copied.
        """
        return dataclasses.replace(self, truth={}, signals=dict(self.signals), metadata=dict(self.metadata))

    def slice(self, start: int, stop: int) -> Recording:
        """Samples start..stop-1 (Python slice rules), e.g. for held-out splits.

        Arrays are copied, so changing the slice never changes this recording.
        """
        if len(range(self.n)[start:stop]) == 0:
            raise ValueError(f"slice({start}, {stop}) of a recording with {self.n} samples is empty")
        cut = slice(start, stop)
        return dataclasses.replace(
            self,
            t=self.t[cut].copy(),
            signals={k: v[cut].copy() for k, v in self.signals.items()},
            truth={k: v[cut].copy() for k, v in self.truth.items()},
            metadata=dict(self.metadata),
        )


# ---------------------------------------------------------------- reading


def read_recording(path: str | Path) -> Recording:
    """Read a recording from a .csv or .mat file, checking it thoroughly.

    Unknown columns are ignored with one :class:`RecordingWarning` naming them.
    Raises :class:`RecordingError` for any problem; never modifies the file.
    """
    path = Path(path)
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        raise RecordingError(f"{path}: unknown recording type '{path.suffix}', expected .csv or .mat")
    _check_readable(path)
    try:
        columns, metadata, line_of, names = reader(path)
    except OSError as e:  # e.g. permission denied: the user's to fix, not a crash
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from None
    _check_columns(columns, str(path), line_of, names)
    return _to_recording(columns, metadata, path)


def _check_readable(path: Path) -> None:
    if not path.exists():
        raise RecordingError(f"{path}: file does not exist")
    if not path.is_file():
        raise RecordingError(f"{path}: not a regular file")
    if path.stat().st_size == 0:
        raise RecordingError(f"{path}: file is empty")


def _to_recording(columns: dict[str, np.ndarray], metadata: dict[str, str], path: Path | None) -> Recording:
    return Recording(
        t=columns["t"],
        signals={k: columns[k] for k in SIGNALS[1:] if k in columns},
        truth={k: columns[k] for k in sorted(columns) if k.startswith(TRUTH_PREFIX)},
        metadata=metadata,
        source=path,
    )


# MAT ------------------------------------------------------------------


def _read_mat(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str], None, list[str]]:
    """Known columns, metadata, no line numbers (a .mat file has none), all variable names."""
    variables = _load_mat(path)
    _check_not_a_struct(variables, path)
    metadata = _mat_metadata(variables.pop(_MAT_DESCRIPTION, None), path)
    columns = {name: _mat_vector(name, variables[name], path) for name in keep_known(list(variables), path)}
    return columns, metadata, None, list(variables)


def _check_not_a_struct(variables: dict[str, np.ndarray], path: Path) -> None:
    # MATLAB users often keep a run in one struct: say how to save it as the format's variables
    if "t" in variables:
        return
    for name, value in variables.items():
        fields = np.asarray(value).dtype.names or ()
        if "t" in fields:
            raise RecordingError(f"{where(path, name)}: a struct with fields {', '.join(fields)}; the format wants one "
                                 f"variable per column: in MATLAB, save(file, '-struct', '{name}') saves them so")


def _load_mat(path: Path) -> dict[str, np.ndarray]:
    try:
        with path.open("rb") as f:
            data = scipy.io.loadmat(f)
    except NotImplementedError:  # what scipy raises for HDF5-based files
        raise RecordingError(f"{path}: MATLAB v7.3 files are not supported; save with save(..., '-v7')") from None
    except Exception as e:  # noqa: BLE001 -- scipy raises many types for a corrupt file; all mean "unreadable"
        raise RecordingError(f"{path}: not a readable MATLAB .mat file ({e})") from None
    variables = {k: v for k, v in data.items() if not k.startswith("__")}  # skip __header__ etc.
    if not variables:
        raise RecordingError(f"{path}: the .mat file contains no variables")
    return variables


def _mat_vector(name: str, value: np.ndarray, path: Path) -> np.ndarray:
    value = np.asarray(value)
    if value.dtype.kind not in "biuf":
        raise RecordingError(f"{where(path, name)}: non-numeric variable ({_mat_kind(value)}), expected a numeric vector")
    if sum(d > 1 for d in value.shape) > 1:
        shape = "x".join(str(d) for d in value.shape)
        raise RecordingError(f"{where(path, name)}: a {shape} matrix, expected a vector")
    return value.reshape(-1).astype(np.float64)


def _mat_kind(value: np.ndarray) -> str:
    kinds = {"U": "text", "S": "text", "c": "complex", "O": "cell or struct", "V": "struct"}
    return kinds.get(value.dtype.kind, str(value.dtype))


def _mat_metadata(value: np.ndarray | None, path: Path) -> dict[str, str]:
    """'description' -> metadata: '# key: value' lines as written by us, else free text."""
    if value is None:
        return {}
    value = np.asarray(value)
    if value.dtype.kind == "O" and all(np.asarray(c).dtype.kind == "U" for c in value.reshape(-1)):
        # a cell array of char lines, MATLAB's other way to hold several lines of text
        value = np.array(["\n".join(str(r).rstrip() for r in np.asarray(c).reshape(-1)) for c in value.reshape(-1)])
    if value.dtype.kind != "U":
        raise RecordingError(f"{where(path, _MAT_DESCRIPTION)}: must be text ({_mat_kind(value)} found)")
    # a char matrix comes back as its rows, padded with blanks to equal length
    text = "\n".join(str(row).rstrip() for row in value.reshape(-1))
    lines = text.splitlines()
    if lines and all(_is_metadata_line(ln) for ln in lines):
        return parse_metadata(lines)
    return {_MAT_DESCRIPTION: text}


def _is_metadata_line(line: str) -> bool:
    key, sep, _ = line[1:].partition(":")
    return line.startswith("#") and bool(sep) and bool(key.strip())


_READERS = {".csv": read_csv, ".mat": _read_mat}


# ---------------------------------------------------------------- checks
# Shared by the reader (columns of a file) and the writer (columns of a
# Recording), so that we never write a file we would refuse to read.


def _check_columns(
    columns: dict[str, np.ndarray], label: str, line_of: list[int] | None, names: list[str] | None = None
) -> None:
    """Refuse the first problem found, in the order a user would want to fix them.

    `names` are all column names of the file, unknown ones included (for hints).
    """
    _check_required(columns, label, names if names is not None else list(columns))
    _check_lengths(columns, label)
    for name, values in columns.items():
        _check_finite_or_nan(name, values, label, line_of)
    _check_time(columns["t"], label, line_of)
    for name, values in columns.items():
        _check_not_all_nan(name, values, label)
    _check_units(columns, label, line_of)


def _check_required(columns: dict[str, np.ndarray], label: str, names: list[str]) -> None:
    found = ", ".join(names) or "none"
    for name in REQUIRED:
        if name not in columns:
            hint = _case_hint(name, names)
            raise RecordingError(f"{where(label, name)}: missing required column (columns found: {found}){hint}")
    if not any(p in columns for p in POSITIONS):
        hint = "".join(_case_hint(p, names) for p in POSITIONS)
        raise RecordingError(
            f"{label}: 'x' / 'theta': missing position column, need x (m) or theta (rad) (columns found: {found}){hint}"
        )


def _case_hint(name: str, names: list[str]) -> str:
    # 'PA' for 'pA' is the commonest way to "miss" a column that is there
    near = [n for n in names if n.lower() == name.lower() and n != name]
    return f"; '{near[0]}' is not '{name}': names are case-sensitive" if near else ""


def _check_lengths(columns: dict[str, np.ndarray], label: str) -> None:
    n = len(columns["t"])
    for name, values in columns.items():
        if len(values) != n:
            raise RecordingError(f"{where(label, name)}: has {len(values)} samples but 't' has {n}")
    if n < 2:
        raise RecordingError(f"{where(label, 't')}: {n} sample(s); need at least 2 to know the sampling step")


def _check_finite_or_nan(name: str, values: np.ndarray, label: str, line_of: list[int] | None) -> None:
    bad = np.flatnonzero(np.isinf(values))
    if bad.size:
        raise RecordingError(f"{at(label, name, bad[0], line_of)}: infinite value ({values[bad[0]]:g})")


def _check_time(t: np.ndarray, label: str, line_of: list[int] | None) -> None:
    nan = np.flatnonzero(np.isnan(t))
    if nan.size:
        raise RecordingError(f"{at(label, 't', nan[0], line_of)}: time is missing (NaN); only signals may have gaps")
    step = np.diff(t)
    back = np.flatnonzero(step <= 0)
    if back.size:
        i = back[0] + 1
        raise RecordingError(
            f"{at(label, 't', i, line_of)}: time not strictly increasing ({t[i]:.9g} s after {t[i - 1]:.9g} s)"
        )
    median = np.median(step)
    off = np.flatnonzero(np.abs(step - median) > SAMPLING_TOLERANCE * median)
    if off.size:
        i = off[0] + 1
        raise RecordingError(
            f"{at(label, 't', i, line_of)}: non-uniform sampling: step {step[i - 1]:.6g} s "
            f"differs from the median step {median:.6g} s by more than 1 %"
        )


def _check_not_all_nan(name: str, values: np.ndarray, label: str) -> None:
    if np.isnan(values).all():
        raise RecordingError(f"{where(label, name)}: every sample is missing (NaN); drop the column instead")


def _check_units(columns: dict[str, np.ndarray], label: str, line_of: list[int] | None) -> None:
    for name in PRESSURES:
        peak = _peak(columns.get(name))
        if 0 < peak < PRESSURE_MIN_PA:
            raise RecordingError(f"{where(label, name)}: largest |value| is {peak:g}, looks like bar or MPa, expected Pa")
    for name, limit, meaning in _UPPER_LIMITS:
        peak = _peak(columns.get(name))
        if peak > limit:
            raise RecordingError(f"{where(label, name)}: largest |value| is {peak:g}, {meaning}")
    _check_u_range(columns["u"], label, line_of)


_UPPER_LIMITS = (
    ("theta", THETA_MAX_RAD, "looks like degrees, expected rad"),
    ("x", X_MAX_M, "looks like mm, expected m"),
    ("xs", XS_MAX, "looks like percent, expected a fraction of full opening (-1..+1)"),
)


def _check_u_range(u: np.ndarray, label: str, line_of: list[int] | None) -> None:
    over = np.flatnonzero(np.abs(np.nan_to_num(u)) > U_MAX_V)
    if over.size:
        i = over[0]
        raise RecordingError(f"{at(label, 'u', i, line_of)}: {u[i]:g} V is out of range, expected -10..+10 V")


def _peak(values: np.ndarray | None) -> float:
    """Largest finite |value|, 0 if absent."""
    if values is None:
        return 0.0
    finite = np.abs(values[np.isfinite(values)])
    return float(finite.max()) if finite.size else 0.0


# ---------------------------------------------------------------- writing


def write_recording(path: str | Path, rec: Recording, *, overwrite: bool = False) -> Path:
    """Write `rec` as .csv or .mat (by suffix) and return the path written.

    The recording is checked as the reader would check the file, so a written
    file can always be read back. Refuses to replace an existing file unless
    `overwrite`; creates missing parent directories. Floats round-trip exactly;
    metadata values round-trip except for blanks at the edges of each line.
    """
    path = Path(path)
    writer = _WRITERS.get(path.suffix.lower())
    if writer is None:
        raise RecordingError(f"{path}: unknown recording type '{path.suffix}', expected .csv or .mat")
    if path.is_dir():
        raise RecordingError(f"{path}: is a directory, expected a file name")
    if path.exists() and not overwrite:
        raise RecordingError(f"{path}: file exists; choose another path or pass --force to overwrite it")
    label = f"{path} (not written)"
    columns = _columns_of(rec, label)
    _check_columns(columns, label, None)
    _check_metadata(rec.metadata, label)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _replace_atomically(path, lambda f: writer(f, columns, rec.metadata))
    except OSError as e:  # e.g. permission denied, disk full
        raise RecordingError(f"{path}: cannot write: {e.strerror or e}") from None
    return path


def _columns_of(rec: Recording, label: str) -> dict[str, np.ndarray]:
    """File columns in file order: SIGNALS order, then true_* sorted, as 1-D float64."""
    for name in rec.signals:
        if name not in SIGNALS[1:]:
            raise RecordingError(f"{where(label, name)}: unknown signal; known: {', '.join(SIGNALS[1:])}")
    for name in rec.truth:
        if not _TRUTH_NAME.fullmatch(name):
            raise RecordingError(f"{where(label, name)}: truth columns are named true_<letters, digits, _>")
    named = {"t": rec.t, **rec.signals, **rec.truth}
    ordered = [n for n in SIGNALS if n in named] + sorted(rec.truth)
    return {name: _as_vector(name, named[name], label) for name in ordered}


def _as_vector(name: str, values: object, label: str) -> np.ndarray:
    array = np.asarray(values)
    if array.ndim != 1 or array.dtype.kind not in "biuf":
        raise RecordingError(
            f"{where(label, name)}: must be a 1-D real numeric array (got {array.dtype} with shape {array.shape})"
        )
    return array.astype(np.float64)


def _check_metadata(metadata: dict[str, str], label: str) -> None:
    # keys must survive '# key: value' parsing unchanged
    for key, value in metadata.items():
        if not isinstance(key, str) or not isinstance(value, str):
            raise RecordingError(f"{label}: metadata {key!r}: keys and values must be text")
        if not key or key != key.strip() or ":" in key or "\n" in key or "\r" in key:
            raise RecordingError(
                f"{label}: metadata key {key!r}: must be non-empty, without ':', line breaks or edge blanks"
            )
        if any(len(part.splitlines()) > 1 for part in value.split("\n")):
            raise RecordingError(f"{label}: metadata {key!r}: the only line break allowed in a value is '\\n'")


def _metadata_lines(metadata: dict[str, str]) -> list[str]:
    # a multi-line value becomes one line per line under the same key; the reader joins them
    return [f"# {key}: {part}" for key, value in metadata.items() for part in value.split("\n")]


def _replace_atomically(path: Path, write) -> None:
    """Write to a temporary file next to `path`, then rename: no half-written recordings."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with tmp.open("wb") as f:
            write(f)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _write_csv(f, columns: dict[str, np.ndarray], metadata: dict[str, str]) -> None:
    lines = _metadata_lines(metadata) + [",".join(columns)]
    texts = [_format_column(values) for values in columns.values()]
    lines += [",".join(row) for row in zip(*texts)]
    f.write(("\n".join(lines) + "\n").encode("utf-8"))


def _format_column(values: np.ndarray) -> list[str]:
    # repr is the shortest text that reads back to the same float64 bits
    # (as exact as '%.17g', but 0.001 stays '0.001'); NaN -> empty field
    return [repr(v) if v == v else "" for v in values.tolist()]


def _write_mat(f, columns: dict[str, np.ndarray], metadata: dict[str, str]) -> None:
    variables: dict[str, object] = dict(columns)
    if metadata:
        variables[_MAT_DESCRIPTION] = "\n".join(_metadata_lines(metadata))
    scipy.io.savemat(f, variables, format="5", oned_as="column", do_compression=True)


_WRITERS = {".csv": _write_csv, ".mat": _write_mat}
