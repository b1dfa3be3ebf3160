"""HELD-OUT robustness set for the mismatch diagnosis: never used to tune it.

The development cases (:mod:`discrepancy.cases`) switch on each effect at one
magnitude through the model's own term. These cases use other magnitudes and,
where possible, other functional forms of the same physics, still produced by
``sam`` only: the closed loop sets ``sam``'s parameters or its unknown inputs
(Q_dA, Q_dB, F_d of :class:`sam.params.Disturbances`) at every step from a law
written here (the law is the *concealed physics*; the model equations are
``sam``'s, called through :func:`sam.step_batch`), or post-processes the
measured signals with ``sam.measurement``'s sensor filters.

    python -m discrepancy.proof --set heldout [--duration 20]
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sam import P, S
from sam.hydraulics import supply_flow_array
from sam.measurement import first_order_lag

from .cases import Case

MPa = 1e6


def _tanh_sign(v, v0=1e-3):
    return math.tanh(v / v0)


def air_dissolving(state, p, u):
    """Free air that dissolves as the mean chamber pressure rises (an air fraction scheduled on pressure)."""
    q = p.copy()
    pm = 0.5 * (state[S.p_A] + state[S.p_B])
    q[P.air_fraction] = 0.02 * math.exp(-max(pm, 0.0) / (4 * MPa))
    return q, u


def hose_stiffening(state, p, u):
    """Hose compliance falling quadratically with pressure: C = C0 / (1 + (p / 3 MPa)^2)."""
    q = p.copy()
    pm = 0.5 * (state[S.p_A] + state[S.p_B])
    q[P.C_hose] = 4e-12 / (1 + (pm / (3 * MPa)) ** 2)
    return q, u


def input_deadband(state, p, u):
    """A deadband in the valve electronics (0.35 V of 10 V) rather than a spool overlap."""
    d = 0.35
    return p, math.copysign(max(abs(u) - d, 0.0), u)


def soft_saturation(state, p, u):
    """A flow limit that softens with spool opening (a soft knee rather than a hard clip)."""
    q = p.copy()
    q[P.Q_sat] = 1.3e-4 * (1 + 1.5 * state[S.x_s] ** 2)
    return q, u


class Accumulator:
    """Pump (fixed displacement, 20 L/min) charging an accumulator, relief at the nominal p_S:
    the supply pressure droops with the *integral* of the flow deficit, not in proportion to the flow."""

    def __init__(self, dt=1e-3, Q_pump=3.3e-4, C_acc=4e-11):
        self.dt, self.Q_pump, self.C_acc, self.p_S = dt, Q_pump, C_acc, None

    def __call__(self, state, p, u):
        if self.p_S is None:
            self.p_S = p[P.p_S]
        q = p.copy()
        q[P.p_S] = self.p_S
        arr = lambda i: np.array([state[i]])
        Q_s = float(supply_flow_array(arr(S.x_s), arr(S.p_A), arr(S.p_B), q)[0])
        self.p_S = min(p[P.p_S], max(self.p_S + self.dt * (self.Q_pump - Q_s) / self.C_acc, 2 * MPa))
        return q, u


def lam_turb_bypass(state, p, u):
    """Cross-piston leakage with a laminar and a turbulent part: Q = 1e-12 dp + 2e-9 sgn(dp) sqrt|dp|."""
    q = p.copy()
    dp = state[S.p_A] - state[S.p_B]
    Q = 1e-12 * dp + 2e-9 * math.copysign(math.sqrt(abs(dp)), dp)
    q[P.Q_dA] = -Q
    q[P.Q_dB] = Q
    return q, u


def seal_power_law(state, p, u):
    """Seal friction growing with a power 1.5 of the chamber pressure level (not linearly)."""
    q = p.copy()
    s = (max(state[S.p_A] + state[S.p_B], 0.0) / (10 * MPa)) ** 1.5
    q[P.F_C] = p[P.F_C] * (1 + 2.5 * s)
    q[P.F_S] = p[P.F_S] * (1 + 2.5 * s)
    return q, u


def extra_stribeck(state, p, u):
    """An extra seal friction with a Gaussian Stribeck shape and its own velocity scale, as a force F_d."""
    q = p.copy()
    v = state[S.v]
    q[P.F_d] = _tanh_sign(v) * (1200 + 2500 * math.exp(-(abs(v) / 0.02) ** 2)) + 3000 * v
    return q, u


def laminar_ext_leak_B(state, p, u):
    """A laminar external leak from chamber B: Q = 4e-12 p_B (not a library effect)."""
    q = p.copy()
    q[P.Q_dB] = -4e-12 * max(state[S.p_B], 0.0)
    return q, u


def two_cascaded_lags(sig, dt):
    """A second-order sensor filter (two first-order lags of 6 ms) instead of one lag."""
    return {k: first_order_lag(first_order_lag(y, dt, 0.006), dt, 0.006) for k, y in sig.items()}


def _accumulator_law():
    acc = Accumulator()
    return acc


HELDOUT: tuple[Case, ...] = (
    # --- other magnitudes, the model's own term
    Case("air_low", ("entrained_air",), {"air_fraction": 0.004}, note="0.4 % air"),
    Case("air_high", ("entrained_air",), {"air_fraction": 0.025}, note="2.5 % air"),
    Case("hose_low", ("hose_compliance",), {"C_hose": 0.7e-12}, note="0.7e-12 m^3/Pa"),
    Case("overlap_low", ("spool_lap",), {"lap": 0.015}, note="1.5 % overlap"),
    Case("underlap", ("spool_lap",), {"lap": -0.03}, note="3 % underlap"),
    Case("saturation_hard", ("flow_saturation",), {"Q_sat": 1.0e-4}, note="6 L/min per notch"),
    Case("droop_low", ("supply_droop",), {"R_supply": 2e9}, note="2e9 Pa s/m^3"),
    Case("bypass_low", ("bypass_leakage",), {"K_bypass": 1.2e-12}, note="1.2e-12 m^3/(s Pa)"),
    Case("pfric_low", ("pressure_friction",), {"k_fric_p": 0.6e-4}, note="0.6e-4 m^2"),
    Case("mass_light", ("load_mass",), {"m_L": 300.0}, note="300 kg for 494 kg"),
    Case("delay_frac", ("time_delay",), sensors={"delay_s": 0.0065}, note="6.5 ms (not whole samples)"),
    Case("lag_long", ("sensor_lag",), sensors={"lag_s": 0.02}, note="20 ms"),
    Case("nominal_other", (), {"Q_N_PA": 2.8e-4, "B_eff": 1.6e9}, note="Q_N_PA 17 L/min, B_eff 1.6 GPa"),
    Case("no_mismatch_2", (), note="the nominal plant, other seed", seed_offset=17),
    # --- other functional forms of the same physics
    Case("air_dissolving", ("entrained_air",), law=air_dissolving, note="2 % air x exp(-p/4 MPa)"),
    Case("hose_stiffening", ("hose_compliance",), law=hose_stiffening, note="C = 4e-12/(1+(p/3 MPa)^2)"),
    Case("input_deadband", ("spool_lap",), law=input_deadband, note="0.35 V deadband on u"),
    Case("soft_saturation", ("flow_saturation",), law=soft_saturation, note="Q_sat = 7.8 L/min (1 + 1.5 x_s^2)"),
    Case("accumulator", ("supply_droop",), law="accumulator", note="20 L/min pump + accumulator, relief"),
    Case("bypass_lam_turb", ("bypass_leakage",), law=lam_turb_bypass, note="1e-12 dp + 2e-9 sqrt|dp|"),
    Case("seal_power", ("pressure_friction",), law=seal_power_law, note="F_C,S (1 + 2.5 ((pA+pB)/10 MPa)^1.5)"),
    Case("stribeck_shape", ("friction_level",), law=extra_stribeck, note="F_d Gaussian Stribeck + 3000 v"),
    Case("lag_2nd_order", ("sensor_lag",), sensor_chain=two_cascaded_lags, note="two 6 ms lags"),
    Case("two_droop_mass", ("supply_droop", "load_mass"), {"R_supply": 4e9, "m_L": 700.0},
         note="droop 4e9 + 700 kg"),
    Case("outside_lam_leak_B", (), law=laminar_ext_leak_B, note="laminar external leak from B 4e-12 p_B"),
)


def materialise(case: Case) -> Case:
    """Stateful laws get a fresh instance per recording."""
    if case.law == "accumulator":
        return dataclasses.replace(case, law=_accumulator_law())
    return case
