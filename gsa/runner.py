"""Evaluate a model over a design in chunks, resumably, on one of several executors.

A study is a :class:`Study`: a name, a :class:`~gsa.problem.Problem`, a model
callable and the names of its outputs. :func:`run` evaluates the model on every
row of ``design.X`` and returns Y (n_runs, M) in the design's run order.

The run folder is a :class:`chunkstore.Store` (atomic chunk files, a manifest with
the run's fingerprint, checksums, a lock against a second run into the folder;
see :mod:`chunkstore`)::

    OUT/manifest.json             fingerprint of the run + layout (written first)
    OUT/chunks/chunk_00000.npz    "Y": rows [0, chunk_size) as float64 (rows, M), or float32
                                  for a model that computes in single precision
    OUT/chunks/chunk_00001.npz    "Y": rows [chunk_size, 2 chunk_size) ...
    OUT/chunks/SHA256SUMS         checksums of the finished chunks
    OUT/nonfinite.json            only if some runs returned NaN/inf

Resuming (``resume=True``) loads the finished chunks and computes only the
missing ones; as every value depends only on its own row of X, a resumed run
equals an uninterrupted one bit for bit, whatever the executor, worker count or
chunk size.

Model contract: ``model(X)`` with X (n, k) float64 in parameter units returns
(n, M) float64 (or (n,) when M = 1), row i depending only on X[i]; float32 if every
value is a float32 (a single-precision model: its chunks take half the disk and the
time to write; Y is float64 either way). For the
``"processes"`` and ``"dask"`` executors it must be picklable: a module-level
function or a :func:`functools.partial` of one (no lambdas or closures).
"""

from __future__ import annotations

import json
import math
import numbers
import os
import pickle
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from chunkstore import EXECUTORS, Store, StoreError, check_executor, compute
from gsa.analyze import SobolResult, analyze
from gsa.design import Design
from gsa.errors import GSAError
from gsa.nonfinite import NonFiniteReport
from gsa.problem import Problem

FORMAT = "gsa-run/2"
NONFINITE_POLICIES = ("raise", "report")
NONFINITE_FILE = "nonfinite.json"
#: dtypes of a chunk's outputs on disk (float32: a single-precision model's, held exactly)
CHUNK_DTYPES = (np.dtype(np.float64), np.dtype(np.float32))


def chunk_key(index: int) -> str:
    """Key (file name without suffix) of chunk ``index`` in the run's store."""
    return f"chunk_{index:05d}"


@dataclass(frozen=True)
class Study:
    """What to run: a named problem, a model and the model's output names.

    ``output_times`` (s), if given, go to the ``time_s`` column of results.
    """

    name: str
    problem: Problem
    model: Callable[[np.ndarray], np.ndarray]
    output_names: tuple[str, ...]
    output_times: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise GSAError(f"study: name must be a non-empty string, got {self.name!r}")
        if not isinstance(self.problem, Problem):
            raise GSAError(f"study '{self.name}': problem must be a gsa Problem")
        if not callable(self.model):
            raise GSAError(f"study '{self.name}': model must be callable, got {self.model!r}")
        if isinstance(self.output_names, str) or not isinstance(self.output_names, Sequence):
            raise GSAError(f"study '{self.name}': output_names must be a list of strings")
        names = tuple(str(n) for n in self.output_names)
        if not names:
            raise GSAError(f"study '{self.name}': needs at least one output name")
        object.__setattr__(self, "output_names", names)
        if self.output_times is not None:
            times = tuple(float(t) for t in self.output_times)
            if len(times) != len(names):
                raise GSAError(
                    f"study '{self.name}': {len(times)} output times for {len(names)} outputs"
                )
            object.__setattr__(self, "output_times", times)

    @property
    def M(self) -> int:
        return len(self.output_names)


