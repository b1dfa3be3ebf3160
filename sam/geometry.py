"""Boom geometry and load, Eqs. (3)-(5), (16), (20)-(21).

The paper's Fig. 3 is lost; docs/model.md reconstructs it. Conventions:

* ``theta`` is the joint angle between the boom-side and base-side cylinder
  joints as seen from the boom joint (0.728 rad with the cylinder retracted).
* The boom's elevation (left arm above horizontal) is ``phi = theta - theta_level``:
  the boom is level at the joint angle ``theta_level`` (a plant setting).
* The left load m_L is raised by extension; the right load m_R is lowered.
* The boom's centre of gravity lies r_B from the joint in the direction ``cog_angle``
  (a plant setting), measured in the boom's frame from the m_L arm, positive upward:
  -pi/2 hangs it below the joint (a pendulum whose torque restores the boom to level),
  0 puts it on the m_L arm, pi on the m_R arm.

The gravity torque opposing extension is then
``tau = (m_L - m_R) g L cos(phi) + m_B g r_B cos(phi + cog_angle)``, the derivative of
the potential energy with respect to theta (so Eq. (21)'s F_ext = tau / r = dE_pot/dx).

Every function here is compiled by numba and accepts scalars or numpy arrays, so
the same source serves numpy callers (vectorised) and the compiled model kernel.
The kernel works with cos/sin of the angles rather than the angles themselves:
no trigonometric call is needed per time step.
"""

from __future__ import annotations

import numba
import numpy as np

from .constants import G
from .simd import quot

HALF_PI = np.pi / 2  #: rad, the double nearest pi/2: a quarter turn for quarter_turn_cos_sin

# error_model="numpy": IEEE results (inf, nan) instead of a zero-division check per division
jit = numba.njit(cache=True, error_model="numpy")


@jit
def piston_position(theta, L_1, L_2, L_3):
    """Eq. (3): piston position x [m] from the joint angle theta [rad]."""
    return np.sqrt(L_1**2 + L_2**2 - 2.0 * L_1 * L_2 * np.cos(theta)) - L_3


@jit
def stroke_end(x_max, theta_max, L_1, L_2, L_3):
    """The extension end stop [m]: the stroke x_max or the piston position of the joint limit
    theta_max (Eq. (3)), whichever comes first (scalars or arrays)."""
    return np.minimum(x_max, piston_position(theta_max, L_1, L_2, L_3))


@jit
def cos_joint_angle(x, L_1, L_2, L_3, f=np.float64):
    """cos(theta) from the piston position x [m]: Eq. (3) solved for theta (``f``: the float type)."""
    return quot(L_1**2 + L_2**2 - (x + L_3) ** 2, f(2.0) * L_1 * L_2)


@jit
def joint_angle(x, L_1, L_2, L_3):
    """Inverse of Eq. (3): joint angle theta [rad] from the piston position x [m]."""
    return np.arccos(cos_joint_angle(x, L_1, L_2, L_3))


@jit
def torque_arm_cs(x, sin_theta, L_1, L_2, L_3):
    """Eq. (5): r [m], given the piston position x [m] and sin(theta) at that x."""
    return quot(L_1 * L_2 * sin_theta, x + L_3)


@jit
def torque_arm_slope_cs(x, cos_theta, r, L_1, L_2, L_3):
    """dr/dtheta [m] of Eq. (5), given x [m], cos(theta) and r there: ``(L_1 L_2 cos(theta) - r^2) / (x + L_3)``
    (the pin distance x + L_3 grows at r per radian)."""
    return (L_1 * L_2 * cos_theta - r * r) / (x + L_3)


@jit
def torque_arm(x, L_1, L_2, L_3):
    """Eq. (5): torque arm r = dx/dtheta [m] at piston position x [m]."""
    c = cos_joint_angle(x, L_1, L_2, L_3)
    return torque_arm_cs(x, np.sqrt(1.0 - c * c), L_1, L_2, L_3)


@jit
def total_inertia(m_B, L_B, m_L, m_R, L):
    """Eq. (16), denominator: J_tot [kg m^2] about the boom joint."""
    return m_B * L_B**2 / 12.0 + (m_L + m_R) * L**2


@jit
def reduced_mass(J_tot, r):
    """Eq. (20): the boom's inertia seen at the piston, m_reduced [kg]."""
    return J_tot / (r * r)


@jit
def quarter_turn_cos_sin(angle):
    """(cos, sin) of ``angle`` [rad] (scalar or array), exact at the quarter turns.

    The angle is reduced by the nearest multiple k of :data:`HALF_PI` (an exact subtraction
    for |k| <= 2) and the quarter turns are applied by swapping and negating. So -pi/2 gives
    exactly (0, -1), not cos = 6e-17, and pi/2 - a gives exactly (sin a, cos a) whenever
    pi/2 - a is a double: a convention written as a complement reproduces the constants of
    the convention it replaces bit for bit.
    """
    k = np.round(angle / HALF_PI)
    r = angle - k * HALF_PI
    c, s = np.cos(r), np.sin(r)
    q = k - 4.0 * np.floor(k / 4.0)  # k mod 4
    cq = 1.0 * (q == 0.0) - 1.0 * (q == 2.0)  # cos and sin of the q quarter turns: 0 or +-1
    sq = 1.0 * (q == 1.0) - 1.0 * (q == 3.0)
    return c * cq - s * sq, s * cq + c * sq


@jit
def load_torque_cs(cos_theta, sin_theta, cos_level, sin_level, cos_cog, sin_cog, m_B, r_B, m_L, m_R, L, f=np.float64):
    """Net gravity torque [N m] opposing extension, tau_mL - tau_mR + tau_B (Eqs. (16), (21)),
    from cos/sin of the joint angle theta, of theta_level and of cog_angle.

    With phi = theta - theta_level, ``tau = (m_L - m_R) g L cos(phi) + m_B g r_B cos(phi + cog_angle)``,
    expanded so that no angle is evaluated.
    """
    cos_phi = cos_theta * cos_level + sin_theta * sin_level
    sin_phi = sin_theta * cos_level - cos_theta * sin_level
    return (m_L - m_R) * f(G) * L * cos_phi + m_B * f(G) * r_B * (cos_phi * cos_cog - sin_phi * sin_cog)


@jit
def external_force(x, L_1, L_2, L_3, theta_level, cog_angle, m_B, r_B, m_L, m_R, L):
    """Eq. (21): load force F_ext [N] on the piston at position x [m], positive opposing extension."""
    c = cos_joint_angle(x, L_1, L_2, L_3)
    s = np.sqrt(1.0 - c * c)
    cos_level, sin_level = quarter_turn_cos_sin(theta_level)
    cos_cog, sin_cog = quarter_turn_cos_sin(cog_angle)
    tau = load_torque_cs(c, s, cos_level, sin_level, cos_cog, sin_cog, m_B, r_B, m_L, m_R, L)
    return tau / torque_arm_cs(x, s, L_1, L_2, L_3)
