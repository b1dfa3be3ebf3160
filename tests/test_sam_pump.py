"""A pump-limited supply (sam.supply, Effects.Q_pump): a fixed pump behind a relief valve whose
override is R_supply, checked in closed form (neutral by default to the last bit and the same on
one lane as on a block of lanes: tests/test_sam_effects.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sam
from sam import P, S
from sam.constants import LPM
from sam.dynamics import D, areas, derive, rhs
from sam.hydraulics import flow_coefficient, supply_flow, valve_flows
from sam.measurement import supply_pressure
from sam.supply import relief_cracking_pressure

PLANT = sam.load_plant()
DT = 1e-3
#: the development set's pumps (15-22 L/min) behind a relief of 0.5 MPa override
PUMP = {"Q_pump": 15.0 * LPM, "R_supply": 0.5e6 / (15.0 * LPM)}


def _valve_args(p, x_s, p_A, p_B):
    """valve_flows' arguments of parameter vector p at spool position x_s and chamber pressures [Pa]."""
    K = [flow_coefficient(p[P[f"Q_N_{e}"]], p[P[f"dp_N_{e}"]]) for e in ("PA", "AT", "PB", "BT")]
    return (x_s, p_A, p_B, p[P.offset], p[P.p_S], p[P.p_T], *K, p[P.K_leak_PA], p[P.K_leak_AT], p[P.K_leak_PB],
            p[P.K_leak_BT], p[P.leak_band], p[P.lap], p[P.R_supply], p[P.Q_sat], p[P.x_open], p[P.Q_pump])


# ------------------------------------------------------------------------------------ closed form


def test_the_relief_holds_the_supply_until_the_valve_draws_the_pump_flow_then_it_collapses():
    """p_S = 10 MPa, a 15 L/min pump, a relief cracking at 9.5 MPa. At a small opening (x_s = 0.1,
    p_A = 3.5 MPa) the valve draws less than the pump: the edge passes k sqrt(p_S - R q - p_A), the
    relief's droop (cracking pressure below the supply); fully open (x_s = 0.8) it would draw 26 L/min
    at p_S: it passes exactly the pump's 15 L/min, and the supply pressure falls below cracking to
    p_A + (Q_pump / k)^2; at p_A = 7.5 MPa the same opening draws less than the pump again."""
    p = PLANT.replace(**PUMP).vector()
    Q, R, p_S = p[P.Q_pump], p[P.R_supply], p[P.p_S]
    assert relief_cracking_pressure(p_S, R, Q) == pytest.approx(9.5e6, rel=1e-12)
    K_PA = flow_coefficient(p[P.Q_N_PA], p[P.dp_N_PA])
    q = valve_flows(*_valve_args(p, 0.1, 3.5e6, 1e6))[0]
    assert q < Q
    assert q == pytest.approx(K_PA * 0.1 * math.sqrt(p_S - R * q - 3.5e6), rel=1e-12)
    unlimited = K_PA * 0.8 * math.sqrt(p_S - 3.5e6)
    assert unlimited / LPM == pytest.approx(26.2, abs=0.1)
    assert valve_flows(*_valve_args(p, 0.8, 3.5e6, 1e6))[0] == pytest.approx(Q, rel=1e-12)
    # at a higher load pressure the same opening draws less than the pump: the relief holds again
    q_high = valve_flows(*_valve_args(p, 0.8, 7.5e6, 1e6))[0]
    assert q_high < Q
    assert q_high == pytest.approx(K_PA * 0.8 * math.sqrt(p_S - R * q_high - 7.5e6), rel=1e-12)
    drawn = supply_flow(0.8, 3.5e6, 1e6, 0.0, p_S, K_PA, K_PA, 0.0, R, math.inf, math.inf, Q)
    assert drawn == pytest.approx(Q, rel=1e-12)
    # the pressure the transmitter on the supply line reads: the droop, then the collapse
    states = {"x_s": np.array([0.1, 0.8]), "p_A": np.array([3.5e6, 3.5e6]), "p_B": np.array([1e6, 1e6])}
    p_at_valve = supply_pressure(states, p)
    assert p_at_valve[0] == pytest.approx(p_S - R * q, rel=1e-12)
    assert p_at_valve[1] == pytest.approx(3.5e6 + (Q / (K_PA * 0.8)) ** 2, rel=1e-12)
    assert p_at_valve[1] < 9.5e6


def test_the_tank_edges_and_a_back_flow_are_not_limited_by_the_pump():
    """Retracting fully open, the pump limits the flow into B to Q_pump; the flow out of A to the tank
    is the orifice's (the pump is on the supply side only)."""
    p = PLANT.replace(Q_pump=10.0 * LPM).vector()
    K_AT = flow_coefficient(p[P.Q_N_AT], p[P.dp_N_AT])
    Q_A, Q_B, _, _ = valve_flows(*_valve_args(p, -0.9, 4e6, 2e6))
    assert Q_B == pytest.approx(10.0 * LPM, rel=1e-12)
    assert Q_A == pytest.approx(-K_AT * 0.9 * math.sqrt(4e6), rel=1e-12)


def test_a_collapsed_supply_fills_chamber_A_at_the_pump_flow():
    """Eqs. (8)-(9) with the supply collapsed: dp_A/dt = B_eff (Q_pump - A_A v) / (V_0A + A_A x) at a
    full opening, whatever the pressures (a flow source), to the rounding of the sum."""
    p = PLANT.replace(Q_pump=12.0 * LPM).vector()
    A_A, _ = areas(p[P.D_piston], p[P.D_rod])
    d, ds = np.empty(len(D)), np.empty(7)
    derive(p, d)
    for p_A, v in ((3e6, 0.02), (6e6, 0.05)):
        s = np.array([p_A, 1e6, 0.9, 0.0, 0.2, v, 0.0])
        rhs(s, 9.0, p, d, ds)
        expect = p[P.B_eff] * (12.0 * LPM - A_A * v) / (p[P.V_0A] + A_A * 0.2)
        assert ds[S.p_A] == pytest.approx(expect, rel=1e-9)


def test_a_pump_limited_extension_moves_at_the_pump_flow_over_the_piston_area():
    """A loaded extension fully open for 3 s behind a 12 L/min pump: the piston travels Q_pump t / A_A
    less what the oil in A compresses (V dp / B), within 2 %; without the pump it travels faster."""
    base = PLANT.replace(m_L=400.0)
    u = np.full(3000, 10.0)
    travel = {}
    for name, plant in (("pump", base.replace(Q_pump=12.0 * LPM)), ("ideal", base)):
        p = plant.vector()
        r = sam.simulate_batch(p, u, DT, x0=sam.initial_state(p[None, :], 0.02)[0], scheme="rk4", substeps=4)
        travel[name] = (r["x"][0, -1] - r["x"][0, 0], r["p_A"][0, -1] - r["p_A"][0, 0], r["x"][0, -1])
    p = base.vector()
    A_A, _ = areas(p[P.D_piston], p[P.D_rod])
    dx, dp, x_end = travel["pump"]
    compressed = (p[P.V_0A] + A_A * x_end) * dp / p[P.B_eff]
    assert dx == pytest.approx((12.0 * LPM * 3.0 - compressed) / A_A, rel=0.02)
    assert travel["ideal"][0] > 1.2 * dx
