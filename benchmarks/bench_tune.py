"""The issue's tuning figure, measured end to end: 1000 runs of 4 s on 2 cores.

    PYTHONPATH=. python benchmarks/bench_tune.py [--repeats 3] [--workers 2]

The runs are the tune's own (`fdi.tune`): 230 healthy runs and 46 runs of each of the 17 fault
cases (1012 runs, the `samfdi fdi tune --runs 230` fault runs, with the healthy runs cut from 20 s
to 4 s and the 20-60 s long cycles left out so that every run is 4 s long), each simulated,
filtered, tested and, where a test alarms, judged by the likelihood bank, on the tune's process
pool, chunks written into a chunk store as the tune writes them. Side by side: what a plain filterpy loop that
calls the model once per sigma point needs for the detecting filter alone of the same runs
(timed over 0.4 s of one run and scaled), which is a lower bound of its tune.

``--source rig`` times the rig-drawn tune instead (``samfdi fdi tune --source rig``), per run and
one process: recording on the rig (rig/population.py's development form) and scoring as
``fdi evaluate`` scores (filter, tests, bank, size), healthy 20-60 s runs and faulty runs with
their onset at 4-8 s, against the sam-drawn tune's batched work per run.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from chunkstore import Store  # noqa: E402
from sam import load_plant  # noqa: E402
from fdi import FilterConfig, Thresholds, tune  # noqa: E402
from fdi.filter import initial_mean  # noqa: E402
from fdi import evaluate  # noqa: E402
from fdi.montecarlo import make_batch  # noqa: E402
from rig.population import DEVELOPMENT, simulate_run  # noqa: E402
from sam.plant import default_plant_path  # noqa: E402

RUN_S = 4.0  #: the issue's run length [s]
N_HEALTHY = 230  #: the healthy runs of docs/fdi.md's tune (`--runs 230`)


def tune_jobs() -> list:
    """The tune's chunks of ``--runs 230`` without its long cycles: 230 healthy + 17 x 46 fault runs."""
    return [j for j in tune.jobs_of(N_HEALTHY) if j[0] != "healthy_long"]


def time_tune(plant, th: Thresholds, jobs: list, workers: int) -> float:
    """Wall time [s] of one tune of ``jobs`` on ``workers`` processes (the tune's own pool, worker
    start-up included), into a fresh chunk store."""
    with tempfile.TemporaryDirectory() as tmp, Store.open(tmp, {"bench": "tune"}) as store:
        return tune.compute_chunks(store, plant, th, jobs, "bench", workers=workers)[1]["wall_s"]


def filterpy_seconds_per_run(plant, th: Thresholds, n_ref: int = 400) -> float:
    """Seconds a plain filterpy loop (model once per sigma point) needs to filter one 4 s run."""
    from test_fdi_ukf import _filterpy_reference

    runs = make_batch(plant, 1, 1000, duration=RUN_S, position_sensor=th.derived.position_sensor)
    cfg = FilterConfig()
    z0 = initial_mean(runs.inp, cfg)
    P0 = np.diag((cfg.noise_vectors()[1] / cfg.state_scale()) ** 2)[None].copy()
    short = replace(runs.inp, **{k: getattr(runs.inp, k)[:, :n_ref] for k in ("u", "pA", "pB", "pos")})
    t0 = time.perf_counter()
    _filterpy_reference(short, cfg, z0, P0)
    return (time.perf_counter() - t0) * runs.inp.u.shape[1] / n_ref


def rig_costs(plant, th: Thresholds, n: int) -> dict:
    """Median seconds per run, one process, of the rig-drawn tune's two halves (record, score) for
    n healthy and n faulty (K_extB 0.25 L/min) runs, with the simulated seconds per run."""
    out = {}
    for kind, fault, size, seed in (("healthy", None, 0.0, 1000), ("faulty", "K_extB", 0.25, 500_000)):
        rec_s, score_s, sim_s = [], [], []
        for i in range(n):
            t0 = time.perf_counter()
            rec = simulate_run(default_plant_path(), DEVELOPMENT, seed, i, fault, size)
            t1 = time.perf_counter()
            evaluate.score(rec, evaluate.label(rec, "run"), plant, th)
            rec_s.append(t1 - t0)
            score_s.append(time.perf_counter() - t1)
            sim_s.append(float(rec.t[-1]))
        out[kind] = {"record_s": float(np.median(rec_s)), "score_s": float(np.median(score_s)),
                     "run_s": float(np.median(sim_s))}
    return out


