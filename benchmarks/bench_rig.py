"""Rig speed: a 20 s closed-loop recording (RK4 at 0.1 ms, the controller at 1 kHz, sensors) against
what a user would otherwise write: scipy's solve_ivp on the same right-hand side, restarted at every
controller sample (the input changes there), timed on the first second and extrapolated.

    python benchmarks/bench_rig.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

import rig
from rig.integrate import controller
from rig.layout import N_STATE, R
from rig.simulate import controller_settings, encoder_settings
from rig.sensors import encoder_reading

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "rig" / "healthy_closed_loop_steps.toml"


def baseline(sc, settings, seconds: float) -> float:
    """solve_ivp (LSODA, rtol 1e-8) from controller sample to controller sample, the rig's own RHS."""
    c = rig.build(sc.plant, settings, np.random.default_rng(0))
    y = rig.initial_state(c, sc.x0_m)
    ctrl, enc = controller_settings(sc, settings), encoder_settings(sc, settings)
    integral = 0.0
    t0 = time.perf_counter()
    for k in range(int(round(seconds / sc.dt))):
        u, integral = controller(encoder_reading(y[R.theta], enc), sc.control.setpoint[k], integral, k * sc.dt,
                                 ctrl, enc, sc.dt)

        def f(_, state, u=u):
            dy = np.empty(N_STATE)
            rig.derivatives(state, u, c, dy)
            return dy

        y = solve_ivp(f, (0.0, sc.dt), y, method="LSODA", rtol=1e-8, atol=1e-12).y[:, -1]
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    sc, settings = rig.load_rig_scenario(SCENARIO)
    rig.record(sc, settings)  # compile / load the cache
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        rig.record(sc, settings)
        times.append(time.perf_counter() - t0)
    ours = np.median(times)
    duration = sc.t[-1] + sc.dt
    base = baseline(sc, settings, 1.0) * duration
    print(f"rig      : {duration:g} s recording in {ours:.3f} s (median of {args.repeats}): "
          f"{duration / ours:.0f}x real time (target: 20 s in <= 10 s: {'met' if ours <= 10 else 'NOT met'})")
    print(f"baseline : solve_ivp (LSODA) per controller sample, extrapolated from 1 s: {base:.0f} s")
    print(f"ratio    : {base / ours:,.0f}x faster")


if __name__ == "__main__":
    main()
