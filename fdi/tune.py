"""``samfdi fdi tune``: the Monte Carlo evaluation of the detector. Held-out healthy runs give
the false-alarm rate; fault runs the detection rate within 1 s, delay and isolation accuracy
per fault type, size and load (:mod:`fdi.metrics`). The thresholds are NOT fitted here: they
come from the sensitivity studies (:mod:`fdi.study`, the shipped file or ``--thresholds``), so
every run of this Monte Carlo is held out from the threshold choice.

Each fault run steps in at its own random onset (:func:`draw_onsets`, from the chunk seed apart
from the draws of loads, inputs and nuisance); every scored window is per run. Healthy runs are
scored over the whole run. The protocol is :data:`fdi.montecarlo.TUNE`.

Work is split into chunks; each finished chunk is saved to
``DIR/chunks/<name>_<seed>_<CHUNK_VERSION>.npz`` (a few numbers per run) so an interrupted
run resumes where it stopped. The version tag keeps chunks of an older layout from being mixed in.

A chunk's name does not say which thresholds, plant or run count made it, so the folder
does: ``DIR/tune.json`` (:func:`manifest`), written when a tune starts there. A later tune
into the folder with other settings is refused instead of mixing its chunks with these; the
``--reference`` / ``--bound`` modes are tagged apart and share the folder. Chunks are written
atomically; one that cannot be read (a damaged file) is reported and recomputed.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np

from sam import Plant, UserError
from sam.errors import output_folder

from . import bound as onset_bound
from . import calibration
from .config import FilterConfig
from .diagnosis import judge
from .faults import HYPOTHESES, hypothesis_name
from .filter import run_filter
from .metrics import analyse, write_report
from .montecarlo import LEAKS, TUNE, leak_flow_lpm, make_batch, make_reference_batch, pool_context
from .alarms import first_alarms
from .statistics import Statistics, statistics
from .thresholds import Thresholds

HYP = tuple(HYPOTHESES)
#: chunk file tag: the layout of the chunks (their keys and what made them); an older folder's
#: chunks are never mixed in
CHUNK_VERSION = "x"
MANIFEST = "tune.json"  #: the settings the folder's chunks were made with (:func:`manifest`)
#: what a tune writes besides chunks/ and the manifest: in a folder that is not a tune folder
#: these are the user's own and are not overwritten without ``force``
OUTPUTS = ("metrics.md", "metrics.json", "thresholds_used.json", "roc.png")
#: chunk keys every mode writes (a chunk without one of them is damaged)
CHUNK_KEYS = ("first", "max", "m_L", "k_onset")
#: chunk keys of the bank's verdicts (:func:`bank_decisions`)
BANK_KEYS = ("iso_h", "iso_k", "conf_k", "n_withdrawn")


def draw_onsets(n: int, seed: int) -> np.ndarray:
    """(n,) fault onsets [s] of a chunk: uniform in TUNE.onset_range_s, on the sample grid, from
    their own generator (the chunk seed, 17) so the chunk's other draws are unchanged."""
    rng = np.random.default_rng((seed, 17))
    return np.round(rng.uniform(*TUNE.onset_range_s, n) / TUNE.dt) * TUNE.dt


def chunk_job(plant: Plant, th: Thresholds, fault, size, n, seed, inputs: str = "standard", reference: bool = False,
               bound: bool = False):
    """Filter one chunk; per run and hypothesis: first alarm index (-1: none) and the
    maxima of g/h before the run's onset, within 1 s after it, and over the run; per run
    the onset index ``k_onset`` and, in a leak's runs, ``leak_flow_lpm``: the flow the leak
    passed in the scored second (:func:`fdi.montecarlo.leak_flow_lpm`). ``reference``: each
    machine is first calibrated on a healthy reference recording of its own
    (:func:`fdi.montecarlo.make_reference_batch`, :mod:`fdi.calibration`), as ``fdi replay
    --reference`` does. ``bound``: also the evidence
    of :func:`fdi.bound.onset_evidence` per run (healthy runs: at the onsets a fault run of
    the chunk would have)."""
    onset = TUNE.onset_range_s[0] if fault is None else draw_onsets(n, seed)
    sensor = th.derived.position_sensor
    runs = make_batch(plant, n, seed, fault=fault, size=size, duration=run_seconds(th, fault), onset=onset,
                      position_sensor=sensor, inputs=inputs)
    inp, cfg = runs.inp, FilterConfig()
    if reference:
        ref = make_reference_batch(plant, runs.truth["params"], seed, duration=TUNE.reference_s, position_sensor=sensor)
        inp, cfg = calibration.apply(inp, cfg, calibration.learn(run_filter(ref.inp, cfg), cfg))
    out = run_filter(inp, cfg)
    st = statistics(out, th)
    k0 = runs.truth["k_onset"]
    res = window_maxima(st, th, k0)
    res.update({"m_L": runs.truth["m_L_kg"], "resets": out.n_cov_reset, "k_onset": k0})
    if fault in LEAKS:
        res["leak_flow_lpm"] = leak_flow_lpm(runs, fault, k0, TUNE.within_s)
    res.update(bank_decisions(out, st, th, k0, fault is not None))
    if bound:
        k_b = k0 if fault is not None else np.round(draw_onsets(n, seed) / TUNE.dt).astype(np.int64)
        res["evidence"] = onset_bound.onset_evidence(out, k_b)
    return res


