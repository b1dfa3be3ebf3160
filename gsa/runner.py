"""Evaluate a model over a design in chunks, resumably, on one of several executors.

A study is a :class:`Study`: a name, a :class:`~gsa.problem.Problem`, a model
callable and the names of its outputs. :func:`run` evaluates the model on every
row of ``design.X`` and returns Y (n_runs, M) in the design's run order.

Output folder layout::

    OUT/manifest.json            fingerprint of the run + layout (written first)
    OUT/chunks/chunk_00000.npy   Y rows [0, chunk_size) as float64 (rows, M)
    OUT/chunks/chunk_00001.npy   Y rows [chunk_size, 2 chunk_size) ...
    OUT/nonfinite.json           only if some runs returned NaN/inf

Every chunk is written to a temporary file and renamed over its final name
(``os.replace``, atomic on POSIX), so a chunk file that exists is complete even
after SIGKILL; one damaged by a power loss fails to load on resume and is
computed again (with a warning). Resuming (``resume=True``) loads the existing
chunks and computes only the missing ones; as every value depends only on its
own row of X, a resumed run equals an uninterrupted one bit for bit, whatever
the executor, worker count or chunk size.

Model contract: ``model(X)`` with X (n, k) float64 in parameter units returns
(n, M) float64 (or (n,) when M = 1), row i depending only on X[i]. For the
``"processes"`` and ``"dask"`` executors it must be picklable: a module-level
function or a :func:`functools.partial` of one (no lambdas or closures).
"""

from __future__ import annotations

import json
import math
import multiprocessing
import numbers
import os
import pickle
import uuid
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from gsa.analyze import SobolResult, analyze
from gsa.design import Design
from gsa.errors import GSAError, GSAWarning
from gsa.nonfinite import NonFiniteReport
from gsa.problem import Problem

FORMAT = "gsa-run/1"
EXECUTORS = ("inline", "processes", "dask")
NONFINITE_POLICIES = ("raise", "report")
MANIFEST = "manifest.json"
CHUNK_DIR = "chunks"
NONFINITE_FILE = "nonfinite.json"


def chunk_name(index: int) -> str:
    """File name of chunk ``index`` inside ``OUT/chunks``."""
    return f"chunk_{index:05d}.npy"


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
    """Identity of a run: what a folder's chunks must share to be resumed (estimator-free)."""
    return {
        "format": FORMAT,
        "study": study.name,
        **design.fingerprint(),
        "chunk_size": chunk_size,
        "output_names": list(study.output_names),
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
        ``resume`` is set.
    chunk_size : int
        Runs per chunk (unit of work, of saving and of resuming).
    executor : "inline" | "processes" | "dask"
        Where chunks are computed: this process; a local process pool of
        ``workers`` (default ``os.cpu_count()``) processes; a dask.distributed
        cluster at ``scheduler`` (e.g. "tcp://10.0.0.5:8786").
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
    fp = fingerprint(study, design, int(chunk_size))
    _prepare_folder(out, fp, design, resume)

    n_runs, M = design.n_runs, study.M
    bounds = [(r0, min(n_runs, r0 + chunk_size)) for r0 in range(0, n_runs, chunk_size)]
    chunks = out / CHUNK_DIR
    Y = np.empty((n_runs, M))
    done = []
    for i in range(len(bounds)):
        path = chunks / chunk_name(i)
        if not path.exists():
            continue
        try:
            Y[slice(*bounds[i])] = _load_chunk(path, bounds[i], M)
            done.append(i)
        except GSAError as e:  # e.g. a power loss before the OS wrote it out: recompute it
            warnings.warn(f"{e}; recomputing it", GSAWarning, stacklevel=2)
    done_set = set(done)
    pending = [i for i in range(len(bounds)) if i not in done_set]

    bar = tqdm(
        total=n_runs,
        initial=sum(b - a for a, b in (bounds[i] for i in done)),
        unit="run",
        desc=study.name,
        disable=not progress,
        dynamic_ncols=True,
    )
    tasks = [(i, design.rows(*bounds[i])) for i in pending]
    results = _EXECUTE[executor](study.model, tasks, workers=workers, scheduler=scheduler)
    # Chunks are written by one background thread, so the disk works while the next
    # chunk computes; leaving the `with` waits for every started write.
    with ThreadPoolExecutor(max_workers=1) as writer:
        try:
            writes = []
            for i, Y_chunk in results:
                Y_chunk = _as_chunk_outputs(Y_chunk, i, bounds[i], M)
                Y[slice(*bounds[i])] = Y_chunk
                writes.append(writer.submit(_save_atomic, chunks / chunk_name(i), Y_chunk))
                bar.update(len(Y_chunk))
            for w in writes:
                w.result()  # a failed write is an error of the run
        except Exception as e:
            e.add_note(
                f"[gsa] finished chunks are saved in {chunks}; run again with resume=True "
                f"(--resume) to compute only the missing ones"
            )
            raise
        finally:
            bar.close()

    report = NonFiniteReport.from_outputs(design, Y, study.output_names)
    if report:
        _write_json_atomic(out / NONFINITE_FILE, report.to_dict())
        if nonfinite == "raise":
            raise GSAError(
                f"study '{study.name}': {report.summary()}\n"
                f"All {report.count} runs are listed in {out / NONFINITE_FILE}; the chunks "
                f"are kept in {chunks}."
            )
    return RunResult(study, design, Y, out, report, len(pending), len(done))


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
    if executor not in EXECUTORS:
        raise GSAError(f"unknown executor {executor!r} (known: {', '.join(EXECUTORS)})")
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, numbers.Integral) or workers < 1
    ):
        raise GSAError(f"workers must be an integer >= 1, got {workers!r}")
    if executor == "dask" and not scheduler:
        raise GSAError("executor 'dask' needs a scheduler address, e.g. tcp://127.0.0.1:8786")
    if scheduler and executor != "dask":
        raise GSAError(f"a scheduler address is only used by executor 'dask', not {executor!r}")
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


