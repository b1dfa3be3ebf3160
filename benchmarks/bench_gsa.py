"""Benchmark: both paper studies end to end, against SALib with a per-sample loop.

Side by side, in one run:

1. ours: ``paper_parameters`` (k = 7) and ``paper_leakage`` (k = 3) at N = 10000,
   i.e. 140,000 simulations of 4 s at 1 ms, then Sobol' indices of every output
   (3 signals x 401 = 1203 per study) with 1000 bootstrap resamples. Run in a
   child process so that its peak memory (max RSS) is measured alone.
2. baseline, end to end: SALib's ``sobol.sample`` + a plain per-sample Python loop
   around the same model (its compiled step, one sample per call: the step's vector
   intrinsics do not run as plain Python, so NUMBA_DISABLE_JIT is no longer an option)
   + SALib's ``sobol.analyze`` looped over the
   outputs, as SALib's docs do it. Timed on a subset and extrapolated.
3. analysis alone: SALib's ``sobol.analyze`` on our exact Y, looped over outputs
   (timed on a subset of outputs, extrapolated), against our vectorised analysis.

Usage::

    python benchmarks/bench_gsa.py [--n 10000] [--baseline-runs 3] [--salib-outputs 8]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CHUNK = 16384  # runs per checkpointed chunk (the CLI default for SAM studies)
PRECISION = "float32"  # bootstrap replicate products, as `samfdi gsa run` does; estimates stay float64
STUDIES = [ROOT / "scenarios" / "gsa" / "paper_parameters.toml", ROOT / "scenarios" / "gsa" / "paper_leakage.toml"]


def ours_child(N: int, out: str) -> None:
    """Both studies end to end (design, simulation, analysis); prints JSON timings."""
    import warnings

    from gsa import run, saltelli_design
    from gsa.studies import load_study

    warnings.simplefilter("ignore")
    timings = {}
    for path in STUDIES:
        spec = load_study(path)
        t0 = time.perf_counter()
        design = saltelli_design(spec.study.problem, N=N, seed=spec.seed)
        res = run(spec.study, design, Path(out) / spec.study.name, chunk_size=CHUNK, progress=False)
        t1 = time.perf_counter()
        sobol = res.analyze(n_boot=1000, seed=spec.seed, precision=PRECISION)
        t2 = time.perf_counter()
        np.save(Path(out) / f"{spec.study.name}_Y_head.npy", res.Y[:, :16])
        timings[spec.study.name] = {"simulate_s": t1 - t0, "analyze_s": t2 - t1, "runs": design.n_runs,
                                    "outputs": int(res.Y.shape[1]), "S1_first": float(sobol.S1[0, -1])}
    print(json.dumps(timings))


def run_ours(N: int, out: Path) -> tuple[dict, float, float]:
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, __file__, "--ours-child", str(N), str(out)],
                          capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    peak_gb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024**2
    return json.loads(done.stdout.strip().splitlines()[-1]), wall, peak_gb


def baseline_model_child(n_runs: int) -> None:
    """One SAM run per call (the compiled model, the first call compiling); prints seconds per run."""
    from gsa.studies import load_study

    spec = load_study(STUDIES[0])
    X = np.array([[0.0, 24.0, 35.0, 24.0, 35.0, 750.0, 2500.0]])
    times = []
    for _ in range(n_runs):
        t0 = time.perf_counter()
        spec.study.model(X)
        times.append(time.perf_counter() - t0)
    print(json.dumps(times))


def baseline_per_run_seconds(n_runs: int) -> float:
    done = subprocess.run([sys.executable, __file__, "--baseline-child", str(n_runs + 1)],
                          env=dict(os.environ), capture_output=True, text=True, check=True)
    return float(np.median(json.loads(done.stdout.strip().splitlines()[-1])[1:]))  # the first compiles


def salib_analyze_seconds(N: int, n_outputs: int) -> tuple[float, float]:
    """SALib sobol.analyze per output (1000 resamples) on Y with the study's shape; and ours on
    the same Y. Returns (SALib seconds per output, our seconds per output)."""
    from SALib.analyze import sobol as salib_sobol
    from SALib.sample import sobol as salib_sample

    from gsa import analyze, saltelli_design
    from gsa.studies import load_study

    spec = load_study(STUDIES[0])
    problem = spec.study.problem
    salib_problem = {"num_vars": len(problem.names), "names": list(problem.names),
                     "bounds": [list(b) for b in problem.bounds]}
    k = len(problem.names)
    t0 = time.perf_counter()
    salib_sample.sample(salib_problem, N, calc_second_order=False, scramble=True, seed=1)
    sample_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    # realistic Y: smooth functions of the inputs, one column per output
    design = saltelli_design(problem, N=N, seed=1)
    X = design.X
    W = rng.standard_normal((k, n_outputs))
    Y = np.tanh((X - X.mean(0)) / X.std(0) @ W) + 0.1 * ((X[:, :1] - X[:, :1].mean()) / X[:, :1].std()) ** 2
    t0 = time.perf_counter()
    for j in range(n_outputs):
        salib_sobol.analyze(salib_problem, _salib_order(Y[:, j], N, k), calc_second_order=False,
                            num_resamples=1000, seed=1)
    salib_per_output = (time.perf_counter() - t0) / n_outputs
    Ybig = np.tile(Y, (1, max(1, 1203 // n_outputs)))
    t0 = time.perf_counter()
    analyze(problem, design, Ybig, n_boot=1000, seed=1)
    ours_per_output = (time.perf_counter() - t0) / Ybig.shape[1]
    return salib_per_output, ours_per_output, sample_s


def _salib_order(y: np.ndarray, N: int, k: int) -> np.ndarray:
    """Our run order [A; B; AB_1..AB_k] -> SALib's interleaved rows [A, AB_1..AB_k, B] per sample."""
    blocks = y.reshape(k + 2, N)
    return np.stack([blocks[0], *blocks[2:], blocks[1]], axis=1).reshape(-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--baseline-runs", type=int, default=3)
    ap.add_argument("--salib-outputs", type=int, default=8)
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_gsa"))
    ap.add_argument("--ours-child", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--baseline-child", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.ours_child:
        ours_child(int(args.ours_child[0]), args.ours_child[1])
        return
    if args.baseline_child:
        baseline_model_child(args.baseline_child)
        return
    import shutil

    shutil.rmtree(args.out, ignore_errors=True)
    args.out.mkdir(parents=True)
    timings, wall, peak_gb = run_ours(args.n, args.out)
    n_runs = sum(t["runs"] for t in timings.values())
    n_outputs = sum(t["outputs"] for t in timings.values())
    sim = sum(t["simulate_s"] for t in timings.values())
    ana = sum(t["analyze_s"] for t in timings.values())
    print(f"ours     : {n_runs} runs + {n_outputs} outputs x 1000 bootstraps: {wall:.1f} s wall "
          f"(simulate {sim:.1f} s, analyse {ana:.1f} s), peak memory {peak_gb:.2f} GB "
          f"(targets: <= 20 s, <= 2 GB)")
    per_run = baseline_per_run_seconds(args.baseline_runs)
    salib_out, ours_out, sample_s = salib_analyze_seconds(args.n, args.salib_outputs)
    base_sim = per_run * n_runs
    base_ana = salib_out * n_outputs
    base_total = base_sim + base_ana + sample_s
    print(f"baseline : SALib sample {sample_s:.2f} s + per-sample Python loop {per_run:.2f} s/run "
          f"-> {base_sim / 3600:.1f} h + SALib analyze {salib_out:.2f} s/output -> {base_ana / 60:.1f} min "
          f"= {base_total / 3600:.2f} h (extrapolated from {args.baseline_runs} runs, {args.salib_outputs} outputs)")
    print(f"ratio    : end to end {base_total / wall:,.0f}x (target >= 300x); analysis alone "
          f"{salib_out / ours_out:,.0f}x (SALib {salib_out * 1e3:.0f} ms/output vs ours "
          f"{ours_out * 1e3:.2f} ms/output; target >= 50x)")


if __name__ == "__main__":
    main()
