"""``samfdi fdi tune``: the Monte Carlo evaluation of the detector. Held-out healthy runs give
the false-alarm rate; fault runs the detection rate within 1 s, delay and isolation accuracy
per fault type, size and load (:mod:`fdi.metrics`). The thresholds are NOT fitted here: they
come from the sensitivity studies (:mod:`fdi.study`, the shipped file or ``--thresholds``), so
every run of this Monte Carlo is held out from the threshold choice.

Each fault run steps in at its own random onset (:func:`draw_onsets`, from the chunk seed apart
from the draws of loads, inputs and nuisance); every scored window is per run. Healthy runs are
scored over the whole run. The protocol is :data:`fdi.montecarlo.TUNE`.

Work is split into chunks of a :class:`chunkstore.Store` in the output folder
(``DIR/manifest.json``, ``DIR/chunks/<name>_<seed>_<mode>.npz`` with their checksums): an
interrupted run resumes where it stopped, a folder made with other thresholds, plant or run
count is refused (:func:`fingerprint`), and the ``--reference`` / ``--bound`` modes are keyed
apart and share the folder.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from chunkstore import MANIFEST, Store, StoreError, compute
from sam import Plant, UserError
from sam.errors import output_folder

from . import bound as onset_bound
from . import calibration
from . import evaluate
from .config import FilterConfig
from .filter import run_filter
from .metrics import analyse, write_report
from .montecarlo import LEAKS, TUNE, leak_flow_lpm, make_batch, make_reference_batch
from .scoring import BANK_KEYS, HYP, SIZE_KEYS, bank_decisions, window_maxima  # noqa: F401 (HYP: the chunks' columns)
from .statistics import statistics
from .thresholds import Thresholds

#: the layout of the chunks (their keys and what made them): in the fingerprint and every key
CHUNK_VERSION = "x"
#: what a tune writes besides the store: in a folder that is not a tune folder these are the
#: user's own and are not overwritten without ``force``
OUTPUTS = ("metrics.md", "metrics.json", "thresholds_used.json", "rates.png")
#: what the manifest says of the chunks, for a person reading it
LAYOUT = {"chunks": "<case>_<seed>_<mode>.npz: per run of the chunk (fdi.tune.chunk_job)",
          "mode": "x, then c with --reference, b with --bound"}
#: chunk keys every mode writes
CHUNK_KEYS = ("first", "max", "m_L", "k_onset")


def draw_onsets(n: int, seed: int) -> np.ndarray:
    """(n,) fault onsets [s] of a chunk: uniform in TUNE.onset_range_s, on the sample grid, from
    their own generator (the chunk seed, 17) so the chunk's other draws are unchanged."""
    rng = np.random.default_rng((seed, 17))
    return np.round(rng.uniform(*TUNE.onset_range_s, n) / TUNE.dt) * TUNE.dt


def chunk_job(plant: Plant, th: Thresholds, fault, size, n, seed, inputs: str = "standard", reference: bool = False,
               bound: bool = False, cfg: FilterConfig | None = None):
    """Filter one chunk; per run and hypothesis: first alarm index (-1: none) and the
    maxima of g/h before the run's onset, within 1 s after it, and over the run; per run
    the onset index ``k_onset`` and, in a leak's runs, ``leak_flow_lpm``: the flow the leak
    passed in the scored second (:func:`fdi.montecarlo.leak_flow_lpm`). ``reference``: each
    machine is first calibrated on a healthy reference recording of its own
    (:func:`fdi.montecarlo.make_reference_batch`, :mod:`fdi.calibration`), as ``fdi replay
    --reference`` does. ``bound``: also the evidence
    of :func:`fdi.bound.onset_evidence` per run (healthy runs: at the onsets a fault run of
    the chunk would have). ``cfg``: the filter (default: the shipped one)."""
    onset = TUNE.onset_range_s[0] if fault is None else draw_onsets(n, seed)
    sensor = th.derived.position_sensor
    runs = make_batch(plant, n, seed, fault=fault, size=size, duration=run_seconds(th, fault), onset=onset,
                      position_sensor=sensor, inputs=inputs)
    inp, cfg = runs.inp, FilterConfig() if cfg is None else cfg
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