@dataclass(frozen=True, eq=False)
class RunResult:
    """Outputs of a finished run. ``Y`` is (n_runs, M) float64 in design run order."""

    study: Study
    design: Design
    Y: np.ndarray
    out_dir: Path
    nonfinite: NonFiniteReport
    chunks_computed: int
    chunks_reused: int

    def analyze(self, **kwargs) -> SobolResult:
        """:func:`gsa.analyze.analyze` with this run's problem, design, Y and output names."""
        kwargs.setdefault("output_names", self.study.output_names)
        kwargs.setdefault("output_times", self.study.output_times)
        return analyze(self.design.problem, self.design, self.Y, **kwargs)


def fingerprint(study: Study, design: Design, chunk_size: int) -> dict:
    """Identity of a run: what a folder's chunks must share to be resumed (estimator-free). A
    model that describes itself (a ``fingerprint()`` method, as the SAM model's: plant, input,
    step, precision) is part of it, so that a study file edited between two runs into one
    folder is refused rather than mixed."""
    described = getattr(study.model, "fingerprint", None)
    return {
        "format": FORMAT,
        "study": study.name,
        **design.fingerprint(),
        "chunk_size": chunk_size,
        "output_names": list(study.output_names),
        **({"model": described()} if callable(described) else {}),
    }


def run(
    study: Study,
    design: Design,
    out_dir: str | os.PathLike,
    *,
    chunk_size: int = 1024,
    executor: str = "inline",
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    progress: bool = True,
    nonfinite: str = "raise",
) -> RunResult:
    """Evaluate ``study.model`` on every run of ``design``, saving chunks to ``out_dir``.

    Parameters
    ----------
    study, design :
        What to run and on which samples (``design.problem == study.problem``).
    out_dir :
        Folder of the run (created if missing). Must not hold another run unless
        ``resume`` is set; locked while the run writes into it.
    chunk_size : int
        Runs per chunk (unit of work, of saving and of resuming).
    executor : "inline" | "processes" | "dask"
        Where chunks are computed: this process; a local process pool of
        ``workers`` (default ``os.cpu_count()``) processes that die with this one; a
        dask.distributed cluster at ``scheduler`` (e.g. "tcp://10.0.0.5:8786").
    resume : bool
        Continue the run in ``out_dir``: reuse its finished chunks. Refused if the
        folder holds a different run (study, problem, N, seed, chunk size, outputs).
    progress : bool
        Show a tqdm progress bar (runs done / total).
    nonfinite : "raise" | "report"
        Runs with NaN/inf output: raise GSAError listing them (default), or return
        them in ``RunResult.nonfinite`` (analysis still refuses them unless told).

    Returns
    -------
    RunResult
    """
    _check_args(study, design, chunk_size, executor, workers, scheduler, nonfinite)
    out = Path(out_dir)
    n_runs, M = design.n_runs, study.M
    bounds = [(r0, min(n_runs, r0 + chunk_size)) for r0 in range(0, n_runs, chunk_size)]
    tasks = {chunk_key(i): (study.model, design.rows(a, b), i, (a, b), M) for i, (a, b) in enumerate(bounds)}
    index = {chunk_key(i): i for i in range(len(bounds))}
    Y = np.empty((n_runs, M))
    reused = 0
    try:
        with Store.open(out, fingerprint(study, design, int(chunk_size)), resume=resume,
                        layout=_layout(design, int(chunk_size))) as store:
            chunks = compute(store, _evaluate, tasks, executor=executor, workers=workers,
                             scheduler=scheduler, progress=progress, desc=study.name, unit="run",
                             sizes={k: b - a for k, (a, b) in zip(tasks, bounds)})
            for chunk in chunks:
                i = index[chunk.key]
                Y[slice(*bounds[i])] = _chunk_outputs(chunk.arrays, i, bounds[i], M, store.path(chunk.key))
                reused += chunk.reused
            report = NonFiniteReport.from_outputs(design, Y, study.output_names)
            if report:
                (out / NONFINITE_FILE).write_text(json.dumps(report.to_dict(), indent=2) + "\n")
    except StoreError as e:
        raise GSAError(str(e)) from None
    if report and nonfinite == "raise":
        raise GSAError(
            f"study '{study.name}': {report.summary()}\n"
            f"All {report.count} runs are listed in {out / NONFINITE_FILE}; the chunks "
            f"are kept in {store.chunk_dir}."
        )
    return RunResult(study, design, Y, out, report, len(bounds) - reused, reused)


