"""Monte Carlo evaluation of the detector: held-out healthy runs give the false-alarm
rate; fault runs give the detection rate within 1 s, delay and isolation accuracy per
fault type, size and load. The thresholds are NOT fitted here: they come from the
sensitivity studies (:mod:`fdi.thresholds`, the shipped
``scenarios/faults/thresholds.toml`` or ``--thresholds``), so every healthy run of
this Monte Carlo is held out from the threshold choice.

Each fault run steps in at its own random onset, uniform in [ONSET_MIN, ONSET_MAX] s
(drawn from the chunk seed by :func:`draw_onsets`, apart from the draws of loads, inputs
and nuisance, so the runs are paired with those of the fixed-onset tables apart from the
onset); every window (before the onset, within 1 s of it) is per run. Healthy runs are
scored over the whole run, as before.

Work is split into chunks; each finished chunk is saved to
``DIR/chunks/<name>_<seed>_<CHUNK_VERSION>.npz`` (a few numbers per run) so an interrupted
run resumes where it stopped. The version tag keeps chunks of an older layout (the
fixed-onset chunks had no tag and no ``k_onset``) from being mixed in.

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
from . import calibration, isolate, rates
from .detect import HYPOTHESES, Thresholds, alarm_judging, statistics
from .montecarlo import LEAKS, LONG_CYCLES, leak_flow_lpm, make_batch, make_reference_batch, pool_context
from .synth import POSITION_SENSORS
from .config import FilterConfig
from .filter import run_filter

FAULT_SIZES = {"K_int": (0.1, 0.25, 0.5, 1.0), "K_extA": (0.1, 0.25, 0.5, 1.0),
               "K_extB": (0.1, 0.25, 0.5, 1.0), "offset": (0.01, -0.01, 0.02, -0.02, 0.05)}
#: s: fault runs last DURATION; healthy runs last the thresholds' run_length_s (the length their
#: false-alarm level is stated for: 20 s since session 11; a recording's healthy change residual
#: carries an offset that lasts, so a longer run is more likely to false-alarm)
DURATION, CHUNK, DT = 4.0, 25, 1e-3
ONSET_MIN, ONSET_MAX = 1.5, 2.5  #: fault onset range [s]; + the 1 s scored ends by 3.5 s < DURATION
ONSET = ONSET_MIN  #: the nominal onset of healthy runs (their windows are not scored)
WITHIN_S = 1.0  #: s, the issue's scored window: detected and isolated within this long of the onset
REFERENCE_S = 4.0  #: s, length of the healthy reference recording of ``--reference``
#: chunk file tag: "r" = random onset, per-run k_onset saved (session 8); "s" = the same with the
#: tests held where pinned pressures hide them and the session-9 thresholds (an older folder's
#: chunks are not mixed in); "t": healthy runs of the thresholds' run_length_s (session 11);
#: "u": every alarm judged by the bank, withdrawn unless confirmed (conf_k, session 14); "w":
#: no fault named on an end stop where it cannot act, and the confirmation bank with the
#: calibration uncertain (session 15; "v" had the first alone); "x": the filter's random walks
#: held while the piston rests on an end stop and a diverged mean restored (session 26), after
#: session 25's notch-flow trigger, which changed the decisions without a new tag
CHUNK_VERSION = "x"
#: how each position sensor is simulated (fdi.synth.POSITION_SENSORS), for metrics.md
POSITION_SENSOR_TEXT = {"encoder": "the joint angle from the quantised encoder",
                        "linear": f"x from a linear transducer, white noise {POSITION_SENSORS['linear']['x_noise'] * 1e6:g} um"}
LOAD_BINS = ((0.0, 267.0), (267.0, 534.0), (534.0, 800.1))
#: L/min: bin edges of the flow a leak passed in its scored second, for isolation by flow
FLOW_BINS_LPM = (0.05, 0.1, 0.15, 0.25, 0.5, 1.0)
HYP = tuple(HYPOTHESES)
#: the issue's target: each fault case detected and isolated within 1 s in at least this
#: fraction of runs (judged on the point rate and, with :mod:`fdi.rates`, on its interval)
TARGET_RATE = 0.95
MANIFEST = "tune.json"  #: the settings the folder's chunks were made with (:func:`manifest`)
#: what a tune writes besides chunks/ and the manifest: in a folder that is not a tune folder
#: these are the user's own and are not overwritten without ``force``
OUTPUTS = ("metrics.md", "metrics.json", "thresholds_used.json", "roc.png")
#: chunk keys every mode writes (a chunk without one of them is damaged)
CHUNK_KEYS = ("first", "max", "m_L", "k_onset")
#: chunk keys of likelihood isolation (:func:`_bank_decisions`)
BANK_KEYS = ("iso_h", "iso_k", "conf_k", "n_withdrawn")
#: per fault type: colormap (one shade per size), line style and marker of its ROC curves
ROC_STYLE = {"K_int": ("Blues", "-", "o"), "K_extA": ("Greens", "--", "s"), "K_extB": ("Oranges", "-.", "^"),
             "offset+": ("Purples", ":", "D"), "offset-": ("Reds", (0, (5, 1, 1, 1)), "v")}


def draw_onsets(n: int, seed: int) -> np.ndarray:
    """(n,) fault onsets [s] of a chunk: uniform in [ONSET_MIN, ONSET_MAX], on the sample grid,
    from their own generator (the chunk seed, 17) so the chunk's other draws are unchanged."""
    rng = np.random.default_rng((seed, 17))
    return np.round(rng.uniform(ONSET_MIN, ONSET_MAX, n) / DT) * DT


