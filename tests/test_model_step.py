"""The model's one step, sam.dynamics.step: Eq. (22) by default, bit for bit; sub-steps and
higher-order schemes that converge at their order; end stops, rails and the cavitation floor
kept under every scheme; the scenario's [numerics] table."""

from __future__ import annotations

from pathlib import Path

import numba
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import sam
from sam import P, S
from sam.constants import LPM, P_CAVITATION
from sam.dynamics import D, N_DERIVED, N_SCRATCH, derive, euler_step, rhs
from sam.errors import UserError
from sam.hydraulics import inverse_capacitance
from sam.scenario import run_scenario, scenario_from_table

PLANT = sam.load_plant()
DT = 1e-3
SCHEMES = tuple(sam.SCHEMES)


@numba.njit(cache=True)
def _euler_loop(s, u, p, dt):
    """Eq. (22) as it was before sub-steps: euler_step once per step."""
    d, ds = np.empty(N_DERIVED), np.empty(7)
    derive(p, d)
    out = np.empty((u.shape[0] + 1, 7))
    out[0] = s
    for k in range(u.shape[0]):
        euler_step(s, u[k], p, d, dt, ds)
        out[k + 1] = s
    return out


def _moving_state(p):
    """A state in steady extension at 3 V, 0.6 s after a start at x = 0.05 m (no stop, no rail)."""
    warm = sam.simulate_batch(p, np.full(600, 3.0), DT, x0=sam.initial_state(p, 0.05), substeps=100, scheme="rk4")
    return np.array([warm[k][0, -1] for k in S.__members__])


def test_defaults_are_eq22_bit_for_bit():
    """simulate_batch and step_batch with their defaults, and with substeps = 1, scheme = "euler"
    given, are euler_step once per step, to the last bit: every caller's results, and every
    pinned figure, stay what they were. Reversals, the retracted stop, faults and a load change."""
    p = PLANT.replace(m_L=650.0).vector()
    p[P.K_int], p[P.offset] = 2e-9, 0.01
    u = 6.0 * np.sign(np.sin(np.arange(3000) * DT * 2 * np.pi * 0.4))
    x0 = sam.initial_state(p, 0.02)
    loop = _euler_loop(x0.copy(), u, p, DT)
    for kw in ({}, {"substeps": 1, "scheme": "euler"}):
        res = sam.simulate_batch(p, u, DT, x0=x0, **kw)
        assert np.array_equal(np.stack([res[k][0] for k in S.__members__], axis=1), loop)
    s = loop[1234][None].copy()
    assert np.array_equal(sam.step_batch(s, u[1234:1235], p[None], DT)[0][0], loop[1235])
    assert np.array_equal(sam.step_batch(s, u[1234:1235], p[None], DT, 1, 0)[0][0], loop[1235])
    assert np.min(loop[:, S.x]) == 0.0  # the run met the stop