def timed_chunk_job(job, *args) -> dict:
    """``job(*args)`` (:func:`chunk_job` or :func:`recorded_chunk_job`) with the seconds it took
    (``compute_s``, a worker's wall time), kept in the chunk so that a resumed tune can state the
    cost of all its runs, not only of the last part."""
    t0 = time.perf_counter()
    res = job(*args)
    return {**res, "compute_s": np.float64(time.perf_counter() - t0)}


def recorded_chunk_job(recorder, plant: Plant, th: Thresholds, fault, size, n, seed, inputs: str = "standard"):
    """A chunk of runs that ``recorder`` records (another simulator, e.g. the rig), each scored as
    ``fdi evaluate`` scores a labelled recording (:func:`fdi.evaluate.score`): the keys of
    :func:`chunk_job` and the reported size. ``recorder(fault, size, n, seed, inputs)``: n
    recordings with ``true_*`` columns, the fault (None: healthy) of ``size`` (leaks in L/min at
    10 MPa, the offset a fraction) stepping in at an onset of the recorder's own choosing."""
    parts = []
    for i, rec in enumerate(recorder(fault, size, n, seed, inputs)):
        parts.append(evaluate.score(rec, evaluate.label(rec, f"run {i} of chunk {seed}"), plant, th))
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def run_seconds(th: Thresholds, fault) -> float:
    """Length [s] of a tune run: TUNE.fault_run_s for fault runs, the thresholds' run_length_s (the
    run their false-alarm level is stated for) for healthy ones."""
    return TUNE.fault_run_s if fault is not None else th.derived.run_length_s


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
             bound: bool = False, force: bool = False, recorder=None, source: str = "sam") -> dict:
    """The Monte Carlo of ``n_runs`` healthy runs (and the fault runs of :func:`jobs_of`) on the
    ``plant`` with ``thresholds`` (default: the shipped ones) into ``out_dir`` (resumable), with a
    progress bar if ``progress``; ``reference``: every machine calibrated on a
    healthy reference recording first; ``bound``: also the evidence at the known onset
    (:mod:`fdi.bound`; about three times the work). Each mode's chunks are keyed apart.
    ``force``: overwrite the files a tune writes in a folder that is not a tune folder.
    ``workers`` > 1: a local process pool (spawned: a calling script needs
    ``if __name__ == "__main__":``); ``scheduler``: a dask.distributed cluster instead.
    ``recorder``: None, runs of ``sam``'s batched simulator (:func:`fdi.montecarlo.make_batch`);
    else recordings of another simulator, named ``source`` (:func:`recorded_chunk_job`; the CLI's
    ``--source rig`` gives the rig's, ``rig.population.tune_recordings``), each scored with its size.
    Every refusal (``out_dir`` not a writable folder, made with other settings, holding the
    user's files, another run writing into it) is a UserError raised before any computing."""
    out_dir = Path(out_dir)
    th = Thresholds.shipped() if thresholds is None else thresholds
    dt = th.derived.sample_dt_s
    if abs(dt / TUNE.dt - 1.0) > 1e-9:
        raise UserError(f"--thresholds: derived for {1 / dt:.4g} Hz recordings; the tune simulates and "
                        f"filters at {1 / TUNE.dt:g} Hz only ({th.derived.source})")
    if recorder is not None and (reference or bound):
        raise UserError(f"--reference and --bound: with --source sam only (the {source} has no batched reference runs)")
    jobs = jobs_of(n_runs)
    want = fingerprint(plant, th, n_runs, None if recorder is None else source)
    output_folder(out_dir, create=False)  # created by the store: a refused run leaves nothing behind
    _check_folder(out_dir, want, force)
    if scheduler:
        _check_scheduler(scheduler)
    try:
        with Store.open(out_dir, want, resume=True, layout=LAYOUT) as store:
            (out_dir / "thresholds_used.json").write_text(th.to_json() + "\n")
            cases, timing = compute_chunks(store, plant, th, jobs, mode_tag(reference, bound), workers=workers,
                                           scheduler=scheduler, progress=progress, reference=reference, bound=bound,
                                           recorder=recorder)
            return summarise(out_dir, cases, th, reference, timing, source)
    except StoreError as exc:
        raise UserError(str(exc)) from None


