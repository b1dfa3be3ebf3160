"""Physics checks of the shared model: closed forms, conservation, hand calculations.

Each test states the physics it checks. Nothing here checks shapes only.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import sam
from sam import P, S
from sam.constants import LPM, P_CAVITATION
from sam.dynamics import D, N_DERIVED, derive, rhs
from sam.friction import stribeck
from sam.geometry import external_force, joint_angle, piston_position, torque_arm
from sam.hydraulics import valve_flows

PLANT = sam.load_plant()
DT = 1e-3


def derived(p):
    d = np.empty(N_DERIVED)
    derive(p, d)
    return d


def run(p, u, seconds, x0=None, **kw):
    n = int(round(seconds / DT))
    return sam.simulate_batch(p, np.full(n, u), DT, x0=x0, **kw)


def final_state(res):
    return np.array([res[name][0, -1] for name in S.__members__])


def boom_force(p, x):
    return external_force(x, p[P.L_1], p[P.L_2], p[P.L_3], p[P.theta_level], p[P.cog_angle], p[P.m_B],
                          p[P.r_B], p[P.m_L], p[P.m_R], p[P.L])


def steady_friction(p, v):
    """LuGre in steady sliding: sigma_0 z_ss = g(v) sgn(v), plus viscous b v (Eq. (17))."""
    return np.sign(v) * stribeck(v, p[P.F_C], p[P.F_S], p[P.v_s]) + p[P.b] * v


def test_geometry_retracted_angle_and_inverse():
    """Appendix 2: theta = 0.728 rad with the cylinder retracted (x = 0), Eq. (3) and its inverse."""
    b = PLANT.boom
    assert piston_position(0.728, b.L_1, b.L_2, b.L_3) == pytest.approx(0.0, abs=2e-4)
    x = np.linspace(0.0, 0.4, 9)
    np.testing.assert_allclose(piston_position(joint_angle(x, b.L_1, b.L_2, b.L_3), b.L_1, b.L_2, b.L_3), x, atol=1e-12)


def test_torque_arm_is_derivative_of_position():
    """Eq. (5) is dx/dtheta of Eq. (3)."""
    b = PLANT.boom
    theta, h = 1.2, 1e-6
    dx = (piston_position(theta + h, b.L_1, b.L_2, b.L_3) - piston_position(theta - h, b.L_1, b.L_2, b.L_3)) / (2 * h)
    x = piston_position(theta, b.L_1, b.L_2, b.L_3)
    assert torque_arm(x, b.L_1, b.L_2, b.L_3) == pytest.approx(dx, rel=1e-8)


def test_leak_of_table5_upper_bound_is_one_litre_per_minute():
    """Table 5: K = 5.27e-9 m^3/(s Pa^0.5) passes 1 L/min at 10 MPa (Eqs. (41)-(43))."""
    from sam.hydraulics import fault_leakages

    _, Q_extA, _ = fault_leakages(10e6, 0.0, 0.0, 0.0, 5.27e-9, 0.0)
    assert Q_extA / LPM == pytest.approx(1.00, abs=0.005)


def test_leak_flows_over_recordings_are_eqs_41_43_at_every_sample():
    """fault_leakages_batch (B, T) is the scalar fault_leakages at every sample, and that is the
    closed form K sgn(dp) sqrt(|dp|) of Eqs. (41)-(43): the internal leak reverses where p_B > p_A,
    an external one where a chamber drops below tank pressure, and a zero K passes nothing."""
    from sam.hydraulics import fault_leakages_batch

    rng = np.random.default_rng(41)
    B, T = 3, 50
    p_A, p_B = rng.uniform(-0.5e6, 21e6, (2, B, T))
    p_T = rng.uniform(0.0, 0.3e6, B)
    K = rng.uniform(0.0, 5.27e-9, (3, B, T))
    K[1, 0] = 0.0  # run 0 has no K_extA
    Q = fault_leakages_batch(p_A, p_B, p_T, K[0], K[1], K[2])
    ssqrt = lambda dp: np.sign(dp) * np.sqrt(np.abs(dp))  # noqa: E731
    expect = np.stack([K[0] * ssqrt(p_A - p_B), K[1] * ssqrt(p_A - p_T[:, None]), K[2] * ssqrt(p_B - p_T[:, None])])
    np.testing.assert_allclose(Q, expect, rtol=1e-13, atol=0.0)
    assert (Q[1, 0] == 0.0).all() and (Q[0][p_B > p_A] < 0).all()


def test_steady_state_matches_closed_form_eqs_39_40():
    """Eqs. (39)-(40), friction folded into F_ext, within 1 %.

    Eq. (39) is used with F_ext A_A^2 K_BT^2 (the printed A_A A_B violates the
    piston's force balance; docs/model.md).
    """
    p = PLANT.vector()
    s = final_state(run(p, 2.5, 3.0))
    d = derived(p)
    A_A, A_B, K_PA, K_BT = d[D.A_A], d[D.A_B], d[D.K_PA], d[D.K_BT]
    p_S, p_T = p[P.p_S], p[P.p_T]
    F = boom_force(p, s[S.x]) + steady_friction(p, s[S.v])
    den = A_A**3 * K_BT**2 + A_B**3 * K_PA**2
    p_A = (F * A_A**2 * K_BT**2 + A_B**3 * K_PA**2 * p_S + A_A**2 * A_B * K_BT**2 * p_T) / den
    p_B = (-F * K_PA**2 * A_B**2 + A_A * A_B**2 * K_PA**2 * p_S + A_A**3 * K_BT**2 * p_T) / den
    assert s[S.p_A] == pytest.approx(p_A, rel=0.01)
    assert s[S.p_B] == pytest.approx(p_B, rel=0.01)
    assert s[S.p_A] * A_A - s[S.p_B] * A_B == pytest.approx(F, rel=0.01)


@pytest.mark.parametrize("u", [2.5, -2.5, 6.0])
def test_volume_flows_balance_in_steady_motion(u):
    """In steady motion the valve flows fill and empty the chambers: A_A v = Q_A, A_B v = -Q_B (1 %)."""
    p = PLANT.vector()
    x0 = 0.0 if u > 0 else 0.3
    s = final_state(run(p, u, 3.0, x0=sam.initial_state(p, x0)))  # retraction rings for ~2.5 s
    d = derived(p)
    Q_A, Q_B, _, _ = valve_flows(
        s[S.x_s], s[S.p_A], s[S.p_B], p[P.offset], p[P.p_S], p[P.p_T], d[D.K_PA], d[D.K_AT],
        d[D.K_PB], d[D.K_BT], p[P.K_leak_PA], p[P.K_leak_AT], p[P.K_leak_PB], p[P.K_leak_BT],
        p[P.leak_band], p[P.lap], p[P.R_supply], p[P.Q_sat])
    assert abs(s[S.v]) > 5e-3
    assert d[D.A_A] * s[S.v] == pytest.approx(Q_A, rel=0.01)
    assert d[D.A_B] * s[S.v] == pytest.approx(-Q_B, rel=0.01)


def test_centred_valve_drifts_only_by_null_leakage():
    """Valve closed and centred, no faults: the load sinks at the rate the laminar null
    leakage of Eqs. (13)-(14) lets it, found by hand from flow and force balances. 800 kg at
    x = 0.15 m: there the null-leakage pressures hold the default plant's 494 kg by stiction."""
    p = PLANT.replace(m_L=800.0).vector()
    x0 = 0.15
    res = run(p, 0.0, 6.0, x0=sam.initial_state(p, x0))
    s = final_state(res)
    d = derived(p)
    A_A, A_B, p_S = d[D.A_A], d[D.A_B], p[P.p_S]

    def force_residual(v):
        p_A = (p[P.K_leak_PA] * p_S - A_A * v) / (p[P.K_leak_PA] + p[P.K_leak_AT])
        p_B = (p[P.K_leak_PB] * p_S + A_B * v) / (p[P.K_leak_PB] + p[P.K_leak_BT])
        return p_A * A_A - p_B * A_B - boom_force(p, s[S.x]) - steady_friction(p, v)

    v_hand = brentq(force_residual, -0.05, -1e-9)
    assert -5e-3 < v_hand < -1e-4  # sinking, about a millimetre per second
    assert s[S.v] == pytest.approx(v_hand, rel=0.02)
    # and without the null leakage the piston would hold still
    p_tight = PLANT.replace(m_L=800.0, K_leak_PA=0.0, K_leak_AT=0.0, K_leak_PB=0.0, K_leak_BT=0.0).vector()
    held = run(p_tight, 0.0, 2.0, x0=sam.initial_state(p, x0))
    assert abs(held["x"][0, -1] - x0) < 1e-6


@settings(max_examples=40, deadline=None)
@given(x=st.floats(1e-3, 0.43), m_L=st.floats(0.0, 800.0))
def test_the_start_at_rest_balances_the_load_without_cavitating(x, m_L):
    """At rest with the valve centred, anywhere on the stroke and for loads 0-800 kg: the chambers
    balance the boom exactly (p_A A_A - p_B A_B = F_ext, Eq. (21)), neither below the cavitation
    floor; one chamber sits at its null-leakage pressure, the other carries the load."""
    p = PLANT.replace(m_L=m_L).vector()
    s = sam.initial_state(p, x)
    d = derived(p)
    force = s[S.p_A] * d[D.A_A] - s[S.p_B] * d[D.A_B]
    assert force == pytest.approx(boom_force(p, x), rel=1e-9, abs=1e-6)
    assert min(s[S.p_A], s[S.p_B]) >= P_CAVITATION
    null = sam.initial_state(p, 0.0)  # on the stop both chambers sit at their null-leakage pressures
    assert s[S.p_B] == null[S.p_B] or s[S.p_A] == P_CAVITATION


def test_a_boom_past_vertical_is_held_by_the_rod_side():
    """Past vertical (default plant, 800 kg at x = 0.42 m) the boom pulls the piston out; at rest
    chamber A sits at the cavitation floor and chamber B holds the boom: with sealed chambers it
    stays where it started."""
    p = PLANT.replace(m_L=800.0, K_leak_PA=0.0, K_leak_AT=0.0, K_leak_PB=0.0, K_leak_BT=0.0).vector()
    assert boom_force(p, 0.42) < 0.0  # pulling
    s = sam.initial_state(p, 0.42)
    assert s[S.p_A] == P_CAVITATION and s[S.p_B] > sam.initial_state(p, 0.0)[S.p_B]
    held = run(p, 0.0, 1.0, x0=s)
    assert abs(held["x"][0, -1] - 0.42) < 1e-6


def linearised_frequency_hz(p, s, u):
    d = derived(p)

    def f(state):
        ds = np.empty(7)
        rhs(state, u, p, d, ds)
        return ds

    J = np.empty((7, 7))
    for j in range(7):
        h = 1e-6 * max(abs(s[j]), 1e-3)
        e = np.zeros(7)
        e[j] = h
        J[:, j] = (f(s + e) - f(s - e)) / (2 * h)
    ev = np.linalg.eigvals(J)
    hydraulic = ev[(np.abs(ev.imag) > 1.0) & (np.abs(ev) < 100.0)]  # spool modes sit at 2 pi 20 rad/s
    return np.abs(hydraulic[0]) / (2 * np.pi)


@pytest.mark.parametrize("B_eff, expected_hz", [(7.5e8, 6.93), (3.0e8, 4.54)])
def test_hydraulic_natural_frequency(B_eff, expected_hz):
    """The model's linearised hydraulic mode at the paper's operating point agrees with the
    classic sqrt(B/m (A_A^2/V_A + A_B^2/V_B)) within 10 % (the classic form ignores the
    valve's and friction's stiffness); the paper's Fig. 4 gives 4.5 Hz (docs/model.md)."""
    p = PLANT.replace(B_eff=B_eff).vector()
    s = final_state(run(p, 2.5, 2.0))
    d = derived(p)
    x = s[S.x]
    V_A, V_B = p[P.V_0A] + d[D.A_A] * x, p[P.V_0B] + d[D.A_B] * (p[P.x_max] - x)
    m = 1.0 / (d[D.inv_J_tot] * torque_arm(x, p[P.L_1], p[P.L_2], p[P.L_3]) ** 2)
    f_classic = np.sqrt(B_eff / m * (d[D.A_A] ** 2 / V_A + d[D.A_B] ** 2 / V_B)) / (2 * np.pi)
    f_model = linearised_frequency_hz(p, s, 2.5)
    assert f_model == pytest.approx(f_classic, rel=0.10)
    assert f_model == pytest.approx(expected_hz, rel=0.02)


def test_euler_at_1ms_tracks_tight_reference_solution():
    """Eq. (22) at T = 1 ms against a tight-tolerance implicit solution of the same
    right-hand side (Eq. (19)): pressures within 0.6 % of p_S throughout; velocity within
    2 % of the peak speed in the transient and 0.2 % in the last 0.1 s. The error is the
    scheme's, first order: half the step halves it."""
    p = PLANT.vector()
    d = derived(p)
    x0 = sam.initial_state(p, 0.05)
    seconds, u = 1.0, 2.5

    def f(_, s):
        ds = np.empty(7)
        rhs(s, u, p, d, ds)
        return ds

    ref = solve_ivp(f, (0, seconds), x0, method="Radau", rtol=1e-9,
                    atol=[1.0, 1.0, 1e-9, 1e-7, 1e-10, 1e-10, 1e-12], t_eval=np.arange(0, 1001) * DT)
    assert ref.success
    euler = run(p, u, seconds, x0=x0)
    error = np.max(np.abs(euler["p_A"][0] - ref.y[S.p_A]))
    assert error < 0.006 * p[P.p_S]
    assert np.max(np.abs(euler["p_B"][0] - ref.y[S.p_B])) < 0.006 * p[P.p_S]
    half = run(p, u, seconds, x0=x0, substeps=2)
    assert np.max(np.abs(half["p_A"][0] - ref.y[S.p_A])) == pytest.approx(error / 2, rel=0.1)
    v_err = np.abs(euler["v"][0] - ref.y[S.v])
    assert np.max(v_err) < 0.02 * np.max(np.abs(ref.y[S.v]))
    assert np.max(v_err[-100:]) < 0.002 * np.max(np.abs(ref.y[S.v]))


def test_batched_and_single_runs_agree_bit_for_bit():
    rng = np.random.default_rng(3)
    params = np.tile(PLANT.vector(), (16, 1))
    params[:, P.B_eff] = rng.uniform(3e8, 1.2e9, 16)
    params[:, P.K_int] = rng.uniform(0, 5.27e-9, 16)
    params[:, P.offset] = rng.uniform(-0.05, 0.05, 16)
    u = 2.5 * np.sign(np.sin(np.arange(3000) * DT * 2 * np.pi * 0.5))
    batch = sam.simulate_batch(params, u, DT, record_every=7)
    for i in (0, 5, 15):
        single = sam.simulate_batch(params[i], u, DT, record_every=7)
        for name in S.__members__:
            assert np.array_equal(batch[name][i], single[name][0])


def test_step_batch_equals_simulator_step():
    """The filter's process model (step_batch) is the simulator's step: same numbers."""
    p = PLANT.replace(B_eff=9e8).vector()
    res = run(p, 2.5, 0.2)
    s = np.array([res[name][0, 100] for name in S.__members__])
    nxt, _ = sam.step_batch(s[None], np.array([2.5]), p[None], DT)
    assert np.array_equal(nxt[0], [res[name][0, 101] for name in S.__members__])


def test_step_batch_rows_are_independent_in_any_memory_layout():
    """Each row of a batch, stepped through borrowed row views (sam.views), equals that row
    stepped alone; Fortran-ordered inputs give the same numbers; the in-place step writes
    exactly what the allocating one returns."""
    rng = np.random.default_rng(11)
    params = np.repeat(PLANT.vector()[None], 6, axis=0)
    params[:, P.K_int] = rng.uniform(0, 5.27e-9, 6)
    params[:, P.offset] = rng.uniform(-0.05, 0.05, 6)
    params[:, P.m_L] = rng.uniform(0, 800, 6)
    states = sam.initial_state(params, x=0.2)
    states[:, S.x_s] = rng.uniform(-0.5, 0.5, 6)
    u = rng.uniform(-5, 5, 6)
    new, _ = sam.step_batch(states, u, params, DT)
    alone = [sam.step_batch(states[i:i + 1], u[i:i + 1], params[i:i + 1], DT)[0][0] for i in range(6)]
    assert np.array_equal(new, np.array(alone))
    fortran, _ = sam.step_batch(np.asfortranarray(states), u, np.asfortranarray(params), DT)
    assert np.array_equal(new, fortran)
    inplace, flags = states.copy(), np.empty(6, dtype=np.int64)
    sam.step_batch_inplace(inplace, u, params, DT, flags)
    assert np.array_equal(inplace, new)
    assert not np.array_equal(new, states)  # it did step


@settings(max_examples=40, deadline=None)
@given(rows=st.lists(st.integers(0, 3), min_size=2, max_size=12))
def test_step_batch_derives_each_row_from_its_own_parameters(rows):
    """step_batch re-derives a row's constants only where its parameters differ from the row
    before (the geometry and the rest separately): any sequence of four machines (one a copy of
    another with faults and load force changed, which derive() does not read; one with another
    geometry; one with other notch flows and load) gives each row exactly what it gives alone."""
    base = PLANT.vector()
    faults = base.copy()
    faults[[P.K_int, P.K_extA, P.offset, P.F_d]] = [2e-9, 1e-9, 0.01, 500.0]
    geometry = base.copy()
    geometry[[P.theta_level, P.cog_angle, P.theta_max, P.L_3]] = [
        base[P.theta_level] - 0.05, 0.3, base[P.theta_max] - 0.1, base[P.L_3] * 1.02]
    machine = base.copy()
    machine[[P.Q_N_PA, P.m_L]] = [base[P.Q_N_PA] * 1.1, 700.0]
    params = np.array([(base, faults, geometry, machine)[r] for r in rows])
    states = sam.initial_state(params, x=0.2)
    states[:, S.x_s] = 0.3
    states[:, S.v] = 0.01
    u = np.full(len(rows), 2.0)
    new, _ = sam.step_batch(states, u, params, DT)
    alone = [sam.step_batch(states[i:i + 1], u[i:i + 1], params[i:i + 1], DT)[0][0] for i in range(len(rows))]
    assert np.array_equal(new, np.array(alone))


GSA_BOX = {  # Table 1 and Table 5
    "offset": (-0.05, 0.05), "Q_N_PA": (15 * LPM, 35 * LPM), "dp_N_PA": (5e5, 40e5),
    "Q_N_BT": (15 * LPM, 35 * LPM), "dp_N_BT": (5e5, 40e5), "B_eff": (3e8, 1.2e9),
    "b": (2000.0, 5000.0), "K_int": (0.0, 5.27e-9), "K_extA": (0.0, 5.27e-9), "K_extB": (0.0, 5.27e-9),
}


@settings(max_examples=60, deadline=None)
@given(unit=st.lists(st.floats(0.0, 1.0), min_size=len(GSA_BOX), max_size=len(GSA_BOX)),
       u=st.sampled_from([2.5, -2.5, 10.0, -10.0]), m_L=st.floats(0.0, 800.0))
def test_no_nan_or_inf_over_parameter_box(unit, u, m_L):
    """Over the whole box of Tables 1 and 5 (and loads 0-800 kg, both directions, full
    opening), a 4 s run stays finite and inside its physical bounds."""
    p = PLANT.replace(m_L=m_L).vector()
    for (name, (lo, hi)), w in zip(GSA_BOX.items(), unit):
        p[P[name]] = lo + w * (hi - lo)
    res = run(p, u, 4.0, x0=sam.initial_state(p, 0.0 if u > 0 else 0.3), record_every=10)
    for name in S.__members__:
        assert np.all(np.isfinite(res[name]))
    assert np.all(res["p_A"] >= sam.constants.P_CAVITATION)
    assert np.all((res["x"] >= 0) & (res["x"] <= p[P.x_max]))


def _last_seconds(res, name, seconds):
    return res[name][0, -int(round(seconds / DT)):]


@settings(max_examples=40, deadline=None)
@given(u=st.floats(1.0, 10.0), B_eff=st.floats(3e8, 1.2e9), m_L=st.floats(0.0, 800.0),
       Q_N=st.floats(15 * LPM, 35 * LPM),
       effect=st.sampled_from(["none", "R_supply", "Q_sat", "air_fraction", "C_hose"]), strength=st.floats(0.0, 1.0))
def test_a_chamber_pinned_to_the_tank_settles_on_it(u, B_eff, m_L, Q_N, effect, strength):
    """On the retracted end stop with the valve open to retract, chamber A drains through the
    open A->T edge and nothing else flows: p_A settles on the tank pressure and B on the supply
    (no load, no leak to balance them), and stays there; also with each optional effect of the
    mismatch library (supply droop, notch saturation, entrained air, hose compliance; ranges of
    discrepancy.library). Forward Euler did not: the edge's flow k sqrt(dp) has an infinite
    slope at dp = 0, and the 1 ms step crossed the rail every step, a period-2 oscillation of
    amplitude (dt c k x_s)^2 / 4 (11 kPa at 2.4 V; about 0.5 MPa at 10 V with the stiffest
    corner of this box: sam.dynamics.euler_step)."""
    p = PLANT.replace(m_L=m_L, B_eff=B_eff).vector()
    p[P.Q_N_AT] = Q_N
    box = {"R_supply": (1e7, 1e12), "Q_sat": (0.05 * Q_N, 2.5 * Q_N), "air_fraction": (1e-5, 0.1),
           "C_hose": (1e-15, 1e-10)}
    if effect in box:
        lo, hi = box[effect]
        p[P[effect]] = lo * (hi / lo) ** strength  # log-uniform, as the library's starts
    res = run(p, -u, 6.0, x0=sam.initial_state(p, 0.01), record_every=1)
    assert np.all(_last_seconds(res, "x", 1.0) == 0.0)  # on the stop
    p_A, p_B = _last_seconds(res, "p_A", 1.0), _last_seconds(res, "p_B", 1.0)
    # monotone onto the rails, never across them (a soft chamber, much air or a strong droop,
    # may still be on its way: physics, a time constant of seconds)
    tol = 1.0  # Pa: on the rail the step wiggles by DP_CONDUCTANCE_MIN / 4 about it
    assert np.all(np.diff(p_A) <= tol) and np.all(p_A >= p[P.p_T] - tol)
    assert np.all(np.diff(p_B) >= -tol) and np.all(p_B <= p[P.p_S] + tol)
    if effect == "none":  # and there
        assert np.max(np.abs(p_A - p[P.p_T])) < 5.0
        assert np.max(np.abs(p_B - p[P.p_S])) < 5.0


@pytest.mark.parametrize("path", [{"K_bypass": 4e-9}, {"K_int": 5 * 5.27e-9}, {"K_int": 5.27e-9}])
def test_a_path_between_the_chambers_relaxes_their_difference_without_swapping_them(path):
    """With the valve centred and the piston on its stop, a wide path between the chambers (a
    bypass, or a 1-5 L/min internal leak) is what sets their difference, and it is stiff: a step
    that held the other chamber fixed would land each on the other's pressure and swap them every
    millisecond. The difference settles monotonically (both pressures then drift slowly together
    by the null leakage)."""
    p = PLANT.vector()
    for name, value in path.items():
        p[P[name]] = value
    res = run(p, 0.0, 3.0, x0=sam.initial_state(p, 0.0), record_every=1)
    diff = _last_seconds(res, "p_A", 1.0) - _last_seconds(res, "p_B", 1.0)
    step = np.diff(diff)
    assert np.all(step <= 0.0) or np.all(step >= 0.0)  # monotone: no sign flips
    assert np.max(np.abs(np.diff(_last_seconds(res, "p_A", 1.0), n=2))) < 1.0  # Pa: no period-2 component


def test_a_stalled_piston_rests_with_its_pressures_on_the_rails():
    """900 kg cannot be lifted from x = 0.05 m at 10 MPa (the default plant lifts up to 819 kg,
    docs/model.md): with the valve open to extend, the piston stalls held by stiction, A fills to
    the supply and B drains to the tank, and both stay there without the step-to-step
    oscillation of forward Euler."""
    p = PLANT.replace(m_L=900.0).vector()
    res = run(p, 4.0, 4.0, x0=sam.initial_state(p, 0.05), record_every=1)
    x = _last_seconds(res, "x", 1.0)
    assert np.ptp(x) < 1e-6  # stalled
    assert np.max(np.abs(_last_seconds(res, "p_A", 1.0) - p[P.p_S])) < 5.0
    assert np.max(np.abs(_last_seconds(res, "p_B", 1.0) - p[P.p_T])) < 5.0


@settings(max_examples=60, deadline=None)
@given(x=st.floats(0.02, 0.4), v=st.floats(-0.05, 0.05), x_s=st.floats(-0.5, 0.5),
       p_A=st.floats(1e6, 9e6), p_B=st.floats(1e6, 9e6), u=st.floats(-10.0, 10.0))
def test_step_is_forward_euler_where_no_chamber_is_stiff(x, v, x_s, p_A, p_B, u):
    """Away from the rails (both chambers at least 1 MPa from the tank and the supply) no
    chamber is stiff at 1 ms, and the step is exactly Eq. (22)'s forward Euler, s + dt f(s):
    the semi-implicit pressure step changes nothing there."""
    p = PLANT.vector()
    d = derived(p)
    s = np.array([p_A, p_B, x_s, 0.0, x, v, 0.0])
    f = np.empty(7)
    rhs(s, u, p, d, f)
    new, _ = sam.step_batch(s[None], np.array([u]), p[None], DT)
    assert np.array_equal(new[0], s + DT * f)


@settings(max_examples=60, deadline=None)
@given(gap=st.floats(0.0, 30e-6), speed=st.floats(0.0, 0.1), extended=st.booleans(),
       p_A=st.floats(1e6, 9e6), p_B=st.floats(1e6, 9e6))
@example(gap=0.0, speed=0.05, extended=False, p_A=5e6, p_B=5e6)  # on the stop, pushing into it
def test_a_step_that_reaches_an_end_stop_displaces_only_its_travel(gap, speed, extended, p_A, p_B):
    """Volume is conserved at an end stop: with the valve closed and no leak, the chambers'
    pressures change by exactly the volume the piston sweeps, A * (travel), where the travel is
    v dt, or the gap to the stop when the step reaches it (0 for a piston already on the stop
    pushing into it: a filter's sigma point). Before, the step compressed a chamber by A v dt even
    where the stop cut the motion short (docs/model.md, "Numerics"), and the filter's offset
    absorbed the phantom flow at each lift-off."""
    from sam.hydraulics import inverse_capacitance

    p = PLANT.vector()
    for notch in ("PA", "AT", "PB", "BT"):
        p[P[f"K_leak_{notch}"]] = 0.0  # a closed valve passes nothing
    d = derived(p)
    x0, v, sign = (d[D.x_end] - gap, speed, -1.0) if extended else (gap, -speed, 1.0)
    travel = min(gap, speed * DT)
    s = np.array([p_A, p_B, 0.0, 0.0, x0, v, 0.0])
    new, _ = sam.step_batch(s[None], np.array([0.0]), p[None], DT)
    c = [inverse_capacitance(V, pc, p[P.B_eff], p[P.air_fraction], p[P.C_hose])
         for V, pc in ((p[P.V_0A] + d[D.A_A] * x0, p_A), (p[P.V_0B] + d[D.A_B] * (p[P.x_max] - x0), p_B))]
    assert new[0, 0] - p_A == pytest.approx(sign * c[0] * d[D.A_A] * travel, rel=1e-9, abs=1e-6)
    assert new[0, 1] - p_B == pytest.approx(-sign * c[1] * d[D.A_B] * travel, rel=1e-9, abs=1e-6)
