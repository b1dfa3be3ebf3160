"""Synthetic test data: runs of ``sam.simulate_batch`` with fault and load profiles
and the SAM's sensor noise (20 kPa pressure noise, 0.007 deg encoder pulses).

Used by the tests, the signature tables, the Monte Carlo tuning and the
benchmark. Only measured channels go to the filter; the truth is kept apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sam import P, initial_state, profiles, simulate_batch
from sam.hydraulics import leak_coefficient
from sam.measurement import quantise_angle
from sam.geometry import joint_angle

from .config import Sensors
from .faults import FAULTS
from .filter import FilterInput
from .states import POS_THETA, POS_X

#: the simulated position channel of each position sensor (fdi.thresholds.SHIPPED_BY_SENSOR): the
#: SAM's quantised encoder, or x from a linear transducer with the white noise the filter
#: assumes for one (fdi.config.Sensors.x_noise, 10 um)
POSITION_SENSORS = {"encoder": {"position": "theta"}, "linear": {"position": "x", "x_noise": Sensors.x_noise}}



def profile(kind: str, value: float, t: np.ndarray, t0: float = 0.0, t1: float | None = None,
            period: float = 1.0, duty: float = 0.5) -> np.ndarray:
    """A fault profile over time t (sam.profiles): constant, step (at t0), ramp (t0 -> t1),
    intermittent (on for ``duty`` of each ``period`` from t0)."""
    if kind == "constant":
        return profiles.constant_profile(t, value)
    if kind == "step":
        return profiles.step_profile(t, value, t0)
    if kind == "ramp":
        return profiles.ramp_profile(t, value, t0, t[-1] if t1 is None else t1)
    if kind == "intermittent":
        return profiles.intermittent_profile(t, value, t0, duty * period, (1 - duty) * period)
    raise ValueError(f"unknown profile kind {kind!r}")


def input_signal(kind: str, t: np.ndarray, amplitude: float = 3.0, frequency: float = 0.5,
                 offset: float = 0.0, seed: int = 0, period: float = 4.0) -> np.ndarray:
    """Valve input [V] (sam.profiles): sine, step (at 0.1 s), prbs (0.2 s hold) or an
    extend, hold, retract, hold cycle."""
    if kind == "sine":
        return profiles.sine_input(t, amplitude, frequency, offset)
    if kind == "step":
        return profiles.step_input(t, amplitude + offset, t0_s=0.1, initial_V=offset)
    if kind == "cycle":
        return profiles.cycle_input(t, amplitude, period, offset_V=offset, dwell_fraction=0.5)
    if kind == "prbs":
        return profiles.prbs_input(t, amplitude, hold_s=0.2, seed=seed, offset_V=offset)
    raise ValueError(f"unknown input kind {kind!r}")


#: s: the period range of the random extend/hold/retract cycles of the Monte Carlo and the
#: threshold studies. The 20-60 s cycles are not drawn: long strokes have a rule of their own
#: (the thresholds' long_stroke_s; why: docs/fdi-design.md, "Long strokes").
CYCLE_PERIOD_S = (2.0, 4.0)


#: the kinds of random experiment (:func:`random_input`) of the Monte Carlo and the studies
INPUT_KINDS = ("sine", "cycle", "prbs")


def random_input(kind: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random experiment of the given kind (sine, cycle, prbs) drawn from rng, in this order:
    amplitude 2-4 V, sine frequency 0.25-0.6 Hz, PRBS seed, cycle period (CYCLE_PERIOD_S)."""
    return input_signal(kind, t, amplitude=rng.uniform(2.0, 4.0), frequency=rng.uniform(0.25, 0.6),
                        seed=int(rng.integers(1 << 31)), period=rng.uniform(*CYCLE_PERIOD_S))


@dataclass
class Runs:
    """Simulated runs: what the filter sees plus the truth."""

    inp: FilterInput
    truth: dict[str, np.ndarray] = field(default_factory=dict)  #: name -> (B, T)
    cavitated: np.ndarray | None = None

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.inp.u.shape[1]) * self.inp.dt


def simulate_runs(params: np.ndarray, u: np.ndarray, dt: float, *, faults: dict | None = None,
                  m_L: np.ndarray | None = None, nominal: np.ndarray | None = None,
                  pressure_noise: float = 20e3, quantise: bool = True, position: str = "theta",
                  x_noise: float = 0.0, seed: int = 0, x0: float | np.ndarray = 0.05) -> Runs:
    """Simulate B runs and add sensor noise.

    Args:
        params: (B, len(P)) TRUE plant vectors (may differ from the nominal).
        u: (T,) or (B, T) input [V]; the recording has T samples (T-1 steps).
        faults: name -> (T,) or (B, T) SI values over time (K in m^3/(s Pa^0.5)).
        m_L: (T,) or (B, T) load mass over time, or None (constant from params).
        nominal: (B, len(P)) vectors the filter is given; default = params with
            healthy faults and the plant's own m_L.
        position: "theta" (quantised encoder) or "x".
        x_noise: m, std of white noise on x (position "x" only; drawn after the pressures' noise).
        x0: m, the piston's start position, at rest: one for all runs or (B,) one per run.
    """
    params = np.atleast_2d(np.asarray(params, dtype=float)).copy()
    B = params.shape[0]
    u = np.broadcast_to(np.atleast_2d(u), (B, np.shape(u)[-1])).astype(float)
    T = u.shape[1]
    tv = {}
    truth = {}
    for name, arr in (faults or {}).items():
        arr = np.broadcast_to(np.atleast_2d(arr), (B, T)).astype(float)
        tv[name] = arr[:, :-1]
        truth[name] = arr
    if m_L is not None:
        arr = np.broadcast_to(np.atleast_2d(m_L), (B, T)).astype(float)
        tv["m_L"] = arr[:, :-1]
        truth["m_L"] = arr
    p_init = params.copy()
    for name, arr in truth.items():
        p_init[:, P[name]] = arr[:, 0]
    s0 = initial_state(p_init, x=x0)
    res = simulate_batch(params, u[:, :-1], dt, x0=s0, time_varying=tv or None)
    rng = np.random.default_rng(seed)
    pA = res["p_A"] + pressure_noise * rng.standard_normal((B, T))
    pB = res["p_B"] + pressure_noise * rng.standard_normal((B, T))
    x = res["x"]
    truth["v"] = res["v"]
    truth["x"] = x
    truth["p_A"], truth["p_B"] = res["p_A"], res["p_B"]  # before the sensor noise
    if position == "theta":
        th = joint_angle(x, params[:, [P.L_1]], params[:, [P.L_2]], params[:, [P.L_3]])
        if quantise:
            th = quantise_angle(th)
        pos, kind = th, POS_THETA
    else:
        pos = x + x_noise * rng.standard_normal((B, T)) if x_noise else x.copy()
        kind = POS_X
    if nominal is None:
        nominal = params.copy()
        for name in FAULTS:
            nominal[:, P[name]] = 0.0
        nominal[:, P.F_d] = 0.0
    inp = FilterInput(dt=dt, u=np.ascontiguousarray(u), pA=pA, pB=pB, pos=pos, pos_kind=kind,
                      params=np.ascontiguousarray(nominal))
    return Runs(inp, truth, res.cavitated)


lpm = leak_coefficient  #: K of a leak of so many L/min at 10 MPa
