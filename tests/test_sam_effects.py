"""The library forms a hydraulics engineer expects (sam.params.Effects): seal friction on the
pressure difference across the piston and on the rod-side pressure (k_fric_dp, k_fric_rod), a
valve opening limit (x_open) and a pump behind a relief valve (Q_pump; closed forms in
tests/test_sam_pump.py). Each checked in closed form, neutral by default to the last bit, the
same on one lane as on a block of lanes."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sam
from sam import P, S
from sam.constants import LPM
from sam.dynamics import D, derive, kernel_variant, rhs, step
from sam.friction import seal_pressure_rise
from sam.hydraulics import flow_coefficient, limited_openings, supply_flow, valve_flows

PLANT = sam.load_plant()
DT = 1e-3
#: the new terms at magnitudes of the development set's machines (docs/mismatch.md)
SEALS = {"k_fric_dp": 1e-4, "k_fric_rod": 5e-5}
OPENING = {"x_open": 0.4}


def _valve_args(p, x_s, p_A, p_B):
    """valve_flows' arguments of parameter vector p at spool position x_s and chamber pressures [Pa]."""
    K = [flow_coefficient(p[P[f"Q_N_{e}"]], p[P[f"dp_N_{e}"]]) for e in ("PA", "AT", "PB", "BT")]
    return (x_s, p_A, p_B, p[P.offset], p[P.p_S], p[P.p_T], *K, p[P.K_leak_PA], p[P.K_leak_AT], p[P.K_leak_PB],
            p[P.K_leak_BT], p[P.leak_band], p[P.lap], p[P.R_supply], p[P.Q_sat])


# ------------------------------------------------------------------------------------ closed form


def test_seal_friction_rises_with_the_pressure_difference_and_the_rod_pressure():
    """8 and 3 MPa: the piston seal holds 5 MPa (1e-4 m^2: 500 N), the rod seal 3 MPa (5e-5 m^2:
    150 N); with the chambers swapped the difference is the same and the rod seal holds 8 MPa; a rod
    side below atmospheric presses the rod seal no harder than none."""
    assert seal_pressure_rise(8e6, 3e6, 1e-4, 5e-5) == pytest.approx(650.0, rel=1e-12)
    assert seal_pressure_rise(3e6, 8e6, 1e-4, 5e-5) == pytest.approx(500.0 + 400.0, rel=1e-12)
    assert seal_pressure_rise(2e6, -5e4, 1e-4, 5e-5) == pytest.approx(1e-4 * 2.05e6, rel=1e-12)
    assert seal_pressure_rise(8e6, 3e6, 0.0, 0.0) == 0.0


def test_the_model_s_friction_levels_are_raised_by_the_seal_terms():
    """The right-hand side (Eq. (19)) of a sliding piston with the seal terms at 8 and 3 MPa is that
    of the nominal model with F_C and F_S each raised by the 650 N of the closed form."""
    p_on = PLANT.replace(**SEALS).vector()
    p_by_hand = PLANT.replace(F_C=PLANT.friction.F_C + 650.0, F_S=PLANT.friction.F_S + 650.0).vector()
    s = np.array([8e6, 3e6, 0.2, 0.0, 0.2, 0.05, 1e-4])
    out = []
    for p in (p_on, p_by_hand):
        d, ds = np.empty(len(D)), np.empty(7)
        derive(p, d)
        rhs(s, 2.0, p, d, ds)
        out.append(ds.copy())
    assert out[0][S.v] == pytest.approx(out[1][S.v], rel=1e-12, abs=1e-12)
    assert out[0][S.z] == pytest.approx(out[1][S.z], rel=1e-12, abs=1e-15)
    assert np.array_equal(out[0][[S.p_A, S.p_B, S.x_s, S.dx_s, S.x]], out[1][[S.p_A, S.p_B, S.x_s, S.dx_s, S.x]])


def test_an_opening_limit_caps_the_area_while_the_flow_follows_the_pressure_drop():
    """x_open = 0.4: below it the valve is the nominal one to the last bit; at 0.8 the P->A edge is
    an orifice of 0.4 of the full area, Q = Q_N 0.4 sqrt(dp / dp_N) (Eq. (12)), at 6.5 MPa and at
    2 MPa (the flow still rises with sqrt(dp): it is no flow cap)."""
    p = PLANT.vector()
    Q_N, dp_N, p_S = p[P.Q_N_PA], p[P.dp_N_PA], p[P.p_S]
    for x_s in (0.1, 0.3, 0.39):
        nominal = valve_flows(*_valve_args(p, x_s, 3.5e6, 1e6))
        assert valve_flows(*_valve_args(p, x_s, 3.5e6, 1e6), 0.4) == nominal
    for p_A in (3.5e6, 8e6):
        Q_A = valve_flows(*_valve_args(p, 0.8, p_A, 1e6), 0.4)[0]
        assert Q_A == pytest.approx(Q_N * 0.4 * math.sqrt((p_S - p_A) / dp_N), rel=1e-12)
    high, low = (valve_flows(*_valve_args(p, 0.8, p_A, 1e6), 0.4)[0] for p_A in (3.5e6, 8e6))
    assert high / low == pytest.approx(math.sqrt(6.5e6 / 2e6), rel=1e-12)
    # the tank edge B->T is limited alike, and so is the flow drawn from the supply
    Q_B = valve_flows(*_valve_args(p, 0.8, 3.5e6, 1e6), 0.4)[1]
    assert Q_B == pytest.approx(-p[P.Q_N_BT] * 0.4 * math.sqrt(1e6 / p[P.dp_N_BT]), rel=1e-12)
    K_PA, K_PB = flow_coefficient(Q_N, dp_N), flow_coefficient(p[P.Q_N_PB], p[P.dp_N_PB])
    drawn = supply_flow(0.8, 3.5e6, 1e6, 0.0, p_S, K_PA, K_PB, 0.0, 0.0, math.inf, 0.4)
    assert drawn == pytest.approx(Q_N * 0.4 * math.sqrt(6.5e6 / dp_N), rel=1e-12)
    assert limited_openings(-0.9, 0.0, 0.0, 0.4) == (0.0, 0.4)