def _layout(design: Design, chunk_size: int) -> dict:
    """The manifest's description of the chunks, for a person opening the folder."""
    return {
        "run_order": list(design.block_names),
        "rows_per_block": design.N,
        "n_runs": design.n_runs,
        "n_chunks": math.ceil(design.n_runs / chunk_size),
        "chunk_file": "chunks/chunk_{index:05d}.npz, array 'Y' (rows, outputs)",
        "chunk_rows": "[index * chunk_size, min(n_runs, (index + 1) * chunk_size))",
    }


# -- validation -----------------------------------------------------------------------


def _check_args(study, design, chunk_size, executor, workers, scheduler, nonfinite) -> None:
    if not isinstance(study, Study):
        raise GSAError(f"study must be a gsa Study, got {type(study).__name__}")
    if not isinstance(design, Design):
        raise GSAError(f"design must be a gsa Design, got {type(design).__name__}")
    if design.problem != study.problem:
        raise GSAError(f"study '{study.name}': the design was built for a different problem")
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, numbers.Integral) or chunk_size < 1:
        raise GSAError(f"chunk_size must be an integer >= 1, got {chunk_size!r}")
    try:
        check_executor(executor, workers, scheduler)
    except StoreError as e:
        raise GSAError(str(e)) from None
    if nonfinite not in NONFINITE_POLICIES:
        raise GSAError(f"nonfinite must be one of {NONFINITE_POLICIES}, got {nonfinite!r}")
    if executor == "processes":
        try:
            pickle.dumps(study.model)
        except Exception as e:
            raise GSAError(
                f"study '{study.name}': executor 'processes' needs a picklable model "
                f"(a module-level function or a functools.partial of one), got "
                f"{study.model!r}: {e}"
            ) from None


def _chunk_outputs(arrays: dict, index: int, bounds: tuple[int, int], M: int, path: Path) -> np.ndarray:
    """The outputs of a chunk read back from the store, checked against the run's layout."""
    Y = arrays.get("Y")
    rows = bounds[1] - bounds[0]
    if Y is None or Y.shape != (rows, M) or Y.dtype not in CHUNK_DTYPES:
        found = "no array 'Y'" if Y is None else f"{Y.dtype} {Y.shape}"
        raise GSAError(f"{path}: expected an array 'Y' of float64 or float32 ({rows}, {M}), found {found}")
    return Y


# -- the work of one chunk (runs in the worker) -----------------------------------------


def _evaluate(model, X: np.ndarray, index: int, bounds: tuple[int, int], M: int) -> dict:
    """One chunk of the model, checked against the model contract: {"Y": (rows, M) float64, or
    float32 as the model returned it}."""
    rows = bounds[1] - bounds[0]
    Y = np.asarray(model(np.asarray(X, dtype=np.float64)))
    if Y.ndim == 1 and M == 1:
        Y = Y[:, None]
    if Y.shape != (rows, M):
        raise GSAError(
            f"the model returned shape {Y.shape} for chunk {index} (runs {bounds[0]}-"
            f"{bounds[1] - 1}); expected ({rows}, {M}): one row per run, one column per output"
        )
    if not (np.issubdtype(Y.dtype, np.number) or Y.dtype == bool) or np.iscomplexobj(Y):
        raise GSAError(f"the model returned dtype {Y.dtype} for chunk {index}; expected float64")
    dtype = np.float32 if Y.dtype == np.float32 else np.float64
    return {"Y": np.ascontiguousarray(Y, dtype=dtype)}
