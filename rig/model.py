"""The rig's right-hand side: the paper's continuous equations (3)-(21), (41)-(43) over the
rig's own state (:class:`rig.layout.R`), and the quantities a logger or a balance reads off a state.

    theta'  = omega
    omega'  = (r(theta) (p_A A_A - p_B A_B - F_mu + F_stop) - tau_g(theta)) / J        Eq. (16)
    oil_A'  = (Q_A - Q_AB - Q_extA) / s(p_A)                                            Eq. (8)
    oil_B'  = (Q_B + Q_AB - Q_extB) / s(p_B)                                            Eq. (9)
    x_s'' = K omega_n^2 u - 2 zeta omega_n x_s' - omega_n^2 x_s                          Eq. (15)
    z'      = v - sigma_0 |v| z / g(v)                                                  Eq. (17)

with x = x(theta) (Eq. (3)), v = r(theta) omega (Eq. (4)) and the pressures from the oil
(:func:`rig.hydraulics.chamber_pressure`). The free air of each chamber relaxes to its
equilibrium, a pump-limited supply line fills and drains, and the transmitters lag.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .hydraulics import (
    chamber_pressure, free_air_equilibrium, leak_flows, oil_for_pressure, specific_volume, supply_line_flow,
    valve_flows,
)
from .layout import N_STATE, P_VAPOUR, C, R
from .mechanics import (
    gravity_torque, inertia, joint_angle, lugre, piston_position, seal_friction_levels, spool_acceleration,
    stop_force, torque_arm, torque_arm_slope,
)

jit = numba.njit(cache=True, error_model="numpy")


@jit
def pressures(y, c):
    """(x [m], p_A, p_B, p_S [Pa]) of the state ``y``: the piston position and the pressures
    that hold the oil in the chambers and the supply line."""
    x = piston_position(y[R.theta], c[C.L_1], c[C.L_2], c[C.L_3])
    B = c[C.B]
    p_A = chamber_pressure(y[R.oil_A], c[C.V_0A] + c[C.A_A] * x, y[R.air_A], c[C.hose_A], c[C.hose_modulus], B)
    p_B = chamber_pressure(y[R.oil_B], c[C.V_0B] + c[C.A_B] * (c[C.x_max] - x), y[R.air_B], c[C.hose_B],
                           c[C.hose_modulus], B)
    p_S = c[C.p_S] if math.isinf(c[C.pump]) else chamber_pressure(y[R.oil_S], c[C.V_line], 0.0, 0.0, math.inf, B)
    return x, p_A, p_B, p_S


@jit
def forces(y, c, x, p_A, p_B):
    """(r [m], J [kg m^2], v [m/s], dz/dt [m/s], F_mu, F_stop [N]) at the state ``y``."""
    theta = y[R.theta]
    r = torque_arm(theta, c[C.L_1], c[C.L_2], c[C.L_3])
    J = inertia(c, c[C.m_L])
    v = r * y[R.omega]  # Eq. (4)
    m_reduced = J / (r * r)  # Eq. (20): for the bristles' damping only
    F_C, F_S = seal_friction_levels(c, p_A, p_B)
    dz, F_mu = lugre(v, y[R.z], F_C, F_S, c, m_reduced)
    return r, J, v, dz, F_mu, stop_force(x, v, c)


@jit
def derivatives(y, u, c, dy):
    """Write dy/dt of the rig's state ``y`` (N_STATE,) under the valve input ``u`` [V] into ``dy``."""
    x, p_A, p_B, p_S = pressures(y, c)
    r, J, v, dz, F_mu, F_stop = forces(y, c, x, p_A, p_B)
    F_cyl = p_A * c[C.A_A] - p_B * c[C.A_B] - F_mu + F_stop
    dy[R.theta] = y[R.omega]
    tau = r * F_cyl - gravity_torque(y[R.theta], c, c[C.m_L])
    if c[C.reduced_mass_motion] != 0.0:  # Eq. (19) as sam has it: without J r' omega^2 / r (Eq. (7)'s R-dot)
        tau -= J * torque_arm_slope(y[R.theta], c[C.L_1], c[C.L_2], c[C.L_3]) * y[R.omega] ** 2 / r
    dy[R.omega] = tau / J  # Eq. (16)

    Q_A, Q_B, Q_P = valve_flows(y[R.x_s], p_A, p_B, p_S, c)
    Q_AB, Q_extA, Q_extB = leak_flows(p_A, p_B, c)
    B = c[C.B]
    dy[R.oil_A] = (Q_A - Q_AB - Q_extA) / specific_volume(p_A, y[R.air_A], B)[0]
    dy[R.oil_B] = (Q_B + Q_AB - Q_extB) / specific_volume(p_B, y[R.air_B], B)[0]
    dy[R.oil_S] = 0.0 if math.isinf(c[C.pump]) else supply_line_flow(p_S, Q_P, c) / specific_volume(p_S, 0.0, B)[0]

    dy[R.x_s] = 0.0 if c[C.spool_stuck] != 0.0 else y[R.w_s]
    dy[R.w_s] = spool_acceleration(y[R.x_s], y[R.w_s], u, c)
    dy[R.z] = dz
    dy[R.air_A] = (free_air_equilibrium(p_A, c) - y[R.air_A]) / c[C.air_tau]
    dy[R.air_B] = (free_air_equilibrium(p_B, c) - y[R.air_B]) / c[C.air_tau]
    lag = c[C.lag]
    dy[R.y_A] = 0.0 if lag == 0.0 else (p_A - y[R.y_A]) / lag
    dy[R.y_B] = 0.0 if lag == 0.0 else (p_B - y[R.y_B]) / lag