# ------------------------------------------------------------------------------------ bit for bit


def _batch(n: int, seed: int, **effects) -> tuple[np.ndarray, np.ndarray]:
    """n parameter rows over loads 0-800 kg and notch flows +-25 %, with ``effects`` (name: (lo, hi)),
    starting inside the stroke and on either stop. Returns (params, x0)."""
    rng = np.random.default_rng(seed)
    params = np.tile(PLANT.vector(), (n, 1))
    box = {"m_L": (0.0, 800.0), "Q_N_PA": (3e-4, 5e-4), "Q_N_BT": (3e-4, 5e-4), **effects}
    for name, (lo, hi) in box.items():
        params[:, P[name]] = rng.uniform(lo, hi, n)
    return params, sam.initial_state(params, rng.choice([0.0, 0.1, 0.25, 0.43], n))


def _input(n_steps: int) -> np.ndarray:
    """Full opening either way (beyond every x_open drawn), a slow reversal, the valve near null."""
    t = np.arange(n_steps) * DT
    return np.where(t < 0.4, 10.0, np.where(t < 0.9, -10.0, np.where(t < 1.3, 4.0 * np.sin(9 * t), 0.02)))


def _states(res) -> np.ndarray:
    return np.stack([res[c] for c in S.__members__])


def _one_by_one(params, x0, u, scheme: str) -> np.ndarray:
    """Each run advanced alone by the scalar step (the general variant of the kernel): (7, n, steps + 1)."""
    out = np.empty((7, params.shape[0], len(u) + 1))
    for i, p in enumerate(params):
        d, ds, s = np.empty(len(D)), np.empty(7), x0[i].copy()
        derive(p, d)
        out[:, i, 0] = s
        for k, uk in enumerate(u):
            step(s, uk, p, d, DT, ds, 1, int(sam.SCHEMES[scheme]))
            out[:, i, k + 1] = s
    return out


@pytest.mark.parametrize("scheme", ["euler", "heun"])
def test_the_new_effects_on_lanes_are_the_scalar_step(scheme):
    """35 runs (a block and a part) with the seal terms, the opening limit and a pump of 8-30 L/min
    behind a relief (override 0-1 MPa at 15 L/min) drawn over the library's range: the lane kernel is
    the scalar step to the last bit, every state at every step."""
    params, x0 = _batch(35, 11, k_fric_dp=(0.0, 4e-4), k_fric_rod=(0.0, 2e-4), x_open=(0.2, 1.1),
                        Q_pump=(8 * LPM, 30 * LPM), R_supply=(0.0, 4e9))
    assert kernel_variant(params) == (False, True)
    u = _input(600)
    lanes = _states(sam.simulate_batch(params, u, DT, x0=x0, scheme=scheme))
    alone = _one_by_one(params, x0, u, scheme)
    assert np.array_equal(lanes[:, :, :alone.shape[2]], alone[:, :, :lanes.shape[2]])


@pytest.mark.parametrize("scheme", ["euler", "heun"])
def test_neutral_new_effects_leave_the_model_unchanged_to_the_last_bit(scheme):
    """At their defaults (0, 0, inf, inf: an ideal supply) the general variant of the kernel, which
    evaluates the new terms, gives the nominal model's numbers (the variant without them) to the last
    bit; a plant that names them at their defaults has the default's vector, and a pump alone needs
    the general variant."""
    assert np.array_equal(PLANT.replace(k_fric_dp=0.0, k_fric_rod=0.0, x_open=math.inf, Q_pump=math.inf).vector(),
                          PLANT.vector())
    assert kernel_variant(PLANT.replace(Q_pump=20 * LPM).vector()[None, :]) == (False, True)
    params, x0 = _batch(35, 12)
    assert kernel_variant(params) == (False, False)
    u = _input(600)
    nominal = _states(sam.simulate_batch(params, u, DT, x0=x0, scheme=scheme))
    general = _one_by_one(params, x0, u, scheme)
    assert np.array_equal(nominal[:, :, :general.shape[2]], general[:, :, :nominal.shape[2]])


def test_the_effects_move_the_model():
    """Switched on, each term changes the trajectory (the kernel does not skip it): the opening limit
    slows a full-opening extension, the seal terms slow a loaded one."""
    u = np.full(300, 10.0)
    base = PLANT.replace(m_L=400.0)
    x_end = {}
    for name, plant in (("nominal", base), ("opening", base.replace(**OPENING)), ("seals", base.replace(**SEALS))):
        p = plant.vector()
        x_end[name] = sam.simulate_batch(p, u, DT, x0=sam.initial_state(p[None, :], 0.1)[0])["x"][0, -1]
    assert x_end["opening"] < x_end["nominal"] - 0.01
    assert x_end["seals"] < x_end["nominal"]
