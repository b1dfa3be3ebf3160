"""LuGre friction, Eq. (17) (Canudas de Wit et al., 1995).

Eq. (17) in the paper is garbled in print; this is the standard LuGre model it
cites, with the paper's choice sigma_1 = 2 sqrt(sigma_0 m_reduced) (critical
damping of the bristles against the moving mass).
"""

from __future__ import annotations

import numba
import numpy as np

from .simd import exp, quot

# error_model="numpy": IEEE results (inf, nan) instead of a zero-division check per division
jit = numba.njit(cache=True, error_model="numpy")


@jit
def stribeck(v, F_C, F_S, v_s):
    """g(v) = F_C + (F_S - F_C) exp(-(v/v_s)^2) [N]: the steady-state friction magnitude."""
    return F_C + (F_S - F_C) * exp(-(quot(v, v_s) ** 2))


@jit
def seal_loaded(F, p_A, p_B, k_fric_p, f=np.float64):
    """A friction level F [N] raised by the chamber pressures on the seals (an optional effect)."""
    return F + k_fric_p * np.maximum(p_A + p_B, f(0.0))


@jit
def seal_pressure_rise(p_A, p_B, k_fric_dp, k_fric_rod, f=np.float64):
    """The rise [N] of the friction levels F_C, F_S of Eq. (17) with the pressures the seals hold
    (an optional effect; docs/model.md, "Effects"): ``k_fric_dp |p_A - p_B| + k_fric_rod max(p_B, 0)``.

    A reciprocating seal's lip is pressed onto its counter-surface by the pressure difference it
    seals, so its friction grows about linearly with it: the piston seal holds the difference
    between the chambers, the rod seal the rod-side pressure against the atmosphere (gauge; below
    atmospheric the lip is not pressed harder). k_fric_dp and k_fric_rod [m^2] are the effective
    areas of that contact; 0 gives 0 (then F + 0 is F to the last bit)."""
    return k_fric_dp * np.abs(p_A - p_B) + k_fric_rod * np.maximum(p_B, f(0.0))


@jit
def bristle_rate(v, z, g, sigma_0):
    """dz/dt [m/s] of the bristle deflection z: v - sigma_0 |v| z / g(v) (Eq. (19), 7th row)."""
    return v - quot(sigma_0 * np.abs(v) * z, g)


@jit
def bristle_damping(sigma_0, m_reduced):
    """The paper's sigma_1 = 2 sqrt(sigma_0 m_reduced) [N s/m] (Appendix 2)."""
    return 2.0 * np.sqrt(sigma_0 * m_reduced)


@jit
def lugre_force(v, z, dz, sigma_0, sigma_1, b):
    """Eq. (17): friction force [N] opposing motion, sigma_0 z + sigma_1 dz/dt + b v."""
    return sigma_0 * z + sigma_1 * dz + b * v