def _chunk_job(plant: Plant, th: Thresholds, fault, size, n, seed, inputs: str = "standard", reference: bool = False,
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
    onset = ONSET if fault is None else draw_onsets(n, seed)
    runs = make_batch(plant, n, seed, fault=fault, size=size, duration=run_seconds(th, fault), onset=onset,
                      position_sensor=th.position_sensor, inputs=inputs)
    inp, cfg = runs.inp, FilterConfig()
    if reference:
        ref = make_reference_batch(plant, runs.truth["params"], seed, duration=REFERENCE_S,
                                   position_sensor=th.position_sensor)
        inp, cfg = calibration.apply(inp, cfg, calibration.learn(run_filter(ref.inp, cfg), cfg))
    out = run_filter(inp, cfg)
    st = statistics(out, th)
    k0 = runs.truth["k_onset"]
    res = _window_maxima(st, th, k0)
    res.update({"m_L": runs.truth["m_L_kg"], "resets": out.n_cov_reset, "k_onset": k0})
    if fault in LEAKS:
        res["leak_flow_lpm"] = leak_flow_lpm(runs, fault, k0, WITHIN_S)
    res.update(_bank_decisions(out, st, th, k0, fault is not None))
    if bound:
        k_b = k0 if fault is not None else np.round(draw_onsets(n, seed) / DT).astype(np.int64)
        res["evidence"] = onset_bound.onset_evidence(out, k_b)
    return res


def run_seconds(th: Thresholds, fault) -> float:
    """Length [s] of a tune run: DURATION for fault runs, the thresholds' run_length_s (the run
    their false-alarm level is stated for, >= DURATION: fdi.detect.MIN_RUN_LENGTH_S) for healthy ones."""
    return DURATION if fault is not None else th.run_length_s


def _window_maxima(st: dict, th: Thresholds, k0: np.ndarray) -> dict:
    """Per run b and hypothesis: the first alarm index (-1: none) and the maxima of g/h over
    [0, k0[b]), [k0[b], k0[b] + 1 s] and the whole run."""
    k0 = np.asarray(k0, dtype=np.int64)
    n = len(k0)
    idx = np.arange(next(iter(st.values())).shape[1])
    pre = idx[None, :] < k0[:, None]
    post = (idx[None, :] >= k0[:, None]) & (idx[None, :] <= k0[:, None] + int(round(WITHIN_S / DT)))
    first = np.full((n, len(HYP)), -1, dtype=np.int64)
    mx = np.zeros((n, len(HYP), 3))
    for i, h in enumerate(HYP):
        if h not in st:  # no statistic: never alarms
            continue
        r = st[h] / th.h[h]
        above = r > 1.0
        first[:, i] = np.where(above.any(axis=1), np.argmax(above, axis=1), -1)
        mx[:, i, 0] = np.where(pre, r, -np.inf).max(axis=1)
        mx[:, i, 1] = np.where(post, r, -np.inf).max(axis=1)
        mx[:, i, 2] = r.max(axis=1)
    return {"first": first, "max": mx}


def _bank_decisions(out, st, th: Thresholds, k_onset: np.ndarray, faulty: bool) -> dict:
    """Likelihood isolation, per run: the isolated hypothesis (index in HYP, -1: none or not
    isolable), the sample of the decision (-1: none), and the first alarm that stood (the
    bank confirmed it, ``th.confirm_nats``; -1: none; in a fault run a first alarm after onset +
    1 s is not judged and counts as it stands) and the number of withdrawn alarms.

    Every alarmed run goes through :func:`fdi.isolate.isolate` as replay runs it: the bank over
    DECISION_WINDOW_S after each alarm, withdrawn alarms restarting the tests, until one
    stands. Fault runs are cut at onset + 1 s (a decision is causal, tests/test_fdi_isolate.py,
    so the cut changes no decision that counts; the bank then costs about the filter's time
    again instead of three times). The several-faults stage is not run: its verdict comes
    isolate.PAIR_WINDOW_S after the alarm, after the 1 s the tune scores."""
    n = out.mean.shape[0]
    res = {key: np.full(n, -1, dtype=np.int64) for key in ("iso_h", "iso_k", "conf_k")}
    res["n_withdrawn"] = np.zeros(n, dtype=np.int64)
    k_end = np.asarray(k_onset, dtype=np.int64) + int(round(WITHIN_S / DT))
    k_alarm, _ = isolate.first_alarms(st, th.h)
    # a fault run whose first alarm comes after onset + 1 s cannot count within 1 s: not judged
    # (the bank would cost for nothing), its alarm taken as it stands (for the mean delay)
    late = faulty & (k_alarm > k_end)
    res["conf_k"][late] = k_alarm[late]
    rows = np.flatnonzero((k_alarm >= 0) & ~late)
    if not len(rows):
        return res
    k_ready = int(round((th.warmup_s + th.baseline_s) / DT))
    decs = isolate.isolate(out, st, th.h, k_ready, isolate.margin_for(th.false_isolation_level),
                           horizon_s=isolate.DECISION_WINDOW_S, rows=rows,
                           k_stop=k_end[rows] + 1 if faulty else None, size=False, pairs=False,
                           **alarm_judging(out, th))
    for b, d in decs.items():
        res["n_withdrawn"][b] = len(d.withdrawn)
        if d.confirmed:
            res["conf_k"][b] = d.alarm
        if d.hypothesis is not None:
            res["iso_h"][b] = HYP.index(isolate.hypothesis_name(d.hypothesis, d.size))
            res["iso_k"][b] = d.index
    return res


def _jobs(n_runs: int):
    """(name, fault, size, runs, seed, inputs) per chunk: ``n_runs`` healthy runs of the studies'
    inputs, max(5, n_runs // 2) healthy runs of the issue's 20-60 s cycles
    (fdi.montecarlo.LONG_CYCLES) and max(CHUNK // 5, n_runs // 5) runs of each fault type and size
    (the --runs help states this rule)."""
    jobs = [("healthy", None, 0.0, min(CHUNK, n_runs - c), 1000 + c, "standard") for c in range(0, n_runs, CHUNK)]
    n_long = long_cycle_runs(n_runs)
    jobs += [("healthy_long", None, 0.0, min(CHUNK, n_long - c), 300_000 + c, "long_cycles")
             for c in range(0, n_long, CHUNK)]
    n_fault = max(CHUNK // 5, n_runs // 5)
    for fault, sizes in FAULT_SIZES.items():
        for size in sizes:
            for c in range(0, n_fault, CHUNK):
                jobs.append((f"{fault}_{size:g}", fault, size, min(CHUNK, n_fault - c),
                             500_000 + c + int(abs(size) * 1e4) + (7 if size < 0 else 0), "standard"))
    return jobs


def long_cycle_runs(n_runs: int) -> int:
    """The number of healthy long-cycle runs of a tune with ``--runs n_runs``."""
    return max(CHUNK // 5, n_runs // 2)


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
    if abs(th.sample_dt_s / DT - 1.0) > 1e-9:
        raise UserError(f"--thresholds: derived for {1 / th.sample_dt_s:.4g} Hz recordings; the tune simulates and "
                        f"filters at {1 / DT:g} Hz only ({th.source})")
    jobs = _jobs(n_runs)
    tag = _tag(reference, bound)
    want = manifest(plant, th, n_runs)
    output_folder(out_dir, create=False)  # created by _start: a refused run leaves nothing behind
    _check_folder(out_dir, want, th, force)
    todo = _todo(chunk_dir, jobs, tag)  # before the manifest is written: it may refuse an older folder
    client = _connect(scheduler) if scheduler else None
    try:
        _start(out_dir, want, th)
        timing = _compute(plant, th, chunk_dir, jobs, todo, tag, workers, client, progress, reference, bound)
    finally:
        if client is not None:
            client.close()
    metrics = analyse(out_dir, jobs, th, tag)
    metrics["reference"] = reference
    metrics["timing"] = timing
    _write_json(out_dir / "metrics.json", metrics)
    return metrics


def _compute(plant: Plant, th: Thresholds, chunk_dir: Path, jobs: list, todo: list, tag: str, workers: int,
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
        _save_chunk(_chunk_path(chunk_dir, job, tag), res)
        bar.update(1)

    t0 = time.perf_counter()
    if client is not None:
        from dask.distributed import as_completed
        futs = {client.submit(_chunk_job, plant, th, *j[1:], reference, bound, pure=False): j for j in todo}
        for fut in as_completed(futs):
            save(futs[fut], fut.result())
    elif workers > 1:
        from concurrent.futures import ProcessPoolExecutor, as_completed
        with ProcessPoolExecutor(workers, mp_context=pool_context()) as ex:
            futs = {ex.submit(_chunk_job, plant, th, *j[1:], reference, bound): j for j in todo}
            for fut in as_completed(futs):
                save(futs[fut], fut.result())
    else:
        for j in todo:
            save(j, _chunk_job(plant, th, *j[1:], reference, bound))
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
        path = _chunk_path(chunk_dir, j, tag)
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


def _tag(reference: bool, bound: bool = False) -> str:
    """Chunk file tag: the layout version, "c" appended for a tune with --reference, "b" with --bound."""
    return CHUNK_VERSION + ("c" if reference else "") + ("b" if bound else "")


def _chunk_path(chunk_dir: Path, job, tag: str = CHUNK_VERSION) -> Path:
    return Path(chunk_dir) / f"{job[0]}_{job[4]}_{tag}.npz"


def _load(chunk_dir, jobs, name, tag: str = CHUNK_VERSION):
    parts = [np.load(_chunk_path(chunk_dir, j, tag)) for j in jobs if j[0] == name]
    keys = ("first", "max", "m_L", "k_onset") + BANK_KEYS \
        + (("evidence",) if all("evidence" in p for p in parts) else ()) \
        + (("leak_flow_lpm",) if all("leak_flow_lpm" in p for p in parts) else ())
    return {k: np.concatenate([p[k] for p in parts]) for k in keys}


def _load_bin(m):
    return np.digitize(m, [b[1] for b in LOAD_BINS[:-1]])


def analyse(out_dir: Path, jobs, th: Thresholds, tag: str = CHUNK_VERSION) -> dict:
    """The metrics of the chunks of ``jobs`` in ``out_dir``/chunks; writes metrics.json (no NaN:
    null), metrics.md and roc.png there. Rates are fractions of runs, delays in s."""
    chunk_dir = Path(out_dir) / "chunks"
    healthy = _load(chunk_dir, jobs, "healthy", tag)
    hmax = healthy["max"][:, :, 2].max(axis=1)  # per run: max over hypotheses of g/h
    fa = _healthy_rates(healthy, th.false_alarm_level)
    scales = np.geomspace(0.25, 4, 17)
    roc = {"scale": scales.tolist(), "false_alarm": [float((hmax > s).mean()) for s in scales], "detection": {}}
    has_bound = "evidence" in healthy
    bnd = None
    if has_bound:
        bnd = (onset_bound.threshold(healthy["evidence"], th.false_alarm_level),
               isolate.margin_for(th.false_isolation_level))
    rows = []
    for fault, sizes in FAULT_SIZES.items():
        for size in sizes:
            name = f"{fault}_{size:g}"
            d = _load(chunk_dir, jobs, name, tag)
            rows.append(_fault_row(d, fault, size, bnd))
            ok_pre = d["max"][:, :, 0].max(axis=1)
            post = d["max"][:, :, 1].max(axis=1)
            roc["detection"][name] = [float(((post > s) & (ok_pre <= s)).mean()) for s in scales]
    smallest, smallest_by_load, smallest_bound, smallest_shown = _smallest_sizes(rows, has_bound)
    n_dec = sum(r["decisions_within_1s"] for r in rows)
    n_wrong = sum(r["wrong_decisions"] for r in rows)
    metrics = {"false_alarm_rate": fa["false_alarm_rate"], "false_alarm_by_load": fa["false_alarm_by_load"],
               "healthy_runs": fa["runs"], "trigger_rate": fa["trigger_rate"],
               **{k: fa[k] for k in ("false_alarms", "false_alarm_ci", "false_alarm_verdict")},
               "healthy_run_s": run_seconds(th, None), "fault_run_s": DURATION,
               "load_bins_kg": LOAD_BINS, "thresholds_source": th.source, "isolation": "likelihood", "rows": rows,
               "isolation_decisions_within_1s": n_dec, "wrong_isolation_decisions": n_wrong,
               "wrong_isolation_rate": n_wrong / n_dec if n_dec else float("nan"),
               "smallest_detected_and_isolated_95pct_within_1s": smallest,
               "smallest_detected_and_isolated_95pct_within_1s_by_load": smallest_by_load,
               "smallest_shown_95pct_within_1s": smallest_shown, "roc": roc}
    flows = _flow_totals(rows)
    if flows:
        metrics["flow_bins_lpm"], metrics["isolated_by_flow"] = FLOW_BINS_LPM, flows
    if any(j[0] == "healthy_long" for j in jobs):
        long = _healthy_rates(_load(chunk_dir, jobs, "healthy_long", tag), th.false_alarm_level)
        metrics["long_cycles"] = long
        k, n = fa["false_alarms"] + long["false_alarms"], fa["runs"] + long["runs"]
        metrics["all_healthy"] = {"runs": n, "false_alarm_rate": k / n, **_false_alarm_count(k, n, th.false_alarm_level)}
    if has_bound:
        metrics["bound"] = {"threshold_nats": bnd[0], "level": th.false_alarm_level, "margin_nats": bnd[1],
                            "healthy_runs": int(len(hmax)),
                            "smallest_isolable_95pct": smallest_bound}
    _write_json(Path(out_dir) / "metrics.json", metrics)
    reference = tag.startswith(CHUNK_VERSION + "c")
    (Path(out_dir) / "metrics.md").write_text("\n".join(_markdown(metrics, th, reference)) + "\n")
    _roc_figure(Path(out_dir) / "roc.png", roc)
    return metrics


def _healthy_rates(d: dict, level: float) -> dict:
    """The false-alarm figures of loaded healthy chunks ``d``: runs, false-alarm rate (runs with an
    alarm that stood: the bank confirmed it, when the chunks have the bank's verdicts; else any
    alarm), its :func:`fdi.rates.interval` and :func:`fdi.rates.verdict` against the stated
    false-alarm ``level``, the rate per load third (NaN: no run there) and the trigger rate (runs
    with any CUSUM alarm, confirmed or withdrawn)."""
    trigger_runs = d["max"][:, :, 2].max(axis=1) > 1.0
    fa_runs = d["conf_k"] >= 0 if "conf_k" in d else trigger_runs
    lb = _load_bin(d["m_L"])
    return {"runs": int(len(fa_runs)), "false_alarm_rate": float(fa_runs.mean()),
            **_false_alarm_count(int(fa_runs.sum()), len(fa_runs), level),
            "false_alarm_by_load": [float(fa_runs[lb == i].mean()) if (lb == i).any() else float("nan")
                                    for i in range(len(LOAD_BINS))],
            "trigger_rate": float(trigger_runs.mean())}


def _false_alarm_count(k: int, n: int, level: float) -> dict:
    """false_alarms (k), false_alarm_ci and false_alarm_verdict (<= ``level``) of k false alarms
    in n healthy runs."""
    return {"false_alarms": k, "false_alarm_ci": list(rates.interval(k, n)),
            "false_alarm_verdict": rates.verdict(k, n, level, at_least=False)}


def _fault_row(d: dict, fault: str, size: float, bnd: tuple | None) -> dict:
    """The metrics.json row of one fault case from its loaded chunks ``d``; ``bnd``: the bound's
    (threshold, margin) [nats] or None. 'wrong_isolation' = fraction of the decisions taken within
    1 s of the onset (the bank's) that named another fault hypothesis: the rate the stated
    false-isolation level is about."""
    k0 = d["k_onset"]  # (runs,) each run's own onset
    first = np.where(d["first"] >= 0, d["first"], 10**9)
    any_alarm = np.where(d["conf_k"] >= 0, d["conf_k"], 10**9)  # the first alarm that stood (the bank confirmed it)
    before = any_alarm < k0  # alarm before the onset: a false alarm, not a detection
    detected = (any_alarm < 10**9) & ~before
    within = detected & ((any_alarm - k0) * DT <= WITHIN_S)
    right = ("offset+" if size > 0 else "offset-") if fault == "offset" else fault
    ri = HYP.index(right)
    # the bank's decision, taken within 1 s of the onset
    decided = within & (d["iso_h"] >= 0) & (d["iso_k"] >= k0) & ((d["iso_k"] - k0) * DT <= WITHIN_S)
    isolated = decided & (d["iso_h"] == ri)
    wrong = decided & (d["iso_h"] != ri)
    delay = (any_alarm[detected] - k0[detected]) * DT
    lb = _load_bin(d["m_L"])
    row = {
        "fault": fault, "size": size, "unit": "%" if fault == "offset" else "L/min", "runs": int(len(first)),
        "detected_within_1s": float(within.mean()), "isolated_within_1s": float(isolated.mean()),
        "isolated_exclusive": float(isolated.mean()), "alarm_before_onset": float(before.mean()),
        "mean_delay_s": float(delay.mean()) if delay.size else float("nan"),
        "isolated_runs": int(isolated.sum()), "isolated_ci": list(rates.interval(isolated.sum(), len(first))),
        "isolated_verdict": rates.verdict(isolated.sum(), len(first), TARGET_RATE),
        "isolated_by_load": [float(isolated[lb == i].mean()) if (lb == i).any() else float("nan")
                             for i in range(len(LOAD_BINS))],
        "wrong_isolation": float(wrong.sum() / decided.sum()) if decided.any() else float("nan"),
        "decisions_within_1s": int(decided.sum()), "wrong_decisions": int(wrong.sum()),
    }
    if "leak_flow_lpm" in d:  # chunks from before session 28 have no flows
        row["leak_flow_median_lpm"] = float(np.median(d["leak_flow_lpm"]))
        row["isolated_by_flow"] = _by_flow(isolated, d["leak_flow_lpm"])
    if bnd is not None:
        ok, iso = onset_bound.verdicts(d["evidence"], fault, *bnd)
        row.update({"bound_detectable": float(ok.mean()), "bound_isolable": float(iso.mean()),
                    "bound_isolable_ci": list(rates.interval(iso.sum(), len(iso))),
                    "bound_median_nats": float(np.median(d["evidence"][:, onset_bound.HYPOTHESES.index(fault)]))})
    return row


def _by_flow(isolated: np.ndarray, flow_lpm: np.ndarray) -> list:
    """[[isolated, runs], ...] per bin of FLOW_BINS_LPM of the flow each run's leak passed."""
    b = np.digitize(flow_lpm, FLOW_BINS_LPM)
    return [[int(isolated[b == i].sum()), int((b == i).sum())] for i in range(len(FLOW_BINS_LPM) + 1)]


def _flow_totals(rows: list) -> dict:
    """{leak: [[isolated, runs], ...] per flow bin, every size of that leak together} of the rows
    that have flows (none: {})."""
    out = {}
    for r in (r for r in rows if "isolated_by_flow" in r):
        tot = out.setdefault(r["fault"], [[0, 0] for _ in r["isolated_by_flow"]])
        for t, (k, n) in zip(tot, r["isolated_by_flow"]):
            t[0] += k
            t[1] += n
    return out


def _smallest_sizes(rows: list, has_bound: bool) -> tuple:
    """({key: smallest |size| met}, {key: [per load third]}, {key: the bound's}, {key: smallest
    |size| shown met by its interval}) with keys K_int, K_extA, K_extB, offset+, offset-
    (:func:`_smallest`; sizes as in FAULT_SIZES)."""
    smallest, smallest_by_load, smallest_bound, smallest_shown = {}, {}, {}, {}
    for fault in FAULT_SIZES:
        for sign in ((1, -1) if fault == "offset" else (1,)):
            mine = [r for r in rows if r["fault"] == fault and np.sign(r["size"]) == sign]
            key = fault if fault != "offset" else ("offset+" if sign > 0 else "offset-")
            smallest[key] = _smallest(mine, lambda r: r["isolated_within_1s"] >= TARGET_RATE)
            smallest_shown[key] = _smallest(mine, lambda r: r["isolated_verdict"] == "met")
            if has_bound:
                smallest_bound[key] = _smallest(mine, lambda r: r["bound_isolable"] >= TARGET_RATE)
            smallest_by_load[key] = [_smallest(mine, lambda r, b=b: r["isolated_by_load"][b] >= TARGET_RATE)
                                     for b in range(len(LOAD_BINS))]
    return smallest, smallest_by_load, smallest_bound, smallest_shown


def _write_json(path: Path, obj) -> None:
    """``obj`` as JSON with every NaN / inf as null (json.dumps would write NaN: not JSON)."""
    path.write_text(json.dumps(_json_safe(obj), indent=2, allow_nan=False) + "\n")


def _json_safe(x):
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    return x


def _f2(v: float, digits: int = 2) -> str:
    """A rate or delay for metrics.md: ``digits`` decimals, '-' for none (NaN: no run to average)."""
    return "-" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _size_text(key: str, v: float | None) -> str:
    """A smallest size for metrics.md with its unit: offsets (fractions of spool travel) in %,
    leaks in L/min at 10 MPa; 'none': not met even at the largest tested size."""
    if v is None:
        return "none"
    return f"{abs(v) * 100:g} %" if key.startswith("offset") else f"{abs(v):g} L/min"


def _size_table(label_values: list) -> list:
    """A Markdown table of smallest sizes: one column per fault key, one row per (label, {key: size})."""
    keys = list(label_values[0][1])
    return (["| | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
            + [f"| {label} | " + " | ".join(_size_text(k, vals[k]) for k in keys) + " |"
               for label, vals in label_values])


def _markdown(m: dict, th: Thresholds, reference: bool) -> list:
    """The lines of metrics.md from the metrics ``m`` of :func:`analyse`."""
    bins = [f"{int(a)}-{int(round(b))} kg" for a, b in LOAD_BINS]
    wr = m["wrong_isolation_rate"]
    lines = ["# FDI tuning metrics", "",
             f"Thresholds: {th.source} (not fitted to these runs).", "",
             f"Position sensor: {th.position_sensor} ({POSITION_SENSOR_TEXT[th.position_sensor]}), as the "
             "thresholds were derived for.", "",
             *([f"Every machine was first calibrated on a healthy {REFERENCE_S:g} s reference recording of its own (another "
                 "load and input): `--reference`, as `fdi replay --reference` does.", ""] if reference else []),
             "Held-out healthy runs (the studies' sine, 2-4 s cycle and PRBS inputs): "
             + _healthy_line({**m, "runs": m["healthy_runs"]}, th, bins)
             + ("" if th.trigger_level is None else
                f" (the h were set for {th.trigger_level:g} of the nuisance study's healthy runs)"), "",
             *([f"Held-out healthy runs of the issue's 20-60 s extend/retract cycles (random period, amplitude "
                f"{LONG_CYCLES['amplitude_V'][0]:g}-{LONG_CYCLES['amplitude_V'][1]:g} V, phase and start position: "
                "some long strokes end on an end stop, some reverse in mid-stroke; not in the threshold studies): "
                + _healthy_line(m["long_cycles"], th, bins), "",
                f"All {m['all_healthy']['runs']} healthy runs: false-alarm rate "
                + _false_alarm_text(m["all_healthy"], th), ""]
               if "long_cycles" in m else []),
             f"Isolation decisions within 1 s of the onset (fault runs detected within 1 s): "
             f"{m['isolation_decisions_within_1s']}, of which wrong (named another fault hypothesis): "
             f"{m['wrong_isolation_decisions']}" + (f" = {wr:.3f}" if math.isfinite(wr) else ""), "",
             f"Each fault run steps in at its own onset, uniform in [{ONSET_MIN:g}, {ONSET_MAX:g}] s; "
             "'within 1 s', 'before onset' and the delay are per run from its own onset. "
             "'isolated' = detected within 1 s and "
             "the likelihood bank named the fault by 1 s after the onset (data up to its decision only). "
             "'wrong isolation' = fraction of the decisions within 1 s of the onset (the bank's) that named "
             "another fault hypothesis.", "",
             *_interval_lines(m["rows"])]
    cols = ["fault", "size", "runs", "within 1 s", "isolated", f"isolated: {rates.LEVEL * 100:g} % interval",
            f"vs {TARGET_RATE * 100:g} %",
            "wrong isolation", "alarm before onset", "mean delay [s]", *(f"isolated {b}" for b in bins)]
    lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in m["rows"]:
        cells = [r["fault"], _row_size(r), str(r["runs"]), _f2(r["detected_within_1s"]), _f2(r["isolated_within_1s"]),
                 _interval_text(r["isolated_ci"]), r["isolated_verdict"],
                 _f2(r["wrong_isolation"]),
                 _f2(r["alarm_before_onset"]), _f2(r["mean_delay_s"]), *(_f2(v) for v in r["isolated_by_load"])]
        lines.append("| " + " | ".join(cells) + " |")
    smallest, by_load = m["smallest_detected_and_isolated_95pct_within_1s"], \
        m["smallest_detected_and_isolated_95pct_within_1s_by_load"]
    lines += ["", "Smallest size detected and isolated within 1 s in >= 95 % of runs (that size and every larger "
              "tested size; per load third about a third of the runs each; 'none': not even the largest):", ""]
    lines += _size_table([("all loads", smallest),
                          (f"all loads, shown by the {rates.LEVEL * 100:g} % interval", m["smallest_shown_95pct_within_1s"])]
                         + [(b, {k: v[i] for k, v in by_load.items()}) for i, b in enumerate(bins)])
    if "isolated_by_flow" in m:
        lines += _flow_lines(m["isolated_by_flow"], m["flow_bins_lpm"])
    if "bound" in m:
        lines += _bound_lines(m["rows"], m["bound"], smallest)
    lines += ["",
              "Thresholds (CUSUM h [sigma s], drift %.2g sigma): %s" % (th.drift, json.dumps(th.h))]
    return lines


def _healthy_line(r: dict, th: Thresholds, bins: list) -> str:
    """metrics.md's words for the false-alarm figures ``r`` of a healthy population
    (:func:`_healthy_rates`: ``runs``, ``false_alarm_rate``, ``false_alarm_by_load``, ``trigger_rate``)."""
    return (f"{r['runs']} x {run_seconds(th, None):g} s; false-alarm rate (any alarm "
            f"{'that the bank confirmed ' if th.confirm_nats > 0 else ''}per run): "
            f"{_false_alarm_text(r, th)}; by load " + ", ".join(f"{b}: {_f2(v, 3)}"
                                                                 for b, v in zip(bins, r["false_alarm_by_load"]))
            + f"; runs with any CUSUM alarm (confirmed or withdrawn): {r['trigger_rate']:.3f}")


def _false_alarm_text(r: dict, th: Thresholds) -> str:
    """A population's false-alarm rate with its count, interval and verdict against the stated level."""
    return (f"{r['false_alarm_rate']:.3f} ({r['false_alarms']} of {r['runs']}; {rates.LEVEL * 100:g} % "
            f"interval {_interval_text(r['false_alarm_ci'], 4)}; <= {th.false_alarm_level:g}: {r['false_alarm_verdict']})")


def _flow_lines(by_flow: dict, edges: list) -> list:
    """metrics.md's table of isolation within 1 s by the flow the leak passed (:func:`_flow_totals`)."""
    heads = [f"< {edges[0]:g}"] + [f"{a:g}-{b:g}" for a, b in zip(edges[:-1], edges[1:])] + [f">= {edges[-1]:g}"]
    lines = ["", "Isolated within 1 s by the flow the leak passed in its scored second (Eqs. (41)-(43) at the run's "
             "true pressures; a leak rated at 10 MPa passes K sqrt(dp) at the machine's own pressure difference: "
             "K_int less where p_A and p_B balance, K_extB less where p_B is low), every size of a leak together, "
             "isolated / runs:", "", "| leak | " + " | ".join(f"{h} L/min" for h in heads) + " |",
             "|---|" + "---|" * len(heads)]
    for leak, cells in by_flow.items():
        lines.append(f"| {leak} | " + " | ".join(f"{k}/{n}" if n else "-" for k, n in cells) + " |")
    return lines


def _interval_lines(rows: list) -> list:
    """metrics.md's words on the rates' intervals, with the runs a case needs to show the target."""
    need = rates.runs_to_show(TARGET_RATE)
    few = min(r["runs"] for r in rows) < need
    return [f"Each rate is k of n runs. Its {rates.LEVEL * 100:g} % interval is the exact (Clopper-Pearson) one, "
            f"fdi/rates.py; 'vs {TARGET_RATE * 100:g} %' is 'met' where the whole interval lies above "
            f"{TARGET_RATE * 100:g} %, "
            "'not met' where it lies below, else 'undecided' at this many runs. Even with no miss, a case shows "
            f"{TARGET_RATE * 100:g} % only from {need} runs on" + (" (more --runs)." if few else "."), ""]


def _interval_text(ci: list, digits: int = 2) -> str:
    """A rate's interval [low, high] for metrics.md: 'low-high' ('-' where nothing was measured)."""
    return "-" if not all(math.isfinite(v) for v in ci) else f"{ci[0]:.{digits}f}-{ci[1]:.{digits}f}"


def _row_size(r: dict) -> str:
    """A row's fault size with sign and unit (offsets in %)."""
    return f"{r['size'] * (100 if r['fault'] == 'offset' else 1):+g} {r['unit']}"


def _bound_lines(rows: list, b: dict, ours: dict) -> list:
    """The metrics.md section of ``--bound``: our detector against the evidence at the known onset;
    ``ours``: our smallest sizes met, next to the bound's."""
    lines = ["", "## What the data carry within 1 s of the onset (`--bound`, fdi/bound.py)", "",
             "A bank started at the TRUE onset (which no detector knows), calibration as uncertain constants. "
             f"'detectable': its evidence for the true fault beats {b['threshold_nats']:.1f} nats, what the best "
             f"fault hypothesis beats in {b['level']:.0%} of the healthy runs; 'isolable': and it beats every other "
             f"fault by the isolation margin {b['margin_nats']:.1f} nats (the threshold is at least "
             f"ln(1 / {b['level']:g}) = {np.log(1 / b['level']):.1f} nats). A bound on what a likelihood test could do "
             "with this nuisance model, not a detector.", "",
             *([f"**Rough:** the threshold is read from {b['healthy_runs']} healthy runs; a {b['level']:.0%} quantile "
                f"needs at least {onset_bound.enough_healthy_runs(b['level'])} (--runs).", ""]
               if b["healthy_runs"] < onset_bound.enough_healthy_runs(b["level"]) else []),
             "| fault | size | ours: isolated within 1 s | bound: detectable | bound: isolable | "
             f"bound: isolable, {rates.LEVEL * 100:g} % interval | median evidence [nats] |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['fault']} | {_row_size(r)} | {_f2(r['isolated_within_1s'])} | {_f2(r['bound_detectable'])} | "
                     f"{_f2(r['bound_isolable'])} | {_interval_text(r['bound_isolable_ci'])} | "
                     f"{r['bound_median_nats']:.0f} |")
    return lines + ["", "Smallest size in >= 95 % of runs (that size and every larger tested size; 'none': not "
                    "even the largest):", ""] + _size_table([("ours: detected and isolated within 1 s", ours),
                                                              ("bound: isolable", b["smallest_isolable_95pct"])])


def _smallest(rows: list, passes) -> float | None:
    """The smallest |size| of ``rows`` from which on EVERY larger tested size also ``passes(row)``
    (None: not even the largest). A size that passes below one that fails is a lucky draw, not a
    size the tool can be trusted at. A NaN rate (a load third with no runs of that size) fails."""
    met = None
    for r in sorted(rows, key=lambda r: -abs(r["size"])):
        if not passes(r):
            break
        met = abs(r["size"])
    return met


def _roc_figure(path: Path, roc: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    for name, det in roc["detection"].items():
        color, style, marker, label = _roc_style(name)
        ax.plot(roc["false_alarm"], det, color=color, ls=style, marker=marker, ms=3, label=label, lw=0.9)
    ax.set_xlabel("false-alarm rate (held-out healthy runs with any alarm), thresholds scaled together")
    ax.set_ylabel("detected within 1 s (no alarm before onset)")
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _roc_style(name: str) -> tuple:
    """(colour, line style, marker, legend label) of the ROC curve of case ``name`` ("K_int_0.25"):
    each fault type its own colormap, line style and marker, larger sizes darker, so the 17
    curves stay apart (one 10-colour cycle repeats colours)."""
    fault, size = name.rsplit("_", 1)
    size = float(size)
    key = fault if fault != "offset" else ("offset+" if size > 0 else "offset-")
    cmap, style, marker = ROC_STYLE[key]
    sizes = sorted(abs(s) for s in FAULT_SIZES[fault] if np.sign(s) == np.sign(size))
    shade = 0.4 + 0.6 * (sizes.index(abs(size)) + 1) / len(sizes)
    import matplotlib
    label = f"offset {size * 100:+g} %" if fault == "offset" else f"{fault} {size:g} L/min"
    return matplotlib.colormaps[cmap](shade), style, marker, label