@pytest.mark.parametrize("scheme, order", [("euler", 1), ("semi_implicit", 1), ("heun", 2), ("rk4", 4)])
def test_each_scheme_converges_at_its_order(scheme, order):
    """In smooth motion (extension under 3 V +- 1 V at 2 Hz, no stop, no rail) halving the sub-step
    divides the largest pressure error against RK4 at 5 us by 2^order (within 15 %; RK4 until
    its error reaches the rounding of the reference)."""
    p = PLANT.vector()
    s0 = _moving_state(p)
    u = 3.0 + np.sin(2 * np.pi * 2.0 * np.arange(400) * DT)
    ref = sam.simulate_batch(p, u, DT, x0=s0, substeps=200, scheme="rk4")

    def error(n):
        r = sam.simulate_batch(p, u, DT, x0=s0, substeps=n, scheme=scheme)
        return max(np.max(np.abs(r[k][0] - ref[k][0])) for k in ("p_A", "p_B"))

    e1, e2 = error(1), error(2)
    assert e1 / e2 == pytest.approx(2.0**order, rel=0.15)
    assert error(4) < e2


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("substeps", [1, 3])
def test_every_scheme_lands_a_chamber_on_its_rail(scheme, substeps):
    """On the retracted stop with the valve open to retract (-4 V, the stiffest case the paper's
    machine meets), chamber A drains onto the tank and B fills to the supply, monotonically and
    without crossing them; within 5 Pa after 1 s; the piston stays on the stop, every pressure
    above the cavitation floor."""
    p = PLANT.vector()
    res = sam.simulate_batch(p, np.full(3000, -4.0), DT, x0=sam.initial_state(p, 0.01), substeps=substeps,
                             scheme=scheme)
    p_A, p_B, x = res["p_A"][0, -1000:], res["p_B"][0, -1000:], res["x"][0, -1000:]
    assert np.all(x == 0.0)
    assert np.all(np.diff(p_A) <= 1.0) and np.all(p_A >= p[P.p_T] - 1.0)
    assert np.all(np.diff(p_B) >= -1.0) and np.all(p_B <= p[P.p_S] + 1.0)
    assert np.max(np.abs(p_A - p[P.p_T])) < 5.0 and np.max(np.abs(p_B - p[P.p_S])) < 5.0
    assert np.all(res["p_A"] >= P_CAVITATION) and np.all(res["p_B"] >= P_CAVITATION)


@settings(max_examples=30, deadline=None)
@given(scheme=st.sampled_from(SCHEMES), gap=st.floats(0.0, 30e-6), speed=st.floats(0.0, 0.1),
       extended=st.booleans(), p_A=st.floats(1e6, 9e6), p_B=st.floats(1e6, 9e6))
def test_a_step_that_reaches_a_stop_displaces_only_its_travel_in_every_scheme(scheme, gap, speed, extended, p_A, p_B):
    """Volume is conserved at an end stop under every scheme: with the valve closed and no leak,
    a step that reaches the stop changes each chamber's pressure by exactly c A times the travel
    to the stop (the Runge-Kutta schemes take the Euler update there; the semi-implicit one moves
    at its new velocity, v + dt dv/dt)."""
    p = PLANT.vector()
    for notch in ("PA", "AT", "PB", "BT"):
        p[P[f"K_leak_{notch}"]] = 0.0
    d = np.empty(N_DERIVED)
    derive(p, d)
    x0, v, sign = (d[D.x_end] - gap, speed, -1.0) if extended else (gap, -speed, 1.0)
    s = np.array([p_A, p_B, 0.0, 0.0, x0, v, 0.0])
    f = np.empty(7)
    rhs(s, 0.0, p, d, f)
    v_move = v + DT * f[S.v] if scheme == "semi_implicit" else v
    travel = min(gap, abs(v_move) * DT) if v_move * sign < 0 else None
    new, _ = sam.step_batch(s[None], np.array([0.0]), p[None], DT, 1, int(sam.SCHEMES[scheme]))
    reaches = x0 + DT * v > d[D.x_end] if extended else x0 + DT * v < 0.0
    if travel is None or (scheme in ("heun", "rk4") and not reaches):
        return  # the step moves away from the stop, or does not reach it (then RK4 and Heun move as they should)
    c = [inverse_capacitance(V, pc, p[P.B_eff], p[P.air_fraction], p[P.C_hose])
         for V, pc in ((p[P.V_0A] + d[D.A_A] * x0, p_A), (p[P.V_0B] + d[D.A_B] * (p[P.x_max] - x0), p_B))]
    assert new[0, 0] - p_A == pytest.approx(sign * c[0] * d[D.A_A] * travel, rel=1e-9, abs=1e-6)
    assert new[0, 1] - p_B == pytest.approx(-sign * c[1] * d[D.A_B] * travel, rel=1e-9, abs=1e-6)