def compute_chunks(store: Store, plant: Plant, th: Thresholds, jobs: list, tag: str, *, workers: int = 1,
                   scheduler: str | None = None, progress: bool = False, reference: bool = False,
                   bound: bool = False, recorder=None) -> tuple[dict, dict]:
    """Every chunk of ``jobs`` in mode ``tag`` from ``store``, the missing ones computed (on
    ``scheduler``, ``workers`` local processes, or here) and saved as each finishes: (case name ->
    its runs' arrays in job order (:func:`gather`), the timing (:func:`timing`))."""
    if recorder is None:
        tasks = {chunk_key(j, tag): (chunk_job, plant, th, *j[1:], reference, bound) for j in jobs}
    else:
        tasks = {chunk_key(j, tag): (recorded_chunk_job, recorder, plant, th, *j[1:]) for j in jobs}
    sizes = {chunk_key(j, tag): j[3] for j in jobs}
    executor = "dask" if scheduler else "processes" if workers > 1 else "inline"
    chunks, computed = {}, []
    t0 = time.perf_counter()
    pool = workers if executor == "processes" else None
    for chunk in compute(store, timed_chunk_job, tasks, executor=executor, workers=pool, scheduler=scheduler,
                         progress=progress, desc="fdi tune", unit="run", sizes=sizes):
        chunks[chunk.key] = chunk.arrays
        if not chunk.reused:
            computed.append(chunk.key)
    return gather(chunks, jobs, tag), timing(chunks, sizes, computed, time.perf_counter() - t0, workers)


def timing(chunks: dict, sizes: dict, computed: list, wall_s: float, workers: int) -> dict:
    """What a tune cost: this call's wall time ``wall_s`` [s] over the chunks it ``computed`` (keys;
    ``sizes``: key -> runs), and over every chunk of ``chunks`` that recorded its ``compute_s``
    (chunks of an older samfdi did not) the worker-seconds per 1000 runs, which a resumed tune's
    wall time does not tell."""
    n_now = sum(sizes[k] for k in computed)
    timed = [k for k, a in chunks.items() if "compute_s" in a]
    worker_s, n_timed = sum(float(chunks[k]["compute_s"]) for k in timed), sum(sizes[k] for k in timed)
    return {"runs_computed": n_now, "wall_s": wall_s, "workers": workers,
            "s_per_1000_runs": wall_s / max(n_now, 1) * 1000, "chunks_computed": len(computed), "chunks": len(chunks),
            "runs": sum(sizes[k] for k in chunks), "runs_timed": n_timed, "worker_s": worker_s,
            "worker_s_per_1000_runs": worker_s / n_timed * 1000 if n_timed else float("nan")}


def timing_text(tm: dict) -> str:
    """A tune's :func:`timing` in words: this call's wall time, and what every timed chunk cost."""
    total = (f"{tm['runs_timed']} runs timed in their chunks: {tm['worker_s']:.1f} worker-s "
             f"({tm['worker_s_per_1000_runs']:.0f} worker-s per 1000 runs)") if tm["runs_timed"] else \
        "their chunks hold no timings (made by an older samfdi)"
    if tm["chunks_computed"] == 0:  # a re-run of a finished tune: say so rather than "0 runs in 0.0 s"
        return f"nothing to compute: all {tm['chunks']} chunks were already in the store; {total}"
    now = (f"{tm['runs_computed']} runs in {tm['wall_s']:.1f} s with {tm['workers']} worker(s) "
           f"({tm['s_per_1000_runs']:.0f} s per 1000 runs")
    if tm["chunks_computed"] == tm["chunks"]:
        return f"{now})"
    return (f"{now}: this run's part only; {tm['chunks'] - tm['chunks_computed']} of {tm['chunks']} chunks "
            f"were resumed from the store); all {tm['runs']} runs: {total}")