def sam_costs(plant, th: Thresholds, n: int) -> dict:
    """Seconds per run, one process, of the sam-drawn tune's chunks of n runs (batched): healthy 20 s,
    faulty 4 s (K_extB 0.25 L/min)."""
    out = {}
    for kind, fault, size in (("healthy", None, 0.0), ("faulty", "K_extB", 0.25)):
        tune.chunk_job(plant, th, fault, size, 1, 999)  # its first call compiles (once per install)
        t0 = time.perf_counter()
        tune.chunk_job(plant, th, fault, size, n, 1000)
        out[kind] = (time.perf_counter() - t0) / n
    return out


def main_rig(n: int) -> None:
    plant, th = load_plant(), Thresholds.shipped()
    warm = simulate_run(default_plant_path(), DEVELOPMENT, 1, 0, "K_extB", 0.25)  # compiles (once per install)
    evaluate.score(warm, evaluate.label(warm, "warm-up"), plant, th)
    rig = rig_costs(plant, th, n)
    sam = sam_costs(plant, th, 2 * n)
    for kind in ("healthy", "faulty"):
        r = rig[kind]
        print(f"{kind} run, rig-drawn ({r['run_s']:.0f} s simulated): record {r['record_s']:.2f} s + score "
              f"{r['score_s']:.2f} s = {r['record_s'] + r['score_s']:.2f} s per run; sam-drawn "
              f"({th.derived.run_length_s:g} s healthy / 4 s faulty, batched): {sam[kind]:.2f} s per run")
    h, f = (rig[k]["record_s"] + rig[k]["score_s"] for k in ("healthy", "faulty"))
    print(f"`fdi tune --source rig --runs 100` (100 + 50 healthy, 17 x 20 faulty): about "
          f"{(150 * h + 340 * f) / 60:.0f} min on one core; --source sam: {(150 * sam['healthy'] + 340 * sam['faulty']) / 60:.1f} min")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--source", choices=("sam", "rig"), default="sam",
                    help="sam: the batched tune end to end (default); rig: the rig-drawn tune's cost per run")
    ap.add_argument("--runs", type=int, default=5, help="--source rig: runs of each kind timed")
    args = ap.parse_args(argv)
    if args.source == "rig":
        main_rig(args.runs)
        return
    plant = load_plant()
    th = Thresholds.shipped().with_(run_length_s=RUN_S)
    jobs = tune_jobs()
    n_runs = sum(j[3] for j in jobs)
    n_healthy = sum(j[3] for j in jobs if j[1] is None)
    # no warm-up here: each worker loads the numba cache itself, as in a user's tune
    walls = []
    for r in range(args.repeats):
        walls.append(time_tune(plant, th, jobs, args.workers))
        print(f"  tune {r + 1}: {walls[-1]:.1f} s", flush=True)
    med = float(np.median(walls))
    per_1000 = med / n_runs * 1000
    loop = filterpy_seconds_per_run(plant, th) * n_runs / args.workers
    print(f"fdi tune, {n_runs} runs of {RUN_S:g} s ({n_healthy} healthy, {n_runs - n_healthy} faulty), "
          f"{args.workers} worker processes: median {med:.1f} s (min {min(walls):.1f}, max {max(walls):.1f}) "
          f"-> {per_1000:.1f} s per 1000 runs (target <= 60 s)")
    print(f"plain filterpy loop, the detecting filter alone of the same runs on {args.workers} cores: "
          f"{loop:.0f} s ({loop / med:.0f}x our whole tune)")


if __name__ == "__main__":
    main()
