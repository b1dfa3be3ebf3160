"""The elastic end stop (sam.params.EndStops, Eq. (C1) of sam.contact): a free piston's rebound at
the restitution of Eq. (C2), a pressed piston's sink F / k, the default (k_stop = 0) the rigid stop
of Eq. (22) to the last bit, and the step stable at the filter's 1 ms where the contact is stiff."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sam
from fdi.config import StopRules
from sam import P, simulate_batch
from sam.contact import restitution, stop_acceleration
from sam.dynamics import D, derive, kernel_variant, rhs
from sam.geometry import cos_joint_angle, torque_arm_cs
from sam.simulate import initial_state

PLANT = sam.load_plant()
K_STOP = 1e9  #: N/m, of the order of the rod's column E A / L
#: V, from x = 0.3 m: 2 s onto the extension stop and pressed there, then 6 s onto the retracted one
STOP_TO_STOP = np.where(np.arange(8000) < 2000, 9.0, -9.0)
LIGHT_FRICTION = {"F_C": 1.0, "F_S": 1.0, "sigma_0": 2e5, "b": 0.0}


def _free_piston(**stops) -> np.ndarray:
    """A plant vector whose piston moves free of every force but the stop's: no gravity torque
    (m_L = m_R, no boom mass), friction of a newton (bristles that settle in 0.1 ms), no leakage,
    chambers so large that the oil's spring is 2 kN/m (a millionth of the contact's)."""
    return PLANT.replace(m_L=300.0, m_R=300.0, m_B=1e-9, **LIGHT_FRICTION, K_leak_PA=0.0, K_leak_AT=0.0,
                         K_leak_PB=0.0, K_leak_BT=0.0, V_0A=10.0, V_0B=10.0, **stops).vector()


def _balanced_state(p, x, v) -> np.ndarray:
    """At x [m], moving at v [m/s], valve centred, chamber forces balanced (p_A A_A = p_B A_B)."""
    A_A = math.pi * p[P.D_piston] ** 2 / 4
    A_B = A_A - math.pi * p[P.D_rod] ** 2 / 4
    return np.array([1e6 * A_B / A_A, 1e6, 0.0, 0.0, x, v, 0.0])


def _reduced_mass(p) -> float:
    """m of Eq. (20) at the retracted stop [kg]: J_tot / r^2."""
    d = np.empty(len(D))
    derive(p, d)
    c = cos_joint_angle(0.0, p[P.L_1], p[P.L_2], p[P.L_3])
    r = torque_arm_cs(0.0, math.sqrt(1 - c * c), p[P.L_1], p[P.L_2], p[P.L_3])
    return 1.0 / (r * r * d[D.inv_J_tot])


@pytest.mark.parametrize("zeta", [0.0, 0.1, 0.25, 0.5])
def test_a_free_piston_rebounds_at_the_restitution_of_the_damping_ratio(zeta):
    """Eq. (C2): a free piston meeting the retracted stop at 5 cm/s leaves it at e v0, e =
    exp(-zeta (pi - 2 asin zeta) / sqrt(1 - zeta^2)) (0.57 at 0.2, 0.51 at 0.25), released after
    (pi - 2 asin zeta) / omega_d, omega_d = omega sqrt(1 - zeta^2), omega = sqrt(k / m), still
    c e v0 / k inside: it is back at the stop's face 2 zeta / omega later. The rigid stop keeps it."""
    p = _free_piston(k_stop=K_STOP, zeta_stop=zeta)
    s0 = _balanced_state(p, 1e-4, -0.05)
    dt, n = 1e-4, 400
    res = simulate_batch(p[None, :], np.zeros(n), dt, x0=s0[None, :], substeps=20, scheme="rk4")
    x, v = res["x"][0], res["v"][0]
    assert x.min() < 0.0  # it entered the contact
    gone = np.flatnonzero((x > 0.0) & (np.arange(len(x)) > np.argmin(x)))[0]
    assert v[gone] == pytest.approx(0.05 * restitution(zeta), rel=5e-3)
    omega = math.sqrt(K_STOP / _reduced_mass(p))
    inside = (math.pi - 2 * math.asin(zeta)) / (omega * math.sqrt(1 - zeta**2)) + 2 * zeta / omega
    assert np.count_nonzero(x < 0.0) * dt == pytest.approx(inside, abs=2 * dt)
    rigid = simulate_batch(_free_piston()[None, :], np.zeros(n), dt, x0=s0[None, :], substeps=20, scheme="rk4")
    assert rigid["x"][0].min() >= 0.0 and abs(rigid["x"][0][-1]) < 1e-7 and abs(rigid["v"][0][-1]) < 1e-5


def test_restitution_is_one_without_damping_and_falls_with_it():
    assert restitution(0.0) == 1.0
    e = [restitution(z) for z in np.linspace(0.0, 0.99, 50)]
    assert np.all(np.diff(e) < 0.0) and e[-1] == pytest.approx(math.exp(-2.0), abs=0.02)
    with pytest.raises(ValueError):
        restitution(1.0)


