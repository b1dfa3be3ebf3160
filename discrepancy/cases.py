"""Recordings with concealed effects, for proving the mismatch diagnosis.

Each case switches on one (or two, or no) effect of ``sam``'s model, drives the
cylinder with a position controller plus a random dither (steps, reversals,
high-flow moves, still periods, visits near the stroke ends), and measures it
like the test bed: 20 kPa pressure noise, an angle encoder of 0.007 deg/pulse.

    python -m discrepancy.cases OUT_DIR [--duration 20] [--case NAME]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

import sam
from sam import P, S
from sam.dynamics import Scheme
from sam.measurement import Sensors, measure, quantise_angle
from sam.geometry import joint_angle, piston_position


@dataclass(frozen=True)
class Case:
    name: str
    expect: tuple[str, ...]  # library hypotheses that should be named (empty: none)
    plant: dict[str, float] = field(default_factory=dict)  # plant.replace(**...)
    faults: dict[str, float] = field(default_factory=dict)  # K_int, K_extA, K_extB
    sensors: dict[str, float] = field(default_factory=dict)  # lag_s, delay_s
    note: str = ""
    #: optional law (state (7,), nominal params (len(P),), u_cmd [V]) -> (params, u_valve), applied every step
    #: of the closed loop: other functional forms of an effect, through sam's parameters / unknown inputs
    law: object = None
    #: optional post-processing of the measured signals (dict -> dict), e.g. a second-order sensor filter
    sensor_chain: object = None
    seed_offset: int = 0


CASES: tuple[Case, ...] = (
    Case("entrained_air", ("entrained_air",), {"air_fraction": 0.01}, note="1 % free air"),
    Case("hose_compliance", ("hose_compliance",), {"C_hose": 1.5e-12}, note="1.5e-12 m^3/Pa per chamber"),
    Case("spool_overlap", ("spool_lap",), {"lap": 0.03}, note="3 % overlap"),
    Case("flow_saturation", ("flow_saturation",), {"x_open": 0.4}, note="notch fully open at 40 % of travel"),
    Case("supply_droop", ("supply_droop",), {"R_supply": 5e9}, note="5e9 Pa s/m^3"),
    Case("bypass_leakage", ("bypass_leakage",), {"K_bypass": 3e-12}, note="0.18 L/min per MPa"),
    Case("pressure_friction", ("pressure_friction",), {"k_fric_dp": 1.5e-4, "k_fric_rod": 0.75e-4},
         note="piston seal 1.5e-4, rod seal 0.75e-4 m^2"),
    Case("friction_level", ("friction_level",), {"F_C": 3000.0, "F_S": 6000.0, "b": 6000.0}, note="F_C 3 kN"),
    Case("load_mass", (), {"m_L": 750.0}, note="750 kg instead of 494 kg: a commissioning value (m_L is [uncertain])"),
    Case("sensor_lag", ("sensor_lag",), sensors={"lag_s": 0.01}, note="10 ms on every sensor"),
    Case("time_delay", ("time_delay",), sensors={"delay_s": 0.012}, note="12 ms"),
    Case("wrong_nominal", (), {"Q_N_BT": 3.0e-4, "B_eff": 1.1e9}, note="Q_N_BT 18 L/min, B_eff 1.1 GPa"),
    Case("two_effects", ("entrained_air", "bypass_leakage"), {"air_fraction": 0.006, "K_bypass": 3e-12},
         note="0.6 % air and bypass"),
    Case("no_mismatch", (), note="the nominal plant"),
    Case("outside_library", (), faults={"K_extA": 4e-9}, note="turbulent external leak from A (not a library effect)"),
)


#: The machine these recordings stand for is continuous in time: Heun at 1 ms agrees with RK4 (with
#: 1 % air the squared error of a segment between the two is 1 % of Euler's), Eq. (22)'s Euler at
#: 1 ms errs as much as the effects, which the diagnosis would then have to explain
SCHEME = Scheme.HEUN


def reference_and_dither(duration: float, dt: float, rng: np.random.Generator, x_max: float):
    """A position reference (random smooth moves between 5 % and 95 % of stroke) and a dither."""
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    ref = np.empty(n)
    k = 0
    while k < n:
        hold = int(rng.uniform(1.5, 3.5) / dt)
        target = rng.uniform(0.04, 0.96) * x_max
        ref[k:k + hold] = target
        k += hold
    # smooth the steps: a second-order prefilter of ~0.3 s
    a = np.exp(-dt / 0.4)
    ref = lfilter([1 - a], [1, -a], lfilter([1 - a], [1, -a], ref, zi=[a * ref[0]])[0], zi=[a * ref[0]])[0]
    dither = np.zeros(n)
    k = 0
    while k < n:
        hold = int(rng.uniform(0.05, 0.4) / dt)
        dither[k:k + hold] = rng.normal(0, 1.2) * (rng.random() < 0.7)
        k += hold
    dither += 0.8 * np.sin(2 * np.pi * (0.5 + 3 * t / duration) * t)
    return t, ref, dither


def simulate_closed_loop(params: np.ndarray, duration: float, dt: float, seed: int, x0: float = 0.2, law=None):
    """Position control u = Kp (ref - x_measured) + dither, clipped to +-10 V; returns t, u, states."""
    rng = np.random.default_rng(seed)
    x_max = params[P.x_max]
    t, ref, dither = reference_and_dither(duration, dt, rng, x_max)
    n = len(t)
    L = params[P.L_1], params[P.L_2], params[P.L_3]
    state = sam.initial_state(params[None, :], x=x0)
    u = np.empty(n)
    states = np.empty((n, 7))
    p2 = params[None, :]
    kp = 100.0
    for k in range(n):
        states[k] = state[0]
        x_meas = piston_position(quantise_angle(joint_angle(state[0, S.x], *L)), *L)
        u[k] = np.clip(kp * (ref[k] - x_meas) + dither[k], -10, 10)
        if law is None:
            state, _ = sam.step_batch(state, u[k:k + 1], p2, dt, scheme=SCHEME)
        else:
            pk, uk = law(state[0], params, u[k])
            state, _ = sam.step_batch(state, np.array([uk]), pk[None, :], dt, scheme=SCHEME)
    names = {"p_A": S.p_A, "p_B": S.p_B, "x_s": S.x_s, "x": S.x, "v": S.v}
    return t, u, {k: states[:, i] for k, i in names.items()}


def make_recording(case: Case, duration: float = 20.0, dt: float = 1e-3, seed: int = 1,
                   plant: sam.Plant | None = None) -> sam.Recording:
    base = plant or sam.load_plant()
    # a real boom has Eq. (7)'s R-dot torque (docs/model.md, "Motion"), and so does the diagnosis' model;
    # without it, each long fast move of a recording is a mismatch no library effect stands for
    true_plant = base.replace(arm_rate_torque=True, **case.plant)
    params = true_plant.vector(faults=sam.Faults(**case.faults))
    t, u, states = simulate_closed_loop(params, duration, dt, seed + case.seed_offset, law=case.law)
    sensors = Sensors(pressure_noise_Pa=20e3, encoder_quantisation=True, **case.sensors)
    sig = measure(states, params, dt, sensors, np.random.default_rng(seed + 1000))
    if case.sensor_chain is not None:
        sig = case.sensor_chain(sig, dt)
    signals = {"u": u, "pA": sig["pA"], "pB": sig["pB"], "theta": sig["theta"]}
    meta = {"plant": base.name, "case": case.name, "concealed": case.note or "none",
            "description": "mismatch-diagnosis proof case (discrepancy/cases.py)"}
    return sam.Recording(t=t, signals=signals, metadata=meta)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--case", action="append")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    for case in CASES:
        if args.case and case.name not in args.case:
            continue
        rec = make_recording(case, args.duration, seed=args.seed)
        path = sam.write_recording(args.out / f"{case.name}.csv", rec, overwrite=True)
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