def fingerprint(plant: Plant, th: Thresholds, n_runs: int, source: str | None = None) -> dict:
    """What a tune folder's chunks depend on besides their job and mode: the chunk layout, the
    run count (it sets the chunks' sizes and the fault runs per case), hashes (sha256) of the
    thresholds as JSON and of the plant vector (float64 bytes), and the runs' ``source`` when it
    is not sam's batched simulator."""
    vec = np.ascontiguousarray(plant.vector(), dtype=np.float64)
    return {"job": "fdi tune", "layout": CHUNK_VERSION, "runs": int(n_runs),
            "thresholds_sha256": hashlib.sha256(th.to_json().encode()).hexdigest(),
            "plant_sha256": hashlib.sha256(vec.tobytes()).hexdigest(), **({"source": source} if source else {})}


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
    if old.get("source", "sam") != new.get("source", "sam"):
        out.append(f"--source {old.get('source', 'sam')} there, {new.get('source', 'sam')} now")
    if old.get("layout") != new["layout"]:
        out.append(f"chunk layout {old.get('layout')!r} there (another samfdi version), {new['layout']!r} now")
    return out


def _check_folder(out_dir: Path, want: dict, force: bool) -> None:
    """Refuse (UserError), in the words of the command line, a tune folder made with other
    settings or by an older samfdi, and a folder that is no tune folder but holds a file the tune
    writes unless ``force`` (the store itself refuses a folder of chunks of unknown origin)."""
    hint = "use another --out, or the same settings to resume"
    if (out_dir / "tune.json").exists():
        raise UserError(f"{out_dir}: a tune folder of an older samfdi (tune.json; its chunks have no checksums); "
                        "use another --out")
    path = out_dir / MANIFEST
    if path.exists():
        try:
            old = json.loads(path.read_text()).get("fingerprint", {})
        except (OSError, ValueError, AttributeError):
            return  # the store names what is wrong with it
        diffs = _differences(old, want)
        if diffs:
            raise UserError(f"{out_dir}: a tune folder made with other settings: {'; '.join(diffs)}; {hint}")
        return
    mine = [f for f in OUTPUTS if (out_dir / f).exists()]
    if mine and not force:
        raise UserError(f"{out_dir}: already holds {', '.join(mine)} and is not a tune folder (no {MANIFEST}); "
                        "use another --out, or --force to overwrite")


def _check_scheduler(scheduler: str) -> None:
    """Refuse (UserError) a dask scheduler that does not answer within dask's connect timeout,
    before the store is opened (the store would try for 30 s behind a progress bar)."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise UserError("--scheduler needs dask[distributed]") from None
    try:
        Client(scheduler).close()
    except (OSError, TimeoutError, ValueError) as exc:  # ValueError: a malformed address
        raise UserError(f"cannot reach the dask scheduler at {scheduler}: {' '.join(str(exc).split())}") from None


def mode_tag(reference: bool, bound: bool = False) -> str:
    """A chunk key's mode: the layout version, "c" appended for a tune with --reference, "b" with --bound."""
    return CHUNK_VERSION + ("c" if reference else "") + ("b" if bound else "")


def chunk_key(job, tag: str = CHUNK_VERSION) -> str:
    """The store key of a job's chunk in mode ``tag``."""
    return f"{job[0]}_{job[4]}_{tag}"


def gather(chunks: dict, jobs: list, tag: str = CHUNK_VERSION) -> dict:
    """Case name -> the arrays of its chunks (``chunks``: key -> arrays) joined in job order."""
    cases = {}
    for name in dict.fromkeys(j[0] for j in jobs):
        parts = [chunks[chunk_key(j, tag)] for j in jobs if j[0] == name]
        keys = CHUNK_KEYS + BANK_KEYS + tuple(k for k in ("evidence", "leak_flow_lpm", *SIZE_KEYS, "true_size")
                                              if all(k in p for p in parts))
        cases[name] = {k: np.concatenate([p[k] for p in parts]) for k in keys}
    return cases


def summarise(out_dir: Path, cases: dict, th: Thresholds, reference: bool = False, timing: dict | None = None,
              source: str = "sam") -> dict:
    """The metrics of ``cases`` (:func:`gather`; :func:`fdi.metrics.analyse`), written into
    ``out_dir`` as metrics.json, metrics.md and rates.png; ``timing``: this run's, if it computed."""
    metrics = analyse(cases, th)
    metrics["reference"] = reference
    metrics["source"] = source
    if timing is not None:
        metrics["timing"] = timing
    write_report(out_dir, metrics, th, reference)
    return metrics
