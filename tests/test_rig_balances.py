"""Conservation on the rig's trajectories: the oil that flows in is the chamber's growth plus what
its compression stores (Eqs. (8)-(9) integrated), and the hydraulic power delivered is the boom's
kinetic and potential energy, the oil's compression energy and what friction and the stops take.

The rig integrates the oil each chamber holds and the joint angle (not the pressures and x), so
these balances check its formulation against the paper's, and its theta-form mechanics against
the pressure force on the piston: on a trajectory sampled at every RK4 step, by the trapezoid rule.
"""

from __future__ import annotations

import numpy as np
import pytest

import rig
import sam
from rig.hydraulics import leak_flows, valve_flows
from rig.layout import C, R
from rig.mechanics import potential_energy
from rig.model import forces, pressures

H = 1e-4


def _trajectory(u_of_t, seconds, x0, **effects):
    """Rows per RK4 step of: t, theta, omega, x, v, p_A, p_B, Q_A, Q_B (into each chamber, leaks
    included), F_mu, F_stop; and the machine vector."""
    c = rig.build(sam.load_plant(), rig.RigSettings(effects=rig.Effects(**effects)), np.random.default_rng(0))
    c[C.K_int], c[C.K_extA] = 1.3e-9, 0.6e-9  # leaks: flows that leave the cylinder or cross it
    y = rig.initial_state(c, x0)
    k = np.empty((5, len(y)))
    rows = []
    for i in range(int(round(seconds / H)) + 1):
        u = u_of_t(i * H)
        x, p_A, p_B, p_S = pressures(y, c)
        _, _, v, _, F_mu, F_stop = forces(y, c, x, p_A, p_B)
        Q_A, Q_B, _ = valve_flows(y[R.x_s], p_A, p_B, p_S, c)
        Q_AB, Q_extA, Q_extB = leak_flows(p_A, p_B, c)
        rows.append((i * H, y[R.theta], y[R.omega], x, v, p_A, p_B, Q_A - Q_AB - Q_extA, Q_B + Q_AB - Q_extB,
                     F_mu, F_stop))
        rig.rk4_step(y, u, c, H, k)
    return np.array(rows).T, c


def _integral(f, t):
    return np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(t))


def _compression(p, V, B):
    """Integral of V/B dp, and of p V/B dp, along the samples (the midpoint in each interval)."""
    pm, Vm, dp = 0.5 * (p[1:] + p[:-1]), 0.5 * (V[1:] + V[:-1]), np.diff(p)
    return np.sum(Vm / B * dp), np.sum(pm * Vm / B * dp)


RUNS = {
    "extend, reverse": (lambda t: 4.0 if t < 0.8 else -4.0, 1.6, 0.1),
    "onto the retracted stop": (lambda t: -3.0, 1.2, 0.03),  # a contact, then the valve open onto a rail
}


@pytest.mark.parametrize("run", RUNS, ids=list(RUNS))
def test_oil_in_is_growth_plus_compression(run):
    """Chamber by chamber: integral of (Q_in - dV/dt) = integral of V/B dp, to 1e-5 of the oil that
    flowed (internal and external leaks included; through a stop contact)."""
    (t, theta, omega, x, v, p_A, p_B, Q_A, Q_B, F_mu, F_stop), c = _trajectory(*RUNS[run])
    V_A = c[C.V_0A] + c[C.A_A] * x
    V_B = c[C.V_0B] + c[C.A_B] * (c[C.x_max] - x)
    for Q, V, p in ((Q_A, V_A, p_A), (Q_B, V_B, p_B)):
        stored, _ = _compression(p, V, c[C.B])
        moved = _integral(np.abs(Q), t)
        assert _integral(Q, t) - (V[-1] - V[0]) == pytest.approx(stored, abs=1e-5 * moved)


@pytest.mark.parametrize("run", RUNS, ids=list(RUNS))
def test_hydraulic_power_is_work_stored_and_dissipated(run):
    """The energy delivered into the chambers, integral of p_A Q_A + p_B Q_B, equals the boom's
    kinetic and potential energy gained, the oil's compression energy (integral of p V/B dp), the
    work of friction (F_mu v) and of the stops, to 1e-4 of the energy that flowed."""
    (t, theta, omega, x, v, p_A, p_B, Q_A, Q_B, F_mu, F_stop), c = _trajectory(*RUNS[run])
    J = c[C.J_fixed] + c[C.m_L] * c[C.gyration_sq]
    delivered = _integral(p_A * Q_A + p_B * Q_B, t)
    kinetic = 0.5 * J * (omega[-1] ** 2 - omega[0] ** 2)
    potential = potential_energy(theta[-1], c, c[C.m_L]) - potential_energy(theta[0], c, c[C.m_L])
    compression = sum(_compression(p, V, c[C.B])[1] for p, V in (
        (p_A, c[C.V_0A] + c[C.A_A] * x), (p_B, c[C.V_0B] + c[C.A_B] * (c[C.x_max] - x))))
    friction = _integral(F_mu * v, t)
    stops = -_integral(F_stop * v, t)
    flowed = _integral(np.abs(p_A * Q_A) + np.abs(p_B * Q_B), t)
    assert abs(potential) > 0.05 * flowed  # the boom really was lifted or lowered
    assert delivered == pytest.approx(kinetic + potential + compression + friction + stops, abs=1e-4 * flowed)
