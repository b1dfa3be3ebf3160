"""The model's form uncertain where it is known to be (fdi.form_noise, FilterConfig.form_noise):
the spool follows Eq. (15) in closed form, the pressures' extra variance is the closed form of
the module docstring at the null band's edge and near cavitation and nothing elsewhere, and
every filter of the bank carries the detecting filter's."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from sam import P, load_plant
from sam.dynamics import areas
from fdi.bank import DESIGN, bank_config, reference_config
from fdi.config import FilterConfig, FormNoise
from fdi.filter import random_walk_gates
from fdi.form_noise import form_gates, measured_rates, near_band_edge, null_flow_spread, spool_positions
from fdi.states import POS_X

DT = 1e-3


@pytest.fixture(scope="module")
def plant():
    return load_plant().vector()[None, :]


def test_spool_follows_eq15_in_closed_form(plant):
    """A step of u from 0 to 2 V at rest: the critically damped Eq. (15) (zeta = 1) gives
    x_s(t) = K_u u (1 - (1 + w t) e^(-w t)); the exact discretisation agrees to 1e-12, and a
    run that starts at 1 V starts at rest at K_u 1 V."""
    T = 200
    u = np.r_[np.zeros(10), np.full(T - 10, 2.0)][None, :]
    xs = spool_positions(u, plant, DT)
    K, w = plant[0, P.K_u], plant[0, P.omega_n]
    assert plant[0, P.zeta] == 1.0
    t = (np.arange(T) - 10) * DT  # the input changes at sample 10 and is held over each sample
    want = np.where(t > 0, K * 2.0 * (1.0 - (1.0 + w * t) * np.exp(-w * t)), 0.0)
    np.testing.assert_allclose(xs[0], want, atol=1e-12)
    assert spool_positions(np.full((1, 5), 1.0), plant, DT)[0] == pytest.approx(np.full(5, K * 1.0))


def test_extra_pressure_variance_is_the_closed_form_at_the_edge_only(plant):
    """Spool at rest at 0.9, 1.0 and 1.5 leak_band (margin 0.2): the gate of p_A is
    1 + (share s_A B_eff / V_A)^2 dt / q^2 at the first two and 1 at the third, with s_A the
    root sum of squares of K_leak_PA (p_S - p_A) and K_leak_AT p_A (p_T = 0), V_A = V_0A + A_A x."""
    p = plant[0]
    K_u, band = p[P.K_u], p[P.leak_band]
    u = np.array([[0.9], [1.0], [1.5]]) * band / K_u * np.ones((1, 50))
    pA, pB, x = 6e6, 2.5e6, 0.2
    inp = SimpleNamespace(u=u, params=np.repeat(plant, 3, axis=0), dt=DT, pA=np.full(u.shape, pA),
                          pB=np.full(u.shape, pB), pos=np.full(u.shape, x), pos_kind=POS_X)
    q = 5e4
    g = form_gates(inp, FormNoise(band_margin=0.2, band_share=1.0), q, q)
    s_A = math.hypot(p[P.K_leak_PA] * (p[P.p_S] - pA), p[P.K_leak_AT] * (pA - p[P.p_T]))
    A_A, _ = areas(p[P.D_piston], p[P.D_rod])
    rate = s_A * p[P.B_eff] / (p[P.V_0A] + A_A * x)
    want = 1.0 + rate ** 2 * DT / q ** 2
    assert want > 5.0  # the edge's flow is large against the model's own pressure noise
    np.testing.assert_allclose(g[:2, :, 0], want, rtol=1e-9)
    np.testing.assert_array_equal(g[2], 1.0)
    # share 0: the model's edge taken as exact; a missing pressure adds nothing
    assert np.all(form_gates(inp, FormNoise(band_share=0.0), q, q) == 1.0)
    inp.pA[0, :] = np.nan
    assert np.all(form_gates(inp, FormNoise(band_share=1.0), q, q)[0, :, 0] == 1.0)


def test_the_edge_is_where_the_offset_moves_it(plant):
    """|x_s + offset| = leak_band is the edge: an offset of +leak_band puts the centred spool there."""
    p = plant.copy()
    p[0, P.offset] = p[0, P.leak_band]
    assert near_band_edge(np.zeros((1, 1)), p, 0.1)[0, 0]
    assert not near_band_edge(np.zeros((1, 1)), plant, 0.1)[0, 0]


def test_null_flow_spread_is_zero_without_null_leakage(plant):
    p = plant.copy()
    p[0, [P.K_leak_PA, P.K_leak_AT, P.K_leak_PB, P.K_leak_BT]] = 0.0
    sA, sB = null_flow_spread(np.full((1, 3), 5e6), np.full((1, 3), 5e6), p)
    assert np.all(sA == 0.0) and np.all(sB == 0.0)


def test_every_filter_of_the_bank_carries_the_detecting_filters_edge(plant):
    """The reference and the constrained filters assume the detecting filter's null_band, and the
    gates put the pressures in groups of their own only when it is on."""
    nb = FormNoise(band_margin=0.3, band_share=0.5)
    detect = FilterConfig(form_noise=nb)
    assert reference_config(DESIGN, None, nb).form_noise == nb
    assert bank_config(detect).form_noise == nb
    u = np.full((1, 20), plant[0, P.leak_band] / plant[0, P.K_u])
    inp = SimpleNamespace(u=u, params=plant, dt=DT, pA=np.full(u.shape, 5e6), pB=np.full(u.shape, 2e6),
                          pos=np.full(u.shape, 0.1), pos_kind=POS_X, pS=None)
    gates, group = random_walk_gates(inp, FilterConfig(form_noise=FormNoise.exact()))
    assert gates.shape[-1] == 2 and group[0] == -1 and group[1] == -1
    gates, group = random_walk_gates(inp, detect)
    assert gates.shape[-1] == 4 and tuple(group[:2]) == (2, 3) and np.all(gates[0, :, 2] > 1.0)


def test_extra_variance_near_cavitation_is_the_displacement_flows(plant):
    """Chamber B below low_pressure, the piston moving at 40 mm/s: p_B's gate is
    1 + (share A_B v B_eff / V_B)^2 dt / q^2 once the rate window has filled, p_A's 1 (above it,
    spool far from the band's edge); at rest it adds nothing."""
    p = plant[0]
    T, v, x0 = 100, 0.04, 0.3
    x = x0 + v * DT * np.arange(T)
    u = np.full((1, T), 3.0)
    inp = SimpleNamespace(u=u, params=plant, dt=DT, pA=np.full((1, T), 5e6), pB=np.full((1, T), 2e5),
                          pos=x[None, :], pos_kind=POS_X)
    fn = FormNoise(low_pressure=1e6, low_share=0.5, velocity_window_s=0.02)
    q = 5e4
    g = form_gates(inp, fn, q, q)
    _, A_B = areas(p[P.D_piston], p[P.D_rod])
    V_B = p[P.V_0B] + A_B * (p[P.x_max] - x)
    want = 1.0 + (0.5 * A_B * v * p[P.B_eff] / V_B) ** 2 * DT / q ** 2
    np.testing.assert_allclose(g[0, 20:, 1], want[20:], rtol=1e-9)
    np.testing.assert_array_equal(g[0, :, 0], 1.0)
    np.testing.assert_allclose(measured_rates(x[None, :], DT, 0.02)[0, 20:], v, rtol=1e-9)
    inp.pos = np.full((1, T), x0)
    assert np.all(form_gates(inp, fn, q, q) == 1.0)


