"""What the lane kernel gives the UKF: replay and batched filtering, this tree against another
checkout (the code before the kernel), side by side in one run, alternated.

    git archive 5d9aea8 | tar -x -C /tmp/before      # the step before the lane kernel
    python benchmarks/bench_kernel_fdi.py --before /tmp/before [--rounds 3]

Each round runs, in a child process of each tree: one 4 s recording at 1 kHz replayed by the
batched UKF (x real time, best of 3), and 100 recordings of 4 s filtered in one batch (ms per run,
one core: the tune's work per run). Medians over the rounds, and the ratio.
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
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0

    one = min(timed(lambda: run_filter(runs.inp)) for _ in range(3))
    batch = timed(lambda: run_filter(mc.inp))
    print(json.dumps({"x_real_time": 4.0 / one, "ms_per_run": batch / 100 * 1e3}))


def measure(tree: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    done = subprocess.run([sys.executable, __file__, "--child"], env=env, cwd=tree, capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="a checkout of the code before the lane kernel")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child()
        return
    trees = {"before": args.before.resolve(), "lanes": ROOT}
    got = {k: [] for k in trees}
    for _ in range(args.rounds):
        for name, tree in trees.items():
            got[name].append(measure(tree))
    load = os.getloadavg()
    print(f"load average {load[0]:.1f}; medians of {args.rounds} alternated rounds, one thread")
    for key, unit in (("x_real_time", "x real time (one 4 s recording replayed)"),
                      ("ms_per_run", "ms per run (100 recordings in one batch)")):
        med = {k: float(np.median([r[key] for r in v])) for k, v in got.items()}
        print(f"{unit}: before {med['before']:.1f}, lanes {med['lanes']:.1f}")


if __name__ == "__main__":
    main()