def _prepare_folder(out: Path, fp: dict, design: Design, resume: bool) -> None:
    """Create or check the run folder; never deletes a chunk."""
    if out.exists() and not out.is_dir():
        raise GSAError(f"output folder {out} exists and is not a folder")
    manifest = out / MANIFEST
    chunks = out / CHUNK_DIR
    existing = sorted(chunks.glob("chunk_*.npy")) if chunks.is_dir() else []
    if not resume and (manifest.exists() or existing):
        raise GSAError(
            f"output folder {out} already holds a run ({len(existing)} finished chunks); "
            f"pass resume=True (--resume) to continue it, or choose another folder. "
            f"Nothing was deleted."
        )
    if manifest.exists():
        try:
            old = json.loads(manifest.read_text())["fingerprint"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise GSAError(f"{manifest}: not a readable run manifest ({e}); refusing to resume") from None
        diffs = _fingerprint_diffs(old, fp)
        if diffs:
            raise GSAError(
                f"{out} holds a different run, refusing to mix results: "
                + "; ".join(diffs)
                + ". Choose another folder, or rerun with the folder's settings."
            )
    elif existing:
        raise GSAError(
            f"{chunks} holds {len(existing)} chunk files but {manifest} is missing, so their "
            f"origin is unknown; refusing to resume. Choose another folder."
        )
    chunks.mkdir(parents=True, exist_ok=True)
    for stale in chunks.glob(".chunk_*.tmp-*"):  # our own half-written files of a killed run
        stale.unlink(missing_ok=True)
    if not manifest.exists():
        n_runs = design.n_runs
        _write_json_atomic(
            manifest,
            {
                "fingerprint": fp,
                "layout": {
                    "run_order": list(design.block_names),
                    "rows_per_block": design.N,
                    "n_runs": n_runs,
                    "n_chunks": math.ceil(n_runs / fp["chunk_size"]),
                    "chunk_file": f"{CHUNK_DIR}/chunk_{{index:05d}}.npy",
                    "chunk_rows": "[index * chunk_size, min(n_runs, (index + 1) * chunk_size))",
                },
            },
        )


def _fingerprint_diffs(old: dict, new: dict) -> list[str]:
    diffs = []
    for key in list(new) + [k for k in old if k not in new]:
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        if key in ("problem", "output_names"):
            diffs.append(f"{key} differs")
        elif key == "design_sha256":
            diffs.append(f"the design samples differ ({str(a)[:12]} there, {str(b)[:12]} here)")
        else:
            diffs.append(f"{key} is {a!r} there, {b!r} here")
    return diffs


def _load_chunk(path: Path, bounds: tuple[int, int], M: int) -> np.ndarray:
    try:
        Y = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise GSAError(f"{path}: unreadable chunk ({e})") from None
    rows = bounds[1] - bounds[0]
    if Y.shape != (rows, M) or Y.dtype != np.float64:
        raise GSAError(
            f"{path}: expected float64 of shape ({rows}, {M}), found {Y.dtype} {Y.shape}"
        )
    return Y


def _as_chunk_outputs(Y, index: int, bounds: tuple[int, int], M: int) -> np.ndarray:
    """Check the model kept its contract for one chunk; float64 (rows, M)."""
    rows = bounds[1] - bounds[0]
    Y = np.asarray(Y)
    if Y.ndim == 1 and M == 1:
        Y = Y[:, None]
    if Y.shape != (rows, M):
        raise GSAError(
            f"the model returned shape {Y.shape} for chunk {index} (runs {bounds[0]}-"
            f"{bounds[1] - 1}); expected ({rows}, {M}): one row per run, one column per output"
        )
    if not (np.issubdtype(Y.dtype, np.number) or Y.dtype == bool) or np.iscomplexobj(Y):
        raise GSAError(f"the model returned dtype {Y.dtype} for chunk {index}; expected float64")
    return np.ascontiguousarray(Y, dtype=np.float64)


# -- files --------------------------------------------------------------------------------


def _save_atomic(path: Path, array: np.ndarray) -> None:
    """Write a chunk under a temporary name, then rename it: the final name only ever
    holds a complete chunk, even after SIGKILL. No fsync: the chunks of a study are
    GBs and waiting for the disk doubled the run time; a chunk lost to a power
    failure fails to load on resume and is computed again."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "wb") as f:
        np.save(f, array, allow_pickle=False)
    os.replace(tmp, path)


def _write_json_atomic(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=2)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


# -- executors: each yields (chunk index, raw model output) as chunks finish -------------


def _evaluate(model, X: np.ndarray) -> np.ndarray:
    """Runs in the worker: one chunk of the model."""
    return np.asarray(model(np.asarray(X, dtype=np.float64)))


def _inline(model, tasks, **_) -> Iterator[tuple[int, np.ndarray]]:
    for i, X in tasks:
        try:
            Y = _evaluate(model, X)
        except Exception as e:
            e.add_note(f"[gsa] raised by the model in chunk {i}")
            raise
        yield i, Y


def _processes(model, tasks, *, workers=None, **_) -> Iterator[tuple[int, np.ndarray]]:
    if not tasks:
        return
    # "spawn": a fresh interpreter per worker, safe with threads (tqdm, BLAS) in the parent.
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1, mp_context=ctx)
    try:
        futures = {pool.submit(_evaluate, model, X): i for i, X in tasks}
        yield from _drain(futures, as_completed)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _dask(model, tasks, *, scheduler=None, **_) -> Iterator[tuple[int, np.ndarray]]:
    if not tasks:
        return
    try:
        from distributed import Client
        from distributed import as_completed as dask_as_completed
    except ImportError:
        raise GSAError("executor 'dask' needs the dask[distributed] package") from None
    try:
        client = Client(scheduler, set_as_default=False, timeout="30s")
    except (OSError, TimeoutError) as e:
        raise GSAError(f"cannot reach the dask scheduler at {scheduler}: {e}") from None
    try:
        token = uuid.uuid4().hex[:8]
        futures = {
            client.submit(_evaluate, model, X, pure=False, key=f"gsa-chunk-{i:05d}-{token}"): i
            for i, X in tasks
        }
        yield from _drain(futures, lambda fs: dask_as_completed(fs, loop=client.loop))
    finally:
        client.close()  # only our connection: the cluster is someone else's


def _drain(futures: dict, as_completed_) -> Iterator[tuple[int, np.ndarray]]:
    """Yield chunks as they finish. On the first model error, cancel what has not
    started, still yield the chunks that had already finished (so they get saved),
    then raise that error."""
    yielded = set()
    for fut in as_completed_(list(futures)):
        try:
            result = fut.result()
        except Exception as e:
            e.add_note(f"[gsa] raised by the model in chunk {futures[fut]}")
            for other in futures:
                other.cancel()
            for other in futures:
                if other not in yielded and other is not fut and _finished_ok(other):
                    yield futures[other], other.result()
            raise
        yielded.add(fut)
        yield futures[fut], result


def _finished_ok(fut) -> bool:
    if not fut.done() or fut.cancelled():
        return False
    try:
        fut.result()
    except Exception:
        return False
    return True


_EXECUTE = {"inline": _inline, "processes": _processes, "dask": _dask}
