"""Benchmark: the batch simulator against the per-run solve_ivp loop a user would write.

Runs, side by side in one process tree:

1. ours: 90,000 parameter sets (Table 1 box), each 4 s at T = 1 ms, keeping
   p_A, p_B and v every 10 ms, with ``sam.simulate_batch`` (numba, all cores);
2. baseline: the same model (the same right-hand side, Eq. (19), ``sam.rhs``, compiled)
   integrated by ``scipy.integrate.solve_ivp`` one run at a time, timed on a few runs
   (after one to compile) and extrapolated to 90,000. (The right-hand side's vector
   intrinsics do not run as plain Python, so NUMBA_DISABLE_JIT is no longer an option.)

Prints medians of repeated timings and the ratio. Usage::

    python benchmarks/bench_simulate.py [--runs 90000] [--repeats 3] [--baseline-runs 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

N_STEPS = 4000
DT = 1e-3
RECORD_EVERY = 10


def table1_params(n: int, seed: int = 0) -> np.ndarray:
    import sam
    from sam.constants import LPM

    box = {"offset": (-0.05, 0.05), "Q_N_PA": (15 * LPM, 35 * LPM), "dp_N_PA": (5e5, 40e5),
           "Q_N_BT": (15 * LPM, 35 * LPM), "dp_N_BT": (5e5, 40e5), "B_eff": (3e8, 1.2e9),
           "b": (2000.0, 5000.0)}
    rng = np.random.default_rng(seed)
    params = np.tile(sam.load_plant().vector(), (n, 1))
    for name, (lo, hi) in box.items():
        params[:, sam.P[name]] = rng.uniform(lo, hi, n)
    return params


def time_ours(n_runs: int, repeats: int) -> list[float]:
    import sam

    params = table1_params(n_runs)
    u = np.full(N_STEPS, 2.5)
    sam.simulate_batch(params[:2], u, DT, record_every=RECORD_EVERY, channels=("p_A", "p_B", "v"))  # compile
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = sam.simulate_batch(params, u, DT, record_every=RECORD_EVERY, channels=("p_A", "p_B", "v"))
        times.append(time.perf_counter() - t0)
        assert np.all(np.isfinite(res["p_A"]))
    return times


def baseline_child(n_runs: int) -> None:
    """Runs inside a subprocess with NUMBA_DISABLE_JIT=1: prints per-run times as JSON."""
    from scipy.integrate import solve_ivp

    import sam
    from sam.dynamics import N_DERIVED, derive, rhs

    params = table1_params(n_runs)
    t_eval = np.arange(0, N_STEPS + 1, RECORD_EVERY) * DT
    out = []
    for p in params:
        t0 = time.perf_counter()
        d = np.empty(N_DERIVED)
        derive(p, d)

        def f(_, s):
            ds = np.empty(7)
            rhs(s, 2.5, p, d, ds)
            return ds

        sol = solve_ivp(f, (0.0, N_STEPS * DT), sam.initial_state(p), t_eval=t_eval, rtol=1e-6,
                        atol=[1.0, 1.0, 1e-9, 1e-7, 1e-10, 1e-10, 1e-12])
        out.append(time.perf_counter() - t0)
        assert sol.success
    print(json.dumps(out))


def time_baseline(n_runs: int) -> list[float]:
    cmd = [sys.executable, __file__, "--baseline-child", str(n_runs + 1)]
    done = subprocess.run(cmd, env=dict(os.environ), capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])[1:]  # the first run compiles


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=90_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline-runs", type=int, default=3)
    ap.add_argument("--baseline-child", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.baseline_child:
        baseline_child(args.baseline_child)
        return
    ours = np.median(time_ours(args.runs, args.repeats))
    run_steps = args.runs * N_STEPS
    base_one = np.median(time_baseline(args.baseline_runs))
    base_all = base_one * args.runs
    print(f"ours     : {args.runs} runs x {N_STEPS} steps in {ours:.2f} s (median of {args.repeats}), "
          f"{ours / run_steps * 1e9:.1f} ns per run-step")
    print(f"baseline : solve_ivp per run, {base_one:.2f} s per run (median of {args.baseline_runs}), "
          f"extrapolated {base_all / 3600:.1f} h for {args.runs} runs")
    print(f"ratio    : {base_all / ours:,.0f}x faster (target: 90,000 runs <= 10 s: "
          f"{'met' if ours <= 10 else 'NOT met'})")


if __name__ == "__main__":
    main()
