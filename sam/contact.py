"""The piston's end stops: rigid and inelastic (the paper's model, the default) or a spring-damper
contact (:class:`sam.params.EndStops`).

A rigid stop holds the piston at x = 0 and x = x_end and zeroes its velocity into the stop: all
of an impact's kinetic energy is lost at once, and the piston never leaves the stop by itself. A
real stop is the column of rod, tube, end cap and pins: it gives under the load (tens of um) and
throws the piston back at a share of its impact speed. With ``k_stop > 0`` the step draws that
contact (Eq. (C1)) and leaves the piston free to enter it; the displacement flows of Eqs. (8)-(9)
then follow the piston into the contact as everywhere else.

Eq. (C1), Kelvin-Voigt with release: for a penetration d >= 0 (d = -x at the retracted stop,
d = x - x_end at the extension stop),

    F_stop = max(k_stop d + c d', 0),   c = 2 zeta_stop sqrt(k_stop m)          [N]

pushing the piston out of the stop and never pulling it in; m is the reduced mass of Eq. (20),
so zeta_stop is the contact's damping ratio whatever the load. A free mass meeting it at speed v0
leaves when the force falls to zero, at the restitution of :func:`restitution`, and a force F
pressing it on the stop sinks it by F / k_stop.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .simd import quot, sqrt, where

# error_model="numpy": IEEE results (inf, nan) instead of a zero-division check per division
jit = numba.njit(cache=True, error_model="numpy")


@jit
def stop_acceleration(x, v, x_end, k_stop, zeta_stop, inv_m_red, f=np.float64):
    """Eq. (C1)'s force over the reduced mass [m/s^2] (+ extends) on a piston at x [m] moving at
    v [m/s], stops at 0 and ``x_end`` [m]; ``inv_m_red`` [1/kg] is 1 / m of Eq. (20). 0 between
    the stops (and for k_stop = 0)."""
    zero = f(0.0)
    c = f(2.0) * zeta_stop * sqrt(k_stop * inv_m_red)  # c / m [1/s]
    into_retracted = max(-k_stop * inv_m_red * x - c * v, zero)
    into_extended = max(k_stop * inv_m_red * (x - x_end) + c * v, zero)
    return where(x < zero, into_retracted, zero) - where(x > x_end, into_extended, zero)


@jit
def stop_travel_velocity(x, v, dt, x_end, f=np.float64):
    """The mean velocity [m/s] of a step of dt [s] from x [m] at v [m/s] that a rigid end stop
    cuts short: the travel to the stop over dt, 0 from on (or beyond) it, v where the step does not
    reach it. The displacement flows A v of Eqs. (8)-(9) must use it, not v: the stop is rigid
    and inelastic, so a chamber is compressed only by the distance the piston really moves."""
    retracts = (v < f(0.0)) & (x + dt * v < f(0.0))
    extends = (v > f(0.0)) & (x + dt * v > x_end)
    travel = where(retracts, -max(x, f(0.0)), max(x_end - x, f(0.0)))
    return where(retracts | extends, quot(travel, dt), v)


def restitution(zeta_stop: float) -> float:
    """The coefficient of restitution e = v_out / v_in of Eq. (C1) for a free mass, damping ratio
    0 <= zeta_stop < 1: the mass leaves where the force k d + c d' falls to zero, at
    omega_d t = pi - 2 asin(zeta), so

        e = exp(-zeta (pi - 2 asin(zeta)) / sqrt(1 - zeta^2))                          (C2)

    (1 at zeta = 0; the unreleased spring-damper's exp(-zeta pi / sqrt(1 - zeta^2)) would pull the
    mass back at the end of the rebound)."""
    if not 0.0 <= zeta_stop < 1.0:
        raise ValueError(f"restitution: zeta_stop = {zeta_stop!r} must be in [0, 1)")
    return math.exp(-zeta_stop * (math.pi - 2.0 * math.asin(zeta_stop)) / math.sqrt(1.0 - zeta_stop**2))
