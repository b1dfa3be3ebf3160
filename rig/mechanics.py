"""The boom, the seals and the spool, written in the joint angle theta (Eqs. (3)-(5), (15)-(17)).

The rig integrates the boom as the rigid body it is, ``J theta'' = r F_cyl - tau_g``
(Eq. (16), with Eq. (5)'s r = dx/dtheta), where sam writes it at the piston with a reduced mass
(Eqs. (19)-(20), neglecting the rate of change of r: Eq. (7)'s R-dot term). The gravity torque
follows contract C1. Scalar functions, compiled by numba, called by :mod:`rig.model`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .layout import C, G

jit = numba.njit(cache=True, error_model="numpy")


@jit
def piston_position(theta, L_1, L_2, L_3):
    """Eq. (3): the piston position x [m] at the joint angle theta [rad] (law of cosines; a float
    or an array)."""
    return np.sqrt(L_1 * L_1 + L_2 * L_2 - 2.0 * L_1 * L_2 * np.cos(theta)) - L_3


@jit
def joint_angle(x, L_1, L_2, L_3):
    """Eq. (3) solved for theta [rad] at the piston position x [m] (a float or an array)."""
    return np.arccos((L_1 * L_1 + L_2 * L_2 - (x + L_3) ** 2) / (2.0 * L_1 * L_2))


@jit
def torque_arm(theta, L_1, L_2, L_3):
    """Eq. (5): r = dx/dtheta [m], the cylinder's lever about the joint."""
    return L_1 * L_2 * math.sin(theta) / (piston_position(theta, L_1, L_2, L_3) + L_3)


@jit
def torque_arm_slope(theta, L_1, L_2, L_3):
    """dr/dtheta [m] of Eq. (5): ``(L_1 L_2 cos(theta) - r^2) / l`` with l = x + L_3 the pin distance."""
    l = piston_position(theta, L_1, L_2, L_3) + L_3
    r = L_1 * L_2 * math.sin(theta) / l
    return (L_1 * L_2 * math.cos(theta) - r * r) / l


@jit
def gravity_torque(theta, c, m_L):
    """Gravity torque [N m] opposing extension (contract C1): with the elevation
    phi = theta - theta_level, ``(m_L - m_R) g L cos(phi) + m_B g r_B cos(phi + cog_angle)``."""
    phi = theta - c[C.theta_level]
    return (m_L - c[C.m_R]) * G * c[C.L] * math.cos(phi) + c[C.m_B] * G * c[C.r_B] * math.cos(phi + c[C.cog_angle])


@jit
def potential_energy(theta, c, m_L):
    """The boom's and loads' potential energy [J] (zero with the boom level); d/dtheta of it is
    :func:`gravity_torque`."""
    phi = theta - c[C.theta_level]
    return (m_L - c[C.m_R]) * G * c[C.L] * math.sin(phi) + c[C.m_B] * G * c[C.r_B] * math.sin(phi + c[C.cog_angle])


@jit
def inertia(c, m_L):
    """J_tot [kg m^2] about the joint, Eq. (16), with the load's own inertia and any extra."""
    return c[C.J_fixed] + m_L * c[C.gyration_sq]


@jit
def seal_friction_levels(c, p_A, p_B):
    """(F_C, F_S) [N] of Eq. (17), raised by the pressures on the piston and rod seals."""
    rise = c[C.seal_piston] * abs(p_A - p_B) + c[C.seal_rod] * max(p_B, 0.0)
    return c[C.F_C] + rise, c[C.F_S] + rise


@jit
def lugre(v, z, F_C, F_S, c, m_reduced):
    """Eq. (17), LuGre (Canudas de Wit et al., 1995): (dz/dt [m/s], friction force [N] against v).
    ``g(v) = F_C + (F_S - F_C) exp(-(v/v_s)^2)``, ``dz/dt = v - sigma_0 |v| z / g``,
    ``F = sigma_0 z + sigma_1 dz/dt + b v`` with Appendix 2's sigma_1 = 2 sqrt(sigma_0 m_reduced)."""
    ratio = v / c[C.v_s]
    g = F_C + (F_S - F_C) * math.exp(-ratio * ratio)
    sigma_0 = c[C.sigma_0]
    dz = v - sigma_0 * abs(v) * z / g
    return dz, sigma_0 * z + 2.0 * math.sqrt(sigma_0 * m_reduced) * dz + c[C.b] * v


@jit
def stop_force(x, v, c):
    """Force [N] of the end stops on the piston (+ extends): a Hunt-Crossley contact at x = 0 and
    x = x_end, ``k d (1 + 1.5 alpha d')`` for a penetration d, which pushes and never pulls. Its
    damping grows with the penetration, so the force has no jump on contact (a spring and a plain
    damper would jump by c v, and an integrator would resolve the impact to first order only)."""
    over = -x if x < 0.0 else x - c[C.x_end]
    if over <= 0.0:
        return 0.0
    rate = -v if x < 0.0 else v  # d(over)/dt
    force = c[C.k_stop] * over * max(1.0 + 1.5 * c[C.stop_damping] * rate, 0.0)
    return force if x < 0.0 else -force


@jit
def spool_acceleration(x_s, w_s, u, c):
    """Eq. (15) with the dimensionally consistent K omega_n^2 u (docs/model.md) [1/s^2], and a
    sticking spool: held while the integrator says it sticks (it breaks free at a pull of
    omega_n^2 ``stiction``); while it slides, against a Coulomb friction of ``spool_sliding`` of
    that (below 1: it jumps when it breaks free, the stick-slip of a sticking spool)."""
    if c[C.spool_stuck] != 0.0:
        return 0.0
    w = c[C.omega_n]
    a = w * w * (c[C.K_u] * u - x_s) - 2.0 * w * c[C.zeta] * w_s
    if c[C.stiction] > 0.0 and w_s != 0.0:
        a -= math.copysign(w * w * c[C.stiction] * c[C.spool_sliding], w_s)
    return a


@jit
def spool_pull(x_s, u, c):
    """What drives a resting spool [1/s^2]: omega_n^2 (K u - x_s). It breaks free beyond
    omega_n^2 times the stiction."""
    w = c[C.omega_n]
    return w * w * (c[C.K_u] * u - x_s)