def test_a_load_pressing_the_piston_on_the_stop_sinks_it_by_F_over_k():
    """The boom's 494 kg pressing the piston onto the retracted stop (valve centred, the oil's spring
    a millionth of the contact's): at rest the contact carries the load force F of Eq. (21),
    so the piston sits F / k_stop into it, at 1e9 and 4e9 N/m."""
    for k in (1e9, 4e9):
        p = PLANT.replace(**LIGHT_FRICTION, K_leak_PA=0.0, K_leak_AT=0.0, K_leak_PB=0.0, K_leak_BT=0.0,
                          V_0A=10.0, V_0B=10.0, k_stop=k, zeta_stop=0.5).vector()
        s0 = _balanced_state(p, 0.0, 0.0)
        s0[:2] = 0.0  # no pressure force: the stop carries the whole load
        res = simulate_batch(p[None, :], np.zeros(2000), 1e-3, x0=s0[None, :], substeps=10, scheme="rk4")
        x_rest = res["x"][0, -1]
        # the load force at rest: what the contact's acceleration balances there
        d, ds = np.empty(len(D)), np.empty(7)
        derive(p, d)
        rigid = p.copy()
        rigid[P.k_stop] = 0.0
        rhs(np.array([0.0, 0.0, 0.0, 0.0, x_rest, 0.0, res["z"][0, -1]]), 0.0, rigid, d, ds)
        load = -ds[5] * _reduced_mass(p)  # N pressing the piston into the stop
        assert load > 1e4
        assert -x_rest == pytest.approx(load / k, rel=2e-3)
        assert abs(res["v"][0, -1]) < 1e-6


def test_the_default_stop_is_rigid_and_needs_no_effects_variant():
    """k_stop = 0 is the paper's model: the plant vector is today's but for two zero columns at its
    end, the lanes' lean variant serves it, and the contact pushes nothing."""
    p = PLANT.vector()
    assert p[P.k_stop] == 0.0 and p[P.zeta_stop] == 0.0 and int(P.k_stop) == len(P) - 2
    assert kernel_variant(p[None, :]) == (False, False)
    assert kernel_variant(PLANT.replace(k_stop=K_STOP).vector()[None, :]) == (False, True)
    assert stop_acceleration(-1e-4, -0.1, 0.4, 0.0, 0.3, 1e-5) == 0.0


@pytest.mark.parametrize("scheme", ["euler", "semi_implicit", "heun", "rk4"])
def test_the_rigid_default_is_the_elastic_step_s_limit_elsewhere_and_bit_for_bit_between_variants(scheme):
    """A run driven into both stops: with k_stop = 0 the lean and the effects variant (forced by a
    second run with entrained air in the batch) give the same numbers to the last bit."""
    p = PLANT.replace(m_L=100.0).vector()
    alone = simulate_batch(p[None, :], STOP_TO_STOP, 1e-3, x0=initial_state(p[None, :], 0.3), scheme=scheme)
    air = PLANT.replace(m_L=100.0, air_fraction=0.01).vector()
    both = simulate_batch(np.stack([p, air]), STOP_TO_STOP, 1e-3, x0=initial_state(np.stack([p, air]), 0.3),
                          scheme=scheme)
    for name in ("p_A", "p_B", "x", "v"):
        assert np.array_equal(alone[name][0], both[name][0])
    assert alone["x"][0].min() == 0.0 and alone["x"][0].max() == pytest.approx(float(sam.stroke_ends(p)))


def test_the_filter_s_1ms_euler_step_is_stable_on_a_stiff_contact():
    """The filter's model (Eq. (22) at 1 ms) with the FDI's contact (4e9 N/m, damping ratio 0.7):
    the light boom (no load, the stiffest contact seen at the piston: h omega = 0.70) driven onto
    both stops settles there, and the pressures and velocity stay bounded (forward Euler needs
    h omega < 2 zeta)."""
    stops = StopRules()
    assert (stops.contact_stiffness_N_per_m, stops.contact_damping_ratio) == (4e9, 0.7)
    p = PLANT.replace(m_L=0.0, k_stop=stops.contact_stiffness_N_per_m, zeta_stop=stops.contact_damping_ratio).vector()
    res = simulate_batch(p[None, :], STOP_TO_STOP, 1e-3, x0=initial_state(p[None, :], 0.3), scheme="euler")
    x, v, t = res["x"][0], res["v"][0], res.t
    x_end = float(sam.stroke_ends(p))
    assert np.all(np.isfinite(x)) and np.abs(v).max() < 0.2
    assert -1e-3 < x.min() < 0.0 and x_end < x.max() < x_end + 1e-3
    for held in ((t > 1.6) & (t < 2.0), (t > 7.6) & (t < 8.0)):  # pressed on each stop, the valve open
        assert np.ptp(x[held]) < 1e-6 and np.abs(v[held]).max() < 1e-4