def run_seconds(th: Thresholds, fault) -> float:
    """Length [s] of a tune run: TUNE.fault_run_s for fault runs, the thresholds' run_length_s (the
    run their false-alarm level is stated for) for healthy ones."""
    return TUNE.fault_run_s if fault is not None else th.derived.run_length_s


def window_maxima(st: Statistics, th: Thresholds, k0: np.ndarray) -> dict:
    """Per run b and hypothesis: the first alarm index (-1: none) and the maxima of g/h over
    [0, k0[b]), [k0[b], k0[b] + 1 s] and the whole run."""
    k0 = np.asarray(k0, dtype=np.int64)
    n = len(k0)
    idx = np.arange(next(iter(st.values())).shape[1])
    pre = idx[None, :] < k0[:, None]
    post = (idx[None, :] >= k0[:, None]) & (idx[None, :] <= k0[:, None] + int(round(TUNE.within_s / TUNE.dt)))
    first = np.full((n, len(HYP)), -1, dtype=np.int64)
    mx = np.zeros((n, len(HYP), 3))
    for i, h in enumerate(HYP):
        if h not in st:  # no statistic: never alarms
            continue
        r = st[h] / th.test.h[h]
        above = r > 1.0
        first[:, i] = np.where(above.any(axis=1), np.argmax(above, axis=1), -1)
        mx[:, i, 0] = np.where(pre, r, -np.inf).max(axis=1)
        mx[:, i, 1] = np.where(post, r, -np.inf).max(axis=1)
        mx[:, i, 2] = r.max(axis=1)
    return {"first": first, "max": mx}


def bank_decisions(out, st: Statistics, th: Thresholds, k_onset: np.ndarray, faulty: bool) -> dict:
    """The bank's verdicts, per run: the isolated hypothesis (index in HYP, -1: none or not
    isolable), the sample of the decision (-1: none), the first alarm that stood (-1: none; in a
    fault run a first alarm after the scored second is not judged and counts as it stands) and
    the number of withdrawn alarms.

    Every alarmed run is judged as replay judges it (:func:`fdi.diagnosis.judge`). Fault runs
    are cut at the scored second's end (a decision is causal, so the cut changes no decision
    that counts, and the bank costs a third). The several-faults stage is not run: its verdict
    comes after the scored second."""
    n = out.mean.shape[0]
    res = {key: np.full(n, -1, dtype=np.int64) for key in ("iso_h", "iso_k", "conf_k")}
    res["n_withdrawn"] = np.zeros(n, dtype=np.int64)
    k_end = np.asarray(k_onset, dtype=np.int64) + int(round(TUNE.within_s / TUNE.dt))
    k_alarm = first_alarms(st, th.test.h)[0]
    # a fault run whose first alarm comes after onset + 1 s cannot count within 1 s: not judged
    # (the bank would cost for nothing), its alarm taken as it stands (for the mean delay)
    late = faulty & (k_alarm > k_end)
    res["conf_k"][late] = k_alarm[late]
    rows = np.flatnonzero((k_alarm >= 0) & ~late)
    if not len(rows):
        return res
    decs = judge(out, th, st, rows=rows, k_stop=k_end[rows] + 1 if faulty else None, size=False, pairs=False)
    for b, d in decs.items():
        res["n_withdrawn"][b] = len(d.withdrawn)
        if d.standing.confirmed:
            res["conf_k"][b] = d.standing.alarm
        if d.naming.hypothesis is not None:
            res["iso_h"][b] = HYP.index(hypothesis_name(d.naming.hypothesis, d.naming.size))
            res["iso_k"][b] = d.naming.index
    return res


