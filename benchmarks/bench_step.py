"""The model's step against the rig: how far sam is from converged physics, and what converging costs.

Two parts (issue 32, part 2):

1. ``--table``: every scheme (Euler, semi-implicit, Heun, RK4) at every internal step (1, 0.5,
   0.25, 0.1 ms) on rig recordings: its fit to the rig, its discretisation error (against sam
   itself at RK4 0.01 ms under the same input) and its cost per run-step. The recordings:
   ``scenarios/rig/healthy_open_loop_cycle.toml`` and an open-loop step series (sam driven by the
   same u), ``healthy_closed_loop_steps.toml`` replayed (sam driven open-loop by the u the rig's
   controller logged, as the filter and the mismatch diagnosis use a recording) and in the loop
   (sam stepped from Python under the same controller and encoder as the rig's).
2. default: the cost of the estimation default against today's Eq. (22) at 1 ms, side by side,
   alternating, as ``bench_simulate.py`` measures (runs of the Table 1 box, 4 s at 1 ms).

    python benchmarks/bench_step.py --table [--runs 2000]
    python benchmarks/bench_step.py [--runs 20000] [--rounds 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import rig  # noqa: E402
import sam  # noqa: E402
from bench_simulate import table1_params  # noqa: E402
from discrepancy.simulation import fit_percent  # noqa: E402
from rig.integrate import controller  # noqa: E402
from rig.simulate import controller_settings, encoder_settings  # noqa: E402
from rig.sensors import encoder_reading  # noqa: E402
from sam.geometry import joint_angle  # noqa: E402
from sam.scenario import scenario_from_table  # noqa: E402

SCHEMES = ("euler", "semi_implicit", "heun", "rk4")
STEPS_MS = (1.0, 0.5, 0.25, 0.1)
REFERENCE = {"substeps": 100, "scheme": "rk4"}  # sam at 0.01 ms: converged to well below a pascal
SIGMA = 15e3  #: Pa, the rig's transmitter noise
#: The estimation default (the cheapest setting whose discretisation error is below SIGMA).
DEFAULT = {"substeps": 1, "scheme": "euler"}
ESTIMATION = {"substeps": 1, "scheme": "heun"}


def rig_runs():
    """(name, scenario, rig settings) of the recordings the table is measured on."""
    steps = scenario_from_table({
        "duration_s": 12.0, "seed": 5, "load": {"m_L_kg": 494.0}, "initial": {"x_m": 0.05},
        "input": {"kind": "pwl_csv", "file": str(ROOT / "benchmarks" / "step_series.csv")},
    }, ROOT / "benchmarks" / "step_series.toml")
    out = [("open-loop steps", steps, rig.RigSettings())]
    for name in ("healthy_open_loop_cycle", "healthy_closed_loop_steps"):
        sc, settings = rig.load_rig_scenario(ROOT / "scenarios" / "rig" / f"{name}.toml")
        out.append((name.replace("healthy_", "").replace("_", " "), sc, settings))
    return out


def sam_open_loop(sc, u, setting):
    """sam on the input u (n,) from the scenario's initial state: {p_A, p_B, x} (n + 1,)."""
    p = sc.plant.vector()
    res = sam.simulate_batch(p, u, sc.dt, x0=sam.initial_state(p, sc.x0_m), time_varying=sc.time_varying,
                             channels=("p_A", "p_B", "x"), **setting)
    return {k: res[k][0] for k in ("p_A", "p_B", "x")}


def sam_in_the_loop(sc, settings, setting):
    """sam stepped from Python under the rig's controller and encoder (sam has no closed loop)."""
    p = sc.plant.vector()
    b = sc.plant.boom
    ctrl, enc = controller_settings(sc, settings), encoder_settings(sc, settings)
    every, period = int(ctrl[6]), int(ctrl[6]) * sc.dt
    s = sam.initial_state(p, sc.x0_m)[None].copy()
    flags = np.zeros(1, dtype=np.int64)
    u, integral = np.zeros(1), 0.0
    out = np.empty((len(sc.t) + 1, 3))
    for k in range(len(sc.t)):
        out[k] = s[0, [sam.S.p_A, sam.S.p_B, sam.S.x]]
        if k % every == 0:
            theta = encoder_reading(joint_angle(s[0, sam.S.x], b.L_1, b.L_2, b.L_3), enc)
            u[0], integral = controller(theta, sc.control.setpoint[k], integral, k * sc.dt, ctrl, enc, period)
        sam.step_batch_inplace(s, u, p[None], sc.dt, flags, setting["substeps"], int(sam.SCHEMES[setting["scheme"]]))
    out[-1] = s[0, [sam.S.p_A, sam.S.p_B, sam.S.x]]
    return {"p_A": out[:, 0], "p_B": out[:, 1], "x": out[:, 2]}


def cost_ns(setting, n_runs, repeats=3):
    """ns per run-step of simulate_batch on runs of the Table 1 box, 4 s at 1 ms, median of repeats."""
    params = table1_params(n_runs)
    u = np.full(4000, 2.5)
    sam.simulate_batch(params[:2], u[:10], 1e-3, **setting)  # compile
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sam.simulate_batch(params, u, 1e-3, record_every=10, channels=("p_A", "p_B", "v"), **setting)
        times.append(time.perf_counter() - t0)
    return np.median(times) / (n_runs * 4000) * 1e9


