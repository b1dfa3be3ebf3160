"""The issue's tuning figure, measured end to end: 1000 runs of 4 s on 2 cores.

    PYTHONPATH=. python benchmarks/bench_tune.py [--repeats 3] [--workers 2]

The runs are the tune's own (`fdi.tune`): 230 healthy runs and 46 runs of each of the 17 fault
cases (1012 runs, the `samfdi fdi tune --runs 230` fault runs, with the healthy runs cut from 20 s
to 4 s and the 20-60 s long cycles left out so that every run is 4 s long), each simulated,
filtered, tested and, where a test alarms, judged by the likelihood bank, on the tune's process
pool, chunks written into a chunk store as the tune writes them. Side by side: what a plain filterpy loop that
calls the model once per sigma point needs for the detecting filter alone of the same runs
(timed over 0.4 s of one run and scaled), which is a lower bound of its tune.
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
from fdi.montecarlo import make_batch  # noqa: E402

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


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
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
