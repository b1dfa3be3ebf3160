"""Each of the rig's effects leaves the signature its physics predicts, where that is cheap to see:
in a recording where it can be, else in the equation that carries it. Faults follow their time
profiles, loads change, geometry tolerances show between the logged and the true position."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st
from rig_cases import scenario, settings

import rig
import sam
from rig.hydraulics import chamber_pressure, free_air_equilibrium, leak_flows, metering_area, valve_flows
from rig.layout import P_ATM, C
from rig.mechanics import gravity_torque, lugre, seal_friction_levels, torque_arm

K_U = 0.1  #: 1/V, the plant file's gain from command to spool


def _machine(**effects):
    return rig.build(sam.load_plant(), settings(**effects), np.random.default_rng(0))


def _ring_frequency(**effects) -> float:
    """Hz of the hydraulic mode that rings when the valve closes on a moving boom (4 V, 494 kg):
    from the first two zero crossings of the velocity after the closure."""
    sc = scenario(duration_s=1.3, x0=0.05, input={"kind": "step", "amplitude_V": 0.0, "initial_V": 4.0, "t0_s": 0.8})
    r = rig.simulate(sc, settings(**effects))
    v, t = r.truth["v"][800:], r.t[800:]
    i = np.where(np.sign(v[:-1]) != np.sign(v[1:]))[0][:2]
    crossing = t[i] - v[i] * (t[i + 1] - t[i]) / (v[i + 1] - v[i])
    return 1.0 / (2.0 * (crossing[1] - crossing[0]))


def test_load_inertia_and_hoses_lower_the_hydraulic_mode():
    """The mode's frequency scales as 1/sqrt(J): a load with a 0.8 m radius of gyration and 1000 kg m^2
    more on the boom lower it by sqrt(J/J') (within 1 %); hoses (0.2 L that swell at 1 GPa) soften
    the oil spring and lower it too."""
    base = _ring_frequency()
    c = _machine()
    J = c[C.J_fixed] + c[C.m_L] * c[C.gyration_sq]
    for effect, extra in (({"load_gyration_m": 0.8}, c[C.m_L] * 0.8**2), ({"extra_inertia_kg_m2": 1000.0}, 1000.0)):
        assert _ring_frequency(**effect) / base == pytest.approx(math.sqrt(J / (J + extra)), rel=0.01)
    assert _ring_frequency(hose_volume_A_m3=2e-4, hose_volume_B_m3=2e-4, hose_modulus_Pa=1e9) < 0.85 * base


def test_entrained_air_softens_the_oil_at_low_pressure_and_dissolves_with_pressure():
    """With 1 % free air, the chamber's stiffness -V dp/dV is the mixture's (oil and polytropic air)
    at 0.5 MPa, a third of the oil's, and the oil's own once the air has dissolved (none free at
    8 MPa); the free air's equilibrium falls linearly to none at air_dissolved_Pa."""
    c = _machine(air_content=0.01, air_dissolved_Pa=5e6)
    B, V = c[C.B], 1e-3

    def stiffness(p, air):
        oil = rig.hydraulics.oil_for_pressure(p, V, air, 0.0, math.inf, B)
        dV = 1e-9
        return -V * (chamber_pressure(oil, V + dV, air, 0.0, math.inf, B) - p) / dV

    air_low = free_air_equilibrium(0.5e6, c)
    assert air_low == pytest.approx(0.01 * 0.9)
    assert free_air_equilibrium(8e6, c) == 0.0
    # the polytropic gas term: 1/B_mix ~ 1/B + ε (p_atm/p_abs)^(1/κ) / (κ p_abs)
    p_abs = 0.5e6 + P_ATM
    expected = 1.0 / (1.0 / B + air_low * (P_ATM / p_abs) ** (1 / 1.4) / (1.4 * p_abs))
    assert stiffness(0.5e6, air_low) == pytest.approx(expected, rel=0.02)
    assert stiffness(0.5e6, air_low) < 0.35 * B
    assert stiffness(8e6, 0.0) == pytest.approx(B * math.exp(0.0), rel=1e-3)


def test_seal_friction_rises_with_the_pressures_on_the_seals():
    """In steady extension at 4 V the piston force p_A A_A - p_B A_B exceeds the run without
    pressure-loaded seals, at the same position, by seal_piston |p_A - p_B| + seal_rod p_B (the
    Coulomb level it adds, which steady sliding sees) within 3 %."""
    sc = scenario(duration_s=2.0, x0=0.05, input={"kind": "step", "amplitude_V": 4.0})
    runs = [rig.simulate(sc, settings(**e)) for e in ({}, {"seal_piston_m2": 4e-5, "seal_rod_m2": 3e-5})]
    c = runs[0].machine
    x = runs[1].truth["x"][-1]
    k = np.argmin(np.abs(runs[0].truth["x"] - x))
    F = [r.truth["p_A"][i] * c[C.A_A] - r.truth["p_B"][i] * c[C.A_B] for r, i in ((runs[0], k), (runs[1], -1))]
    p_A, p_B = runs[1].truth["p_A"][-1], runs[1].truth["p_B"][-1]
    assert F[1] - F[0] == pytest.approx(4e-5 * abs(p_A - p_B) + 3e-5 * p_B, rel=0.03)


def test_an_overlapped_edge_is_a_deadband_of_its_own():
    """Each edge has its own overlap: at 2 % travel with P->A overlapped by 3 % and B->T not at all, B
    drains and A gets nothing. With both edges of the extending path overlapped by 3 %, the piston
    starts to extend on a slow ramp of the command 3 % of travel later than without (within 0.3 %)."""
    c = _machine(lap_PA=0.03, lap_BT=0.0)
    Q_A, Q_B, _ = valve_flows(0.02, 7e6, 3e6, 10e6, c)
    assert Q_A == 0.0 and Q_B < -1e-6
    assert metering_area(0.02, 0.03, 0.0, 2.0) == 0.0 and metering_area(0.05, 0.03, 0.0, 2.0) == pytest.approx(0.02)
    sc = scenario(duration_s=3.0, x0=0.1, input={"kind": "ramp", "start_V": 0.0, "end_V": 1.0, "t0_s": 0.0, "t1_s": 3.0})
    laps = ({}, {"lap_PA": 0.03, "lap_BT": 0.03})
    start = [np.argmax(r.truth["x"] > 0.1 + 1e-4) for r in (rig.simulate(sc, settings(**e)) for e in laps)]
    assert K_U * (sc.u[start[1]] - sc.u[start[0]]) == pytest.approx(0.03, abs=0.003)


def test_a_progressive_notch_meters_less_near_null():
    """Below its knee the notch's area is knee (a / knee)^exponent: a quarter of the linear area at
    a quarter of the knee with exponent 2, then linear from the knee on."""
    assert metering_area(0.02, 0.0, 0.08, 2.0) == pytest.approx(0.08 * 0.25**2)
    assert metering_area(0.08, 0.0, 0.08, 2.0) == pytest.approx(0.08)
    assert metering_area(0.5, 0.0, 0.08, 2.0) == pytest.approx(0.5)


def test_a_port_restriction_in_series_saturates_the_flow_as_the_spool_opens():
    """Each metering edge in series with a port that passes port_flow at dp_N fully open by itself:
    1 / k^2 = 1 / k_edge^2 + 1 / k_port^2. At full opening with 24 L/min edges and a 10 L/min port,
    P->A passes 24 x 10 / sqrt(24^2 + 10^2) = 9.23 L/min at 3.5 MPa; barely opened, the edge alone
    sets the flow; without a port the valve is the plant's."""
    lpm = 1.0 / 60000
    c = _machine(port_flow_m3_s=10.0 * lpm)
    plain = _machine()
    full = valve_flows(1.0, 6.5e6, 0.0, 10e6, c)[0] / lpm
    assert full == pytest.approx(24.0 * 10.0 / math.hypot(24.0, 10.0), rel=1e-3)
    assert valve_flows(1.0, 6.5e6, 0.0, 10e6, plain)[0] / lpm == pytest.approx(24.0, rel=1e-3)
    small = (valve_flows(0.05, 6.5e6, 0.0, 10e6, c)[0], valve_flows(0.05, 6.5e6, 0.0, 10e6, plain)[0])
    assert small[0] / small[1] == pytest.approx(10.0 / math.hypot(1.2, 10.0), rel=1e-3)


def test_a_notch_that_has_uncovered_its_port_meters_no_more():
    """With full_area_opening 0.4 every edge's area stops at 40 %: at 10 V P->A passes what 4 V does,
    0.4 x 24 L/min at 3.5 MPa; below 40 % the valve is the plant's."""
    lpm = 1.0 / 60000
    c = _machine(full_area_opening=0.4)
    plain = _machine()
    assert valve_flows(1.0, 6.5e6, 0.0, 10e6, c)[0] / lpm == pytest.approx(0.4 * 24.0, rel=1e-3)
    assert valve_flows(1.0, 6.5e6, 0.0, 10e6, c)[0] == valve_flows(0.4, 6.5e6, 0.0, 10e6, plain)[0]
    assert valve_flows(0.3, 6.5e6, 0.0, 10e6, c)[0] == valve_flows(0.3, 6.5e6, 0.0, 10e6, plain)[0]


def test_a_pump_limited_supply_droops_and_limits_the_speed():
    """A 10 L/min pump with its relief valve at the plant's 10 MPa: idle, the line sits where the
    relief passes the pump's flow less the valve's null leakage; at 10 V the valve asks for more
    than the pump gives, the line falls below the relief's cracking pressure, and the piston extends
    at the pump's flow over A_A (within 3 %)."""
    pump = 10e-3 / 60
    sc = scenario(duration_s=2.5, x0=0.05, input={"kind": "step", "amplitude_V": 10.0, "t0_s": 0.5})
    r = rig.simulate(sc, settings(pump_flow_m3_s=pump))
    c = r.machine
    p_S = r.truth["p_S"][400]
    draw = valve_flows(r.truth["x_s"][400], r.truth["p_A"][400], r.truth["p_B"][400], p_S, c)[2]
    assert p_S == pytest.approx(10e6 - draw / c[C.relief_gain], rel=1e-4)
    assert r.truth["p_S"][-1] < c[C.relief_crack]
    assert r.truth["v"][-1] == pytest.approx(pump / c[C.A_A], rel=0.03)


def test_a_laminar_bypass_passes_flow_in_proportion_and_lets_the_load_sink():
    """The bypass is K (p_A - p_B) across the piston; with the valve centred the load sinks faster
    the larger it is. 800 kg at x = 0.15 m: there the null-leakage pressures hold the default
    plant's 494 kg by stiction (as in sam's test_centred_valve_drifts_only_by_null_leakage)."""
    c = _machine(bypass_m3_s_Pa=2e-12)
    assert leak_flows(7e6, 3e6, c)[0] == pytest.approx(2e-12 * 4e6)
    sink = []
    for bypass in (0.0, 2e-12, 1e-11):
        r = rig.simulate(scenario(duration_s=2.0, x0=0.15, m_L=800.0, input={"kind": "step", "amplitude_V": 0.0}),
                         settings(bypass_m3_s_Pa=bypass))
        sink.append(-r.truth["v"][-1])
    assert 0 < sink[0] < sink[1] < sink[2]


def test_hysteresis_is_a_play_between_command_and_spool():
    """A 0.4 V play: on a slow sine of the command the spool crosses its centre only after the
    command has passed it by half the play, in each direction: a loop of half-width K w / 2 (plus
    the spool's own lag at 0.2 Hz, 2 zeta / omega_n)."""
    sc = scenario(duration_s=10.0, x0=0.15, input={"kind": "sine", "amplitude_V": 1.0, "frequency_Hz": 0.2})
    r = rig.simulate(sc, settings(hysteresis_V=0.4))
    u, xs = r.u, r.truth["x_s"]
    c = r.machine
    lag = 2 * c[C.zeta] / c[C.omega_n] * K_U * 1.0 * 2 * np.pi * 0.2  # the spool's lag behind a sine
    rising = xs[np.where((u[:-1] < 0) & (u[1:] >= 0))[0]]
    falling = xs[np.where((u[:-1] > 0) & (u[1:] <= 0))[0]]
    assert np.all(rising == pytest.approx(-(K_U * 0.2 + lag), rel=0.1))
    assert np.all(falling == pytest.approx(K_U * 0.2 + lag, rel=0.1))


def test_a_sticking_spool_holds_at_each_reversal_until_pulled_free():
    """With a breakaway of 1 % of travel and sliding at half of it, the spool stands still after each
    reversal of a slow sine until the command has come back by at least the breakaway and at most
    the breakaway and the sliding lag (1-1.5 % of travel): flat segments a healthy spool does not have."""
    sc = scenario(duration_s=8.0, x0=0.15, input={"kind": "sine", "amplitude_V": 1.0, "frequency_Hz": 0.25})
    r = rig.simulate(sc, settings(spool_stiction=0.01))
    xs, Ku = r.truth["x_s"], K_U * r.u
    still = np.r_[np.abs(np.diff(xs)) == 0.0, False]
    edges = np.flatnonzero(np.diff(still.astype(int)))
    holds = [(a + 1, b) for a, b in zip(edges[:-1], edges[1:]) if still[a + 1] and b - a > 20]
    assert len(holds) >= 3
    for a, b in holds[1:]:  # the first is the start from rest
        assert 0.01 <= abs(Ku[b] - Ku[a]) <= 0.0151
    healthy = rig.simulate(sc, settings())
    assert np.sum(np.abs(np.diff(healthy.truth["x_s"])) == 0.0) < 20


def test_transmitter_lag_and_delay_shift_the_logged_pressure():
    """With a 5 ms lag and a 3 ms delay (no noise, no ADC), the logged p_A of a slow motion is the
    truth shifted by their sum (the best shift within 1 ms), and without them by nothing."""
    sc = scenario(duration_s=4.0, x0=0.1, input={"kind": "sine", "amplitude_V": 3.0, "frequency_Hz": 0.5})
    quiet = {"pressure_noise_Pa": 0.0, "adc_bits": 0}

    def best_shift(**sensors):
        rec = rig.record(sc, settings(sensors={**quiet, **sensors}))
        y, truth = rec.signals["pA"][500:], rec.truth["true_pA"]
        errors = [np.mean((y - truth[500 - s:len(truth) - s]) ** 2) for s in range(0, 20)]
        return int(np.argmin(errors))

    assert best_shift() == 0
    assert abs(best_shift(lag_s=0.005, delay_s=0.003) - 8) <= 1


def test_the_logger_quantises_clips_and_adds_noise_as_set():
    """16 bits over 0-25 MPa: every logged pressure is a whole number of 381.5 Pa steps and never
    below 0; the noise about the truth has the set 15 kPa standard deviation (within 3 %); no pS
    column unless asked for; the same seed gives the same recording."""
    sc = scenario(duration_s=4.0, x0=0.1, input={"kind": "sine", "amplitude_V": 3.0, "frequency_Hz": 0.5})
    rec = rig.record(sc, settings())
    q = 25e6 / (2**16 - 1)
    p = rec.signals["pA"]
    assert np.allclose(p / q, np.round(p / q), atol=1e-6) and p.min() >= 0.0
    assert np.std(p - rec.truth["true_pA"]) == pytest.approx(np.sqrt(15e3**2 + q**2 / 12), rel=0.03)
    assert "pS" not in rec.signals and "pS" in rig.record(sc, settings(sensors={"measure_pS": True})).signals
    assert np.array_equal(rig.record(sc, settings()).signals["pA"], p)


def test_faults_follow_their_profiles_and_the_loop_holds_an_offset():
    """A +1 % spool offset from t = 3 s under closed-loop position hold: the true_offset column steps
    with the profile, and the controller's output settles lower by offset / K = 0.1 V (within
    0.02 V) to hold the spool's lands where they were."""
    sc = scenario(duration_s=6.0, x0=0.15, control={"kp_V_per_m": 300.0, "ki_V_per_m_s": 100.0,
                                                     "setpoint": {"kind": "constant", "value_m": 0.15}},
                  faults={"offset": {"kind": "step", "value": 0.01, "t0_s": 3.0}})
    rec = rig.record(sc, settings(sensors={"encoder_deg": 0.0}))
    t, u = rec.t, rec.signals["u"]
    assert np.all(rec.truth["true_offset"][t < 3.0] == 0.0) and np.all(rec.truth["true_offset"][t >= 3.0] == 0.01)
    before, after = u[(t > 2.0) & (t < 3.0)].mean(), u[t > 5.0].mean()
    assert after - before == pytest.approx(-0.01 / K_U, abs=0.02)


def test_a_load_picked_up_raises_the_holding_force_by_its_weight():
    """Holding 0.15 m under P control, the load steps from 300 to 600 kg at 2 s: true_mL follows, and
    the force the pressures hold against friction (LuGre, Eq. (17), from the logged bristle state)
    and the boom's inertia rises by the extra gravity torque over r (within 1 %)."""
    sc = scenario(duration_s=5.0, x0=0.15, control={"kp_V_per_m": 300.0,
                                                     "setpoint": {"kind": "constant", "value_m": 0.15}},
                  load={"kind": "step", "before_kg": 300.0, "after_kg": 600.0, "t0_s": 2.0})
    r = rig.simulate(sc, settings(sensors={"encoder_deg": 0.0}))
    c, tr = r.machine, r.truth
    L = c[C.L_1], c[C.L_2], c[C.L_3]
    assert r.params["m_L"][0] == 300.0 and r.params["m_L"][-1] == 600.0
    alpha = np.gradient(tr["omega"], r.t)

    def held(i, m_L):
        arm = torque_arm(tr["theta"][i], *L)
        J = c[C.J_fixed] + m_L * c[C.gyration_sq]
        F_C, F_S = seal_friction_levels(c, tr["p_A"][i], tr["p_B"][i])
        _, F_mu = lugre(tr["v"][i], tr["z"][i], F_C, F_S, c, J / arm**2)
        return tr["p_A"][i] * c[C.A_A] - tr["p_B"][i] * c[C.A_B] - F_mu - J * alpha[i] / arm

    theta = tr["theta"][-2]
    extra = (gravity_torque(theta, c, 600.0) - gravity_torque(theta, c, 300.0)) / torque_arm(theta, *L)
    assert held(-2, 600.0) - held(1900, 300.0) == pytest.approx(extra, rel=0.01)


def test_geometry_tolerances_show_between_the_logged_and_the_true_position():
    """The cylinder's pins 3 mm further apart than the drawing: the logger, which computes x from the
    encoder with the drawing's lengths, reads the piston 3 mm further out than it is (within the
    encoder's resolution); seeded draws are the same for the same seed and differ for another."""
    sc = scenario(duration_s=2.0, x0=0.1, input={"kind": "sine", "amplitude_V": 2.0, "frequency_Hz": 0.5})
    st = rig.RigSettings(tolerances=rig.Tolerances(L_3_m=0.003))
    rec = rig.record(sc, st)
    assert np.mean(rec.signals["x"] - rec.truth["true_x"]) == pytest.approx(0.003, abs=5e-5)
    drawn = rig.RigSettings(tolerances=rig.Tolerances(length_sd_m=0.002))
    a, b = rig.simulate(sc, drawn).machine, rig.simulate(sc, drawn).machine
    other = rig.simulate(sc.__class__(**{**sc.__dict__, "seed": 8}), drawn).machine
    assert np.array_equal(a, b) and not np.array_equal(a[:3], other[:3])


@hsettings(max_examples=25, deadline=None)
@given(oil_ratio=st.floats(0.95, 1.02), air=st.floats(0.0, 0.05), hose=st.floats(0.0, 3e-4),
       modulus=st.floats(2e8, 5e9), B=st.floats(3e8, 1.2e9))
def test_the_chamber_pressure_holds_its_oil(oil_ratio, air, hose, modulus, B):
    """Over a box of oil, air, hoses and moduli the pressure solved from the oil fills the room
    exactly (to 1e-9 of it), or, where the oil cannot fill it, is the vapour pressure (a void)."""
    V = 5e-4
    oil = oil_ratio * (V + hose)
    p = chamber_pressure(oil, V, air, hose, modulus, B)
    s, _ = rig.hydraulics.specific_volume(p, air, B)
    room = V + hose * (1 + p / modulus)
    if p > rig.layout.P_VAPOUR:
        assert oil * s == pytest.approx(room, rel=1e-9)
    else:
        assert oil * s <= room * (1 + 1e-12)