GSA_BOX = {
    "offset": (-0.05, 0.05), "Q_N_PA": (15 * LPM, 35 * LPM), "dp_N_PA": (5e5, 40e5),
    "Q_N_BT": (15 * LPM, 35 * LPM), "dp_N_BT": (5e5, 40e5), "B_eff": (3e8, 1.2e9),
    "K_int": (0.0, 5.27e-9), "K_extA": (0.0, 5.27e-9),
}


@settings(max_examples=20, deadline=None)
@given(unit=st.lists(st.floats(0.0, 1.0), min_size=len(GSA_BOX), max_size=len(GSA_BOX)),
       u=st.sampled_from([2.5, -2.5, 10.0, -10.0]), m_L=st.floats(0.0, 800.0),
       scheme=st.sampled_from(SCHEMES), substeps=st.integers(1, 3))
def test_no_nan_under_any_scheme_over_the_parameter_box(unit, u, m_L, scheme, substeps):
    """Over the box of Tables 1 and 5, loads 0-800 kg, both directions and full opening, every
    scheme stays finite, above the cavitation floor and within the stroke for 2 s."""
    p = PLANT.replace(m_L=m_L).vector()
    for (name, (lo, hi)), w in zip(GSA_BOX.items(), unit):
        p[P[name]] = lo + w * (hi - lo)
    res = sam.simulate_batch(p, np.full(2000, u), DT, x0=sam.initial_state(p, 0.0 if u > 0 else 0.3),
                             record_every=10, substeps=substeps, scheme=scheme)
    assert all(np.all(np.isfinite(res[k])) for k in S.__members__)
    assert np.all(res["p_A"] >= P_CAVITATION) and np.all(res["p_B"] >= P_CAVITATION)
    assert np.all((res["x"] >= 0) & (res["x"] <= p[P.x_max]))


@pytest.mark.parametrize("scheme", SCHEMES)
def test_step_batch_is_the_simulators_step_in_every_scheme(scheme):
    """The filter's process model (step_batch) and the simulator take the same step, for every
    scheme and sub-step count: the same numbers."""
    p = PLANT.replace(B_eff=9e8).vector()
    kw = {"substeps": 2, "scheme": scheme}
    res = sam.simulate_batch(p, np.full(200, 2.5), DT, **kw)
    s = np.array([res[k][0, 100] for k in S.__members__])
    nxt, _ = sam.step_batch(s[None], np.array([2.5]), p[None], DT, 2, int(sam.SCHEMES[scheme]))
    assert np.array_equal(nxt[0], [res[k][0, 101] for k in S.__members__])
    assert N_SCRATCH >= 6 * 7


def test_the_scenario_chooses_the_step(tmp_path):
    """[numerics] substeps and scheme reach the simulation (the same numbers as simulate_batch
    with them) and the recording's metadata; a bad value is one line naming the key."""
    base = {"duration_s": 1.0, "seed": 2, "input": {"kind": "step", "amplitude_V": 2.5}, "initial": {"x_m": 0.05}}
    sc = scenario_from_table({**base, "numerics": {"substeps": 4, "scheme": "heun"}}, tmp_path / "s.toml")
    rec = run_scenario(sc)
    p = sc.plant.vector()
    res = sam.simulate_batch(p, sc.u, sc.dt, x0=sam.initial_state(p, 0.05), substeps=4, scheme="heun")
    assert np.array_equal(rec.truth["true_pA"], res["p_A"][0])
    assert rec.metadata["model_step"] == "heun, 4 x 0.00025 s"
    for numerics, words in (({"substeps": 0}, "numerics.substeps"), ({"scheme": "rk5"}, "numerics.scheme"),
                            ({"substep": 2}, "numerics.substep"), ({"substeps": 1.5}, "numerics.substeps")):
        with pytest.raises(UserError, match=words.replace(".", r"\.")) as info:
            scenario_from_table({**base, "numerics": numerics}, Path("s.toml"))
        assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="scheme"):
        sam.simulate_batch(p, sc.u, sc.dt, scheme="midpoint")