#: The channels :func:`observe` writes, in order.
CHANNELS = ("theta", "omega", "x", "v", "p_A", "p_B", "p_S", "x_s", "z", "y_A", "y_B")


@jit
def observe(y, c, out):
    """Write the true physical quantities of the state ``y`` into ``out`` (len(CHANNELS),)."""
    x, p_A, p_B, p_S = pressures(y, c)
    lagged = c[C.lag] != 0.0
    out[0], out[1], out[2] = y[R.theta], y[R.omega], x
    out[3] = torque_arm(y[R.theta], c[C.L_1], c[C.L_2], c[C.L_3]) * y[R.omega]
    out[4], out[5], out[6], out[7], out[8] = p_A, p_B, p_S, y[R.x_s], y[R.z]
    out[9] = y[R.y_A] if lagged else p_A
    out[10] = y[R.y_B] if lagged else p_B


def initial_state(c: np.ndarray, x0: float) -> np.ndarray:
    """The rig at rest with the valve centred for a long time, the piston at x0 [m] (N_STATE,).

    Each chamber's pressure is where the null leakage in and out of it balances (Eqs. (13)-(14)
    with no flow), except that away from the retracted stop chamber A holds the load; on the stop
    (x0 = 0) the contact carries what the pressures do not, compressed by that force. A load that
    pulls the piston out harder than the rod side's pressure resists leaves chamber A at the oil's
    vapour pressure and chamber B carrying it. The free air is at its equilibrium, the bristles
    relaxed, the supply line at p_S.
    """
    p_S, p_T = c[C.p_S], c[C.p_T]
    p_A = _null_balance(c[C.KL_PA], c[C.KL_AT], p_S, p_T)
    p_B = _null_balance(c[C.KL_PB], c[C.KL_BT], p_S, p_T)
    x = x0
    for _ in range(3):  # on the stop its compression moves the boom a little: a fixed point
        load = _load_force(c, x)
        if x0 > 0.0:
            p_A = (p_B * c[C.A_B] + load) / c[C.A_A]
            if p_A < P_VAPOUR:  # pulled out: the rod side holds the load
                p_A, p_B = P_VAPOUR, (P_VAPOUR * c[C.A_A] - load) / c[C.A_B]
            break
        x = -max(load - (p_A * c[C.A_A] - p_B * c[C.A_B]), 0.0) / c[C.k_stop]
    y = np.zeros(N_STATE)
    y[R.theta] = joint_angle(x, c[C.L_1], c[C.L_2], c[C.L_3])
    B = c[C.B]
    y[R.air_A], y[R.air_B] = free_air_equilibrium(p_A, c), free_air_equilibrium(p_B, c)
    y[R.oil_A] = oil_for_pressure(p_A, c[C.V_0A] + c[C.A_A] * x, y[R.air_A], c[C.hose_A], c[C.hose_modulus], B)
    y[R.oil_B] = oil_for_pressure(p_B, c[C.V_0B] + c[C.A_B] * (c[C.x_max] - x), y[R.air_B], c[C.hose_B],
                                  c[C.hose_modulus], B)
    y[R.oil_S] = oil_for_pressure(p_S, c[C.V_line], 0.0, 0.0, math.inf, B)
    y[R.y_A], y[R.y_B] = p_A, p_B
    return y


def _load_force(c: np.ndarray, x: float) -> float:
    """Gravity's force [N] on the piston at x [m], opposing extension: tau_g / r (Eq. (21))."""
    theta = joint_angle(x, c[C.L_1], c[C.L_2], c[C.L_3])
    return gravity_torque(theta, c, c[C.m_L]) / torque_arm(theta, c[C.L_1], c[C.L_2], c[C.L_3])


def _null_balance(k_in: float, k_out: float, p_S: float, p_T: float) -> float:
    """Pressure where laminar leaks from the supply (k_in) and to the tank (k_out) balance."""
    return (k_in * p_S + k_out * p_T) / (k_in + k_out) if k_in + k_out > 0 else p_T