@pytest.mark.parametrize("field,value", [("band_margin", -0.1), ("band_share", -1.0), ("low_share", True),
                                         ("velocity_window_s", 0.0)])
def test_a_bad_setting_names_its_field(field, value):
    with pytest.raises(ValueError, match=f"form_noise.{field}"):
        FormNoise(**{field: value})


def test_a_clipped_transmitter_reading_is_missing_to_the_filter():
    """A cavitating chamber (-0.1 MPa) read by a 0-25 MPa transmitter reads 0: such readings
    (within floor_band_Pa of the range's floor) reach the filter as missing and are counted; a
    reading above the band stays."""
    from sam import Recording
    from fdi.recording import CHECKS, filter_input

    T = 200
    t = np.arange(T) * DT
    pA = np.full(T, 3e6)
    pA[50:80] = 0.0  # clipped
    pA[80:90] = CHECKS.floor_band_Pa + 1e3  # just above the band: a reading
    rec = Recording(t, {"u": np.zeros(T), "pA": pA, "pB": np.full(T, 4e6), "x": np.full(T, 0.2)})
    inp, report = filter_input(rec, load_plant(), position_sensor="linear")
    assert np.isnan(inp.pA[0, 50:80]).all() and np.isfinite(inp.pA[0, 80:]).all() and np.isfinite(inp.pB).all()
    assert report.at_range_floor_samples == 30 and report.to_dict()["at_range_floor_samples"] == 30


def test_a_development_rig_run_that_alarmed_before_its_onset_no_longer_does():
    """Run 78 of the development rig population (seed 32201127: offset -1 % from 7.29 s, open
    loop, 263 kg, a chamber cavitating on its transmitter's floor): with the model's edges taken
    as exact and the clipped readings as readings, the bank confirmed K_extB at 4.21 s, 3.1 s
    before the onset (docs/fdi.md, "On rig recordings"). The shipped filter confirms nothing
    before the onset (nor, at low_pressure 0.2 MPa, within the second after it: a detection this
    run does not make); with the air-release noise up to 1 MPa the bank names offset- within 1 s
    of the onset, sized within 5 %, the price of which is a healthy meter-out chamber blurred on
    sam's own runs (tests/test_fdi_signatures.py)."""
    from rig import population
    from sam import default_plant_path
    from fdi import evaluate

    rec = population.simulate_run(default_plant_path().resolve(), population.DEVELOPMENT, 32201127, 78,
                                  "offset", -1.0)
    lab = evaluate.label(rec, "run 78")
    res = evaluate.score(rec, lab, load_plant(), None)
    k_on = int(res["k_onset"][0])
    assert int(res["conf_k"][0]) == -1 or int(res["conf_k"][0]) >= k_on
    wide = FilterConfig(form_noise=FormNoise(low_pressure=1e6))
    res = evaluate.score(rec, lab, load_plant(), None, cfg=wide)
    assert k_on <= int(res["conf_k"][0]) <= k_on + 1000
    assert int(res["iso_h"][0]) == 4 and int(res["iso_k"][0]) - k_on <= 1000  # offset-, as scored
    assert float(res["size_value"][0]) == pytest.approx(-1.0, rel=0.05)