def table(n_runs: int) -> None:
    cases = []
    for name, sc, settings in rig_runs():
        truth = rig.simulate(sc, settings)
        u = truth.u[:-1]
        cases.append((name, sc, settings, truth, u, sam_open_loop(sc, u, REFERENCE)))
    closed = [(name, sc, settings, truth) for name, sc, settings, truth, _, _ in cases if sc.control is not None]
    loop_ref = {name: sam_in_the_loop(sc, settings, REFERENCE) for name, sc, settings, _ in closed}
    print(f"sigma = {SIGMA / 1e3:g} kPa. fit = 100 (1 - ||y - yhat|| / ||y - mean(y)||) on p_A / p_B, the worst "
          "recording. error: sam against sam at RK4 0.01 ms under the same input, RMS / 99th percentile of |e| "
          "over p_A and p_B, the worst recording [kPa]. cost: simulate_batch, runs of the Table 1 box, ns per "
          "run-step (median of 3)")
    print("| scheme | step | cost [ns] | fit to the rig, open loop | fit to the rig, closed loop | "
          "fit to converged sam, closed loop | error, recorded u | error, closed loop |")
    print("|---|---|---|---|---|---|---|---|")
    for scheme in SCHEMES:
        for ms in STEPS_MS:
            setting = {"substeps": int(round(1.0 / ms)), "scheme": scheme}
            fits_ol, errs = [], []
            for name, sc, settings, truth, u, ref in cases:
                sim = sam_open_loop(sc, u, setting)
                errs.append([sim[k] - ref[k] for k in ("p_A", "p_B")])
                if sc.control is None:
                    fits_ol.append([fit_percent(truth.truth[k], sim[k]) for k in ("p_A", "p_B")])
            fits_cl, fits_self, errs_cl = [], [], []
            for name, sc, settings, truth in closed:
                sim = sam_in_the_loop(sc, settings, setting)
                fits_cl.append([fit_percent(truth.truth[k], sim[k]) for k in ("p_A", "p_B")])
                fits_self.append([fit_percent(loop_ref[name][k], sim[k]) for k in ("p_A", "p_B")])
                errs_cl.append([sim[k] - loop_ref[name][k] for k in ("p_A", "p_B")])
            print(f"| {scheme} | {ms:g} ms | {cost_ns(setting, n_runs):.0f} | {_fits(fits_ol)} | {_fits(fits_cl)} | "
                  f"{_fits(fits_self)} | {_errors(errs)} | {_errors(errs_cl)} |", flush=True)
    print("\nconverged sam (RK4 0.01 ms) against the rig, by recording (fit p_A / p_B / x):")
    for name, sc, settings, truth, u, ref in cases:
        sim = loop_ref[name] if sc.control is not None else ref
        print(f"  {name}: {' / '.join(f'{fit_percent(truth.truth[k], sim[k]):.2f}' for k in ('p_A', 'p_B', 'x'))}")


def _fits(fits) -> str:
    worst = np.min(np.array(fits), axis=0)
    return f"{worst[0]:.2f} / {worst[1]:.2f}"


def _errors(errs) -> str:
    rms = max(np.sqrt(np.mean(e**2)) for pair in errs for e in pair)
    p99 = max(np.percentile(np.abs(e), 99) for pair in errs for e in pair)
    return f"{rms / 1e3:.2f} / {p99 / 1e3:.2f}"


def side_by_side(n_runs: int, rounds: int) -> None:
    """Today's Eq. (22) at 1 ms and the estimation default, alternated round by round."""
    times = {"today": [], "estimation": []}
    for _ in range(rounds):
        times["today"].append(cost_ns(DEFAULT, n_runs, repeats=1))
        times["estimation"].append(cost_ns(ESTIMATION, n_runs, repeats=1))
    today, est = np.median(times["today"]), np.median(times["estimation"])
    ratios = np.array(times["estimation"]) / np.array(times["today"])  # each round's pair, side by side
    print(f"today      ({DEFAULT['scheme']}, {DEFAULT['substeps']} x 1 ms): {today:.1f} ns per run-step "
          f"(median of {rounds}; {', '.join(f'{t:.1f}' for t in times['today'])})")
    print(f"estimation ({ESTIMATION['scheme']}, {ESTIMATION['substeps']} x {1 / ESTIMATION['substeps']:g} ms): "
          f"{est:.1f} ns per run-step ({', '.join(f'{t:.1f}' for t in times['estimation'])})")
    print(f"ratio      : {np.median(ratios):.2f}x the cost of today's step (median of the rounds' ratios; "
          f"{', '.join(f'{r:.2f}' for r in ratios)})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", action="store_true", help="the fit / error / cost table of every setting")
    ap.add_argument("--runs", type=int, default=None, help="runs per cost timing")
    ap.add_argument("--rounds", type=int, default=5, help="alternations of the side-by-side timing")
    args = ap.parse_args()
    if args.table:
        table(args.runs or 2000)
    else:
        side_by_side(args.runs or 20000, args.rounds)


if __name__ == "__main__":
    main()