def jobs_of(n_runs: int) -> list:
    """(name, fault, size, runs, seed, inputs) per chunk: ``n_runs`` healthy runs of the studies'
    inputs, max(5, n_runs // 2) healthy runs of the issue's 20-60 s cycles
    (fdi.montecarlo.LONG_CYCLES) and max(chunk_runs // 5, n_runs // 5) runs of each fault type and
    size (the --runs help states this rule)."""
    chunk = TUNE.chunk_runs
    jobs = [("healthy", None, 0.0, min(chunk, n_runs - c), 1000 + c, "standard") for c in range(0, n_runs, chunk)]
    n_long = long_cycle_runs(n_runs)
    jobs += [("healthy_long", None, 0.0, min(chunk, n_long - c), 300_000 + c, "long_cycles")
             for c in range(0, n_long, chunk)]
    n_fault = max(chunk // 5, n_runs // 5)
    for fault, sizes in TUNE.fault_sizes.items():
        for size in sizes:
            for c in range(0, n_fault, chunk):
                jobs.append((f"{fault}_{size:g}", fault, size, min(chunk, n_fault - c),
                             500_000 + c + int(abs(size) * 1e4) + (7 if size < 0 else 0), "standard"))
    return jobs


def long_cycle_runs(n_runs: int) -> int:
    """The number of healthy long-cycle runs of a tune with ``--runs n_runs``."""
    return max(TUNE.chunk_runs // 5, n_runs // 2)


def run_tune(plant: Plant, out_dir: Path, n_runs: int = 100, workers: int = 1, scheduler: str | None = None,
             progress: bool = True, thresholds: Thresholds | None = None, reference: bool = False,
             bound: bool = False, force: bool = False) -> dict:
    """The Monte Carlo into ``out_dir`` (resumable); ``reference``: every machine calibrated on a
    healthy reference recording first; ``bound``: also the evidence at the known onset
    (:mod:`fdi.bound`; about three times the work). Each mode's chunks are tagged apart.
    ``force``: overwrite the files a tune writes in a folder that is not a tune folder.
    ``workers`` > 1: a local process pool (:func:`fdi.montecarlo.pool_context` says when its
    workers are spawned, and so when a calling script needs ``if __name__ == "__main__":``).
    Every refusal (``out_dir`` not a writable folder, made with other settings, holding the
    user's files; an unreachable ``scheduler``) is a UserError raised before any computing."""
    out_dir = Path(out_dir)
    chunk_dir = out_dir / "chunks"
    th = Thresholds.shipped() if thresholds is None else thresholds
    dt = th.derived.sample_dt_s
    if abs(dt / TUNE.dt - 1.0) > 1e-9:
        raise UserError(f"--thresholds: derived for {1 / dt:.4g} Hz recordings; the tune simulates and "
                        f"filters at {1 / TUNE.dt:g} Hz only ({th.derived.source})")
    jobs = jobs_of(n_runs)
    tag = mode_tag(reference, bound)
    want = manifest(plant, th, n_runs)
    output_folder(out_dir, create=False)  # created by _start: a refused run leaves nothing behind
    _check_folder(out_dir, want, th, force)
    todo = _todo(chunk_dir, jobs, tag)  # before the manifest is written: it may refuse an older folder
    client = _connect(scheduler) if scheduler else None
    try:
        _start(out_dir, want, th)
        timing = compute_chunks(plant, th, chunk_dir, jobs, todo, tag, workers, client, progress, reference, bound)
    finally:
        if client is not None:
            client.close()
    return summarise(out_dir, jobs, th, tag, timing)


def compute_chunks(plant: Plant, th: Thresholds, chunk_dir: Path, jobs: list, todo: list, tag: str, workers: int,
             client, progress: bool, reference: bool, bound: bool) -> dict:
    """Filter the chunks of ``todo`` (those of ``jobs`` not on disk yet) on ``client``, ``workers``
    local processes or here, and save each as it finishes; returns the timing of this call
    (wall_s [s])."""
    old = [p for p in chunk_dir.glob("*.npz") if not p.stem.endswith(f"_{tag}")]
    if old and progress:
        print(f"fdi tune: ignoring {len(old)} chunk file(s) in {chunk_dir} of an older layout or of "
              f"another --reference / --bound mode (this run's tag: {tag!r})")
    from tqdm import tqdm
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="fdi tune", unit="chunk", disable=not progress)

    def save(job, res):
        _save_chunk(chunk_path(chunk_dir, job, tag), res)
        bar.update(1)

    t0 = time.perf_counter()
    if client is not None:
        from dask.distributed import as_completed
        futs = {client.submit(chunk_job, plant, th, *j[1:], reference, bound, pure=False): j for j in todo}
        for fut in as_completed(futs):
            save(futs[fut], fut.result())
    elif workers > 1:
        from concurrent.futures import ProcessPoolExecutor, as_completed
        with ProcessPoolExecutor(workers, mp_context=pool_context()) as ex:
            futs = {ex.submit(chunk_job, plant, th, *j[1:], reference, bound): j for j in todo}
            for fut in as_completed(futs):
                save(futs[fut], fut.result())
    else:
        for j in todo:
            save(j, chunk_job(plant, th, *j[1:], reference, bound))
    bar.close()
    wall = time.perf_counter() - t0
    n_todo = sum(j[3] for j in todo)
    return {"runs_computed": n_todo, "wall_s": wall, "workers": workers,
            "s_per_1000_runs": wall / max(n_todo, 1) * 1000, "chunks_computed": len(todo), "chunks": len(jobs)}


def manifest(plant: Plant, th: Thresholds, n_runs: int) -> dict:
    """What a tune folder's chunks depend on besides their job and mode tag: the chunk layout,
    the run count (it sets the chunks' sizes and the fault runs per case) and hashes (sha256)
    of the thresholds as JSON and of the plant vector (float64 bytes)."""
    vec = np.ascontiguousarray(plant.vector(), dtype=np.float64)
    return {"layout": CHUNK_VERSION, "runs": int(n_runs),
            "thresholds_sha256": hashlib.sha256(th.to_json().encode()).hexdigest(),
            "plant_sha256": hashlib.sha256(vec.tobytes()).hexdigest()}


def _differences(old: dict, new: dict) -> list:
    """What differs between two manifests, in the words of the command line."""
    out = []
    if old.get("runs") != new["runs"]:
        out.append(f"--runs {old.get('runs')} there, {new['runs']} now")
    if old.get("thresholds_sha256") != new["thresholds_sha256"]:
        out.append("other thresholds (--thresholds; or the same file read by another samfdi version, whose "
                   "thresholds have other fields)")
    if old.get("plant_sha256") != new["plant_sha256"]:
        out.append("another plant (--plant)")
    if old.get("layout") != new["layout"]:
        out.append(f"chunk layout {old.get('layout')!r} there (another samfdi version), {new['layout']!r} now")
    return out


def _check_folder(out_dir: Path, want: dict, th: Thresholds, force: bool) -> None:
    """Refuse (UserError) a folder whose manifest differs from ``want``, and a folder that is no
    tune folder but holds a file the tune writes unless ``force``. A folder with chunks and no
    manifest is a tune from before the manifest: resumed; its thresholds_used.json is checked,
    its run count when its chunks are read (:func:`_todo`); its plant cannot be."""
    path = out_dir / MANIFEST
    hint = "use another --out, or the same settings to resume"
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise UserError(f"{path}: not a readable tune manifest ({exc}); delete it to resume the folder "
                            f"unchecked, or use another --out") from None
        diffs = _differences(old, want)
        if diffs:
            raise UserError(f"{out_dir}: a tune folder made with other settings: {'; '.join(diffs)}; {hint}")
        return
    if any((out_dir / "chunks").glob("*.npz")):
        used = _read_json(out_dir / "thresholds_used.json")
        if used is not None and used != json.loads(th.to_json()):
            raise UserError(f"{out_dir}: a tune folder made with other thresholds (thresholds_used.json differs); {hint}")
        return
    mine = [f for f in OUTPUTS if (out_dir / f).exists()]
    if mine and not force:
        raise UserError(f"{out_dir}: already holds {', '.join(mine)} and is not a tune folder (no {MANIFEST}); "
                        "use another --out, or --force to overwrite")


def _read_json(path: Path):
    """The JSON in ``path``; None if it is missing or not JSON."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _connect(scheduler: str):
    """A dask Client on ``scheduler``; an address that cannot be reached is a UserError."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise UserError("--scheduler needs dask[distributed]") from None
    try:
        return Client(scheduler)
    except (OSError, TimeoutError, ValueError) as exc:  # ValueError: a malformed address
        raise UserError(f"cannot reach the dask scheduler at {scheduler}: {' '.join(str(exc).split())}") from None


def _start(out_dir: Path, want: dict, th: Thresholds) -> None:
    """Write the manifest (the first write: an unwritable folder is refused here), chunks/ and
    thresholds_used.json."""
    output_folder(out_dir)
    try:
        _write_atomic(out_dir / MANIFEST, (json.dumps(want, indent=2) + "\n").encode())
        (out_dir / "chunks").mkdir(exist_ok=True)
        (out_dir / "thresholds_used.json").write_text(th.to_json() + "\n")
    except OSError as exc:
        raise UserError(f"{out_dir}: --out: cannot write there ({exc.strerror or exc})") from None


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file in ``path``'s folder, then rename it over ``path``:
    a run killed while writing leaves the old file or none, never a partial one."""
    _replace_with(path, lambda f: f.write(data))


def _save_chunk(path: Path, res: dict) -> None:
    """Save a chunk's arrays atomically (:func:`_write_atomic`): a chunk that exists is finished."""
    _replace_with(path, lambda f: np.savez(f, **res))


def _replace_with(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")  # not *.npz: never taken for a chunk
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _todo(chunk_dir: Path, jobs: list, tag: str) -> list:
    """The jobs whose chunk is not on disk. A chunk that cannot be read is reported in one line
    (a warning) and recomputed: it is our own intermediate file. A readable chunk with another
    run count than its job was made with another --runs (a folder from before the manifest):
    refused."""
    todo = []
    for j in jobs:
        path = chunk_path(chunk_dir, j, tag)
        if not path.exists():
            todo.append(j)
            continue
        n, why = _chunk_runs(path, "b" in tag[len(CHUNK_VERSION):])
        if n is None:
            warnings.warn(f"fdi tune: {path} cannot be read ({why}); recomputing it", stacklevel=2)
            todo.append(j)
        elif n != j[3]:
            raise UserError(f"{path}: holds {n} runs where this tune's chunk has {j[3]}: the folder was made "
                            "with another --runs; use another --out, or the same --runs to resume")
    return todo


def _chunk_runs(path: Path, bound: bool) -> tuple:
    """(runs in the chunk at ``path``, None) or (None, why it cannot be read). Every array is
    read, so a damaged member fails here and not in :func:`analyse`."""
    try:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        return None, f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    missing = [k for k in CHUNK_KEYS + (("evidence",) if bound else ()) if k not in arrays]
    if missing:
        return None, f"no {', '.join(missing)}"
    n = {len(arrays[k]) for k in CHUNK_KEYS}
    return (n.pop(), None) if len(n) == 1 else (None, "arrays of different run counts")


def mode_tag(reference: bool, bound: bool = False) -> str:
    """Chunk file tag: the layout version, "c" appended for a tune with --reference, "b" with --bound."""
    return CHUNK_VERSION + ("c" if reference else "") + ("b" if bound else "")


def chunk_path(chunk_dir: Path, job, tag: str = CHUNK_VERSION) -> Path:
    return Path(chunk_dir) / f"{job[0]}_{job[4]}_{tag}.npz"




def _load(chunk_dir, jobs, name, tag: str = CHUNK_VERSION):
    parts = [np.load(chunk_path(chunk_dir, j, tag)) for j in jobs if j[0] == name]
    keys = CHUNK_KEYS + BANK_KEYS \
        + (("evidence",) if all("evidence" in p for p in parts) else ()) \
        + (("leak_flow_lpm",) if all("leak_flow_lpm" in p for p in parts) else ())
    return {k: np.concatenate([p[k] for p in parts]) for k in keys}


def summarise(out_dir: Path, jobs: list, th: Thresholds, tag: str = CHUNK_VERSION, timing: dict | None = None) -> dict:
    """The metrics of the chunks of ``jobs`` in ``out_dir``/chunks (:func:`fdi.metrics.analyse`),
    written there as metrics.json, metrics.md and roc.png; ``timing``: this run's, if it computed."""
    chunk_dir = Path(out_dir) / "chunks"
    cases = {name: _load(chunk_dir, jobs, name, tag) for name in dict.fromkeys(j[0] for j in jobs)}
    metrics = analyse(cases, th)
    metrics["reference"] = tag.startswith(CHUNK_VERSION + "c")
    if timing is not None:
        metrics["timing"] = timing
    write_report(out_dir, metrics, th, metrics["reference"])
    return metrics
