"""What the model's step gives the UKF: replay and batched filtering, this tree against another
checkout, side by side in one run, alternated.

    git archive fb92257 | tar -x -C /tmp/before      # e.g. the filter before its lane blocks
    python benchmarks/bench_kernel_fdi.py --before /tmp/before [--rounds 5]

Each round runs, in a child process of each tree (their order swapped every round): one 4 s
recording at 1 kHz filtered by the batched UKF (x real time, best of 3), and 100 recordings of
4 s filtered in one batch (ms per run, one core: the tune's filter work per run), each by the
wall clock and by the process's CPU time. Medians over the rounds, the ratios of the medians with
the range of the rounds' ratios, and the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def child() -> None:
    import numba

    from fdi.montecarlo import make_batch
    from fdi.synth import input_signal, profile, simulate_runs
    from sam import load_plant
    from sam.hydraulics import leak_coefficient

    try:
        from fdi import run_filter  # fdi's public face, since its redesign
    except ImportError:
        from fdi.ukf import run_filter  # before it (the code before the lane kernel)

    numba.set_num_threads(1)
    plant = load_plant()
    t = np.arange(4001) * 1e-3
    u = input_signal("sine", t, amplitude=3.0, frequency=0.25)
    runs = simulate_runs(plant.vector()[None], u, 1e-3, faults={"K_extA": profile("step", leak_coefficient(1.0), t, 2.0)})
    mc = make_batch(plant, 100, 1)
    run_filter(runs.inp), run_filter(mc.inp)  # compile / load the cache

    def timed(fn):
        """(wall, CPU) seconds of fn(): on a shared machine the CPU time is the steadier."""
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        return np.array([time.perf_counter() - t0, time.process_time() - c0])

    one = np.min([timed(lambda: run_filter(runs.inp)) for _ in range(3)], axis=0)
    batch = timed(lambda: run_filter(mc.inp))
    print(json.dumps({"x_real_time": 4.0 / one[0], "ms_per_run": batch[0] / 100 * 1e3,
                      "x_real_time_cpu": 4.0 / one[1], "ms_per_run_cpu": batch[1] / 100 * 1e3}))


def measure(tree: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    done = subprocess.run([sys.executable, __file__, "--child"], env=env, cwd=tree, capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="a checkout of the code to compare with (needed)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child()
        return
    if args.before is None:
        ap.error("--before DIR is needed: a checkout of the code to compare with")
    trees = {"before": args.before.resolve(), "this tree": ROOT}
    got = {k: [] for k in trees}
    load0 = os.getloadavg()
    for r in range(args.rounds):
        for name in list(trees)[::1 if r % 2 == 0 else -1]:  # neither tree always runs first
            got[name].append(measure(trees[name]))
    load1 = os.getloadavg()
    print(f"medians of {args.rounds} alternated rounds, one thread; load average (1, 5, 15 min) "
          f"{load0[0]:.1f} {load0[1]:.1f} {load0[2]:.1f} before, {load1[0]:.1f} {load1[1]:.1f} {load1[2]:.1f} after")
    for key, unit, faster in (("x_real_time", "x real time (one 4 s recording filtered), wall", 1),
                              ("x_real_time_cpu", "x real time (one 4 s recording filtered), CPU", 1),
                              ("ms_per_run", "ms per run (100 recordings in one batch), wall", -1),
                              ("ms_per_run_cpu", "ms per run (100 recordings in one batch), CPU", -1)):
        before, this = (np.array([r[key] for r in got[k]]) for k in trees)
        gain = (this / before) ** faster  # > 1: this tree is faster
        print(f"{unit}: before {np.median(before):.1f}, this tree {np.median(this):.1f}; speed-up "
              f"{(np.median(this) / np.median(before)) ** faster:.2f}x (rounds {gain.min():.2f}-{gain.max():.2f})")


if __name__ == "__main__":
    main()
