"""The model's state, right-hand side (Eq. (19)) and its one step: Eq. (22)'s forward Euler by
default (semi-implicit where a chamber pressure is stiff), or sub-steps of a higher-order scheme
(:class:`Scheme`).

This module is the one place where the physics is assembled. The batch simulator, the global
sensitivity analysis and the Unscented Kalman Filter all advance the model through the step
here, on many runs at once: :func:`step_lanes` advances the runs ("lanes") of a block in one
inner loop that LLVM vectorises, so every function below is written for one lane and
branch-free (:func:`sam.simd.where`: every case is computed and one kept). :func:`step`,
:func:`euler_step` and :func:`rhs` are the same functions on one state vector.

State vector, Eq. (18), indexed by :data:`S`::

    [p_A, p_B, x_s, dx_s/dt, x, v, z]
     Pa   Pa   1    1/s      m  m/s m

A block of lanes holds the states as ``s`` (7, W), the parameters (:mod:`sam.params`, indexed
by :data:`P`) as ``p`` (len(P), W) and their derived constants (:data:`D`) as ``d``
(len(D), W): lane j is column j. One lane's state inside a step is a tuple ``y`` of 7 floats.
"""

from __future__ import annotations

from enum import IntEnum

import numba
import numpy as np

from .constants import P_CAVITATION
from .contact import stop_acceleration, stop_travel_velocity
from .friction import bristle_damping, bristle_rate, lugre_force, seal_loaded, seal_pressure_rise, stribeck
from .geometry import (
    cos_joint_angle, load_torque_cs, quarter_turn_cos_sin, stroke_end, torque_arm_cs, torque_arm_slope_cs,
    total_inertia,
)
from .hydraulics import (
    fault_leakages, flow_coefficient, inverse_capacitance, leak_conductance, valve_flows, valve_flows_ideal,
)
from . import views
from .params import P
from .simd import float_type, quot, sqrt, where
from .variant import LEAK_COLS, kernel_variant  # noqa: F401  (the step's API: which compiled variant a batch needs)

# error_model="numpy": IEEE results (inf, nan) instead of a zero-division check per division
jit = numba.njit(cache=True, error_model="numpy")
# The per-lane functions are inlined into the lane loops: the loop vectoriser sees one body.
jit_inline = numba.njit(cache=True, inline="always", error_model="numpy")
# The lane loops allocate nothing, so they run without numba's reference counting (_nrt=False):
# an array handed to an inlined function otherwise costs a count and its release in the loop
# body, calls that stop the vectoriser (even on a borrowed view, sam.views, whose count is none).
jit_lanes = numba.njit(cache=True, error_model="numpy", _nrt=False)


class S(IntEnum):
    """Index of each state in the state vector, Eq. (18)."""

    p_A = 0
    p_B = 1
    x_s = 2
    dx_s = 3
    x = 4
    v = 5
    z = 6


N_STATES = len(S)
N_PARAMS = len(P)

#: Lanes of a block (:func:`step_lanes`): runs advanced together in one vectorised loop. A block's
#: arrays have this many columns, so that its rows lie at constant strides.
LANES = 32

#: Bits of the flag word returned by the step.
FLAG_CAVITATION = 1  #: a chamber pressure was clamped at the cavitation floor


class D(IntEnum):
    """Index of each per-run constant derived from the parameters (see :func:`derive`)."""

    K_PA = 0  #: m^3/(s Pa^0.5), Eq. (12)
    K_AT = 1
    K_PB = 2
    K_BT = 3
    A_A = 4  #: m^2
    A_B = 5  #: m^2
    cos_level = 6  #: cos(theta_level)
    sin_level = 7
    x_end = 8  #: m, extension end stop
    inv_J_tot = 9  #: 1/(kg m^2), inverse of J_tot, Eq. (16)
    sigma_1_r = 10  #: N s, sigma_1 times the torque arm r (sigma_1 = sigma_1_r / r)
    cos_cog = 11  #: cos(cog_angle)
    sin_cog = 12


N_DERIVED = len(D)

#: Parameters that :func:`derive` reads: when one of them varies in time the
#: constants are derived again at every step.
DERIVE_INPUTS = frozenset({
    "Q_N_PA", "Q_N_AT", "Q_N_PB", "Q_N_BT", "dp_N_PA", "dp_N_AT", "dp_N_PB", "dp_N_BT",
    "D_piston", "D_rod", "x_max", "theta_level", "cog_angle", "theta_max", "L_1", "L_2", "L_3",
    "m_B", "m_L", "m_R", "L_B", "L", "sigma_0",
})
#: Those of them that only :func:`derive_geometry` reads (its trigonometry).
GEOMETRY_INPUTS = frozenset({"x_max", "theta_level", "cog_angle", "theta_max", "L_1", "L_2", "L_3"})


@jit
def areas(D_piston, D_rod):
    """Piston and annulus areas (A_A, A_B) [m^2] from the diameters (Appendix 2)."""
    A_A = np.pi * D_piston**2 / 4.0
    return A_A, A_A - np.pi * D_rod**2 / 4.0


def stroke_ends(params) -> np.ndarray:
    """m, (...,): the extension end stop (:func:`stroke_end`) of every parameter row of
    ``params`` (..., len(P)); the retraction stop is x = 0. The step clamps there."""
    p = np.asarray(params, dtype=float)
    return stroke_end(p[..., P.x_max], p[..., P.theta_max], p[..., P.L_1], p[..., P.L_2], p[..., P.L_3])


@jit
def derive(p, d):
    """Fill ``d`` (len(D),) with the constants of parameter vector ``p`` (len(P),).

    They hold for a whole run (or until a parameter they depend on changes), so
    the square roots and trigonometry here are not repeated at every step.
    """
    pj, dj = _column(p), np.empty((N_DERIVED, 1))
    derive_geometry(pj, dj, 0)
    derive_machine(pj, dj, 0)
    d[:] = dj[:, 0]


@jit_inline
def _column(a):
    """The 1-D array ``a`` as a one-lane block (len(a), 1), a copy only where it is not contiguous."""
    return np.ascontiguousarray(a).reshape((a.shape[0], 1))


@jit_inline
def derive_geometry(p, d, j):
    """The constants of :func:`derive` of lane j that depend on GEOMETRY_INPUTS only: cos and sin
    of the boom's conventions (theta_level, cog_angle) and the extension end stop."""
    d[D.cos_level, j], d[D.sin_level, j] = quarter_turn_cos_sin(p[P.theta_level, j])
    d[D.cos_cog, j], d[D.sin_cog, j] = quarter_turn_cos_sin(p[P.cog_angle, j])
    d[D.x_end, j] = stroke_end(p[P.x_max, j], p[P.theta_max, j], p[P.L_1, j], p[P.L_2, j], p[P.L_3, j])


@jit_inline
def derive_machine(p, d, j):
    """The other constants of :func:`derive` of lane j: the notches' flow coefficients
    (Eq. (12)), the areas, the inertia (Eq. (16)) and the bristle damping."""
    d[D.K_PA, j] = flow_coefficient(p[P.Q_N_PA, j], p[P.dp_N_PA, j])
    d[D.K_AT, j] = flow_coefficient(p[P.Q_N_AT, j], p[P.dp_N_AT, j])
    d[D.K_PB, j] = flow_coefficient(p[P.Q_N_PB, j], p[P.dp_N_PB, j])
    d[D.K_BT, j] = flow_coefficient(p[P.Q_N_BT, j], p[P.dp_N_BT, j])
    d[D.A_A, j], d[D.A_B, j] = areas(p[P.D_piston, j], p[P.D_rod, j])
    J_tot = total_inertia(p[P.m_B, j], p[P.L_B, j], p[P.m_L, j], p[P.m_R, j], p[P.L, j])
    d[D.inv_J_tot, j] = 1.0 / J_tot
    # sigma_1 = 2 sqrt(sigma_0 J_tot / r^2) = bristle_damping(sigma_0, J_tot) / r
    d[D.sigma_1_r, j] = bristle_damping(p[P.sigma_0, j], J_tot)


@jit_inline
def rates(y, u, p, d, j, leaks=True, effects=True, f=np.float64):
    """Eq. (19): ds/dt of lane j at state ``y`` (a 7-tuple) under control ``u`` [V].

    Returns (ds/dt as a 7-tuple, c_A, c_B, G_A, G_B, G_AB): with the rates, what the
    semi-implicit pressure step needs (:func:`stiff_pressure_rates`): (c_A, c_B) [Pa/m^3], each
    chamber's inverse capacitance d(dp/dt)/dQ (Eqs. (8)-(9)); (G_A, G_B) [m^3/(s Pa)], the sum of
    the chord conductances q / dp of its paths to the supply and the tank (the open metering
    edges, the null leakage, the external leak); and G_AB, that of the paths between the chambers
    (the internal leak, the bypass).

    Friction is LuGre (Eq. (17)); the load force is Eq. (21) plus the disturbance force F_d;
    leak faults are Eqs. (41)-(43); the optional effects of :class:`sam.params.Effects` enter
    through the hydraulics and friction functions; Eq. (7)'s R-dot term where the plant's
    ``[equations]`` keep it. ``leaks=False`` promises K_int = K_extA = K_extB = K_bypass = 0 and
    ``effects=False`` lap >= 0, R_supply = 0, Q_sat = x_open = Q_pump = inf, air_fraction = 0, no seal terms
    k_fric_dp, k_fric_rod, no R-dot term and rigid end stops, k_stop = 0 (:func:`kernel_variant`): the same
    numbers without the arithmetic that would give zeros; an elastic stop pushes by Eq. (C1)
    (:mod:`sam.contact`). ``f`` is the float type of the arithmetic.
    """
    p_A, p_B, x_s, dx_s, x, v, z = y
    A_A, A_B = d[D.A_A, j], d[D.A_B, j]
    p_S, p_T, offset, lap, leak_band = p[P.p_S, j], p[P.p_T, j], p[P.offset, j], p[P.lap, j], p[P.leak_band, j]
    K_leak_PA, K_leak_AT, K_leak_PB, K_leak_BT = p[P.K_leak_PA, j], p[P.K_leak_AT, j], p[P.K_leak_PB, j], p[P.K_leak_BT, j]
    K_PA, K_AT, K_PB, K_BT = d[D.K_PA, j], d[D.K_AT, j], d[D.K_PB, j], d[D.K_BT, j]

    # Hydraulics, Eqs. (8)-(14), (41)-(43)
    if effects:
        Q_A, Q_B, G_A, G_B = valve_flows(x_s, p_A, p_B, offset, p_S, p_T, K_PA, K_AT, K_PB, K_BT, K_leak_PA, K_leak_AT,
                                         K_leak_PB, K_leak_BT, leak_band, lap, p[P.R_supply, j], p[P.Q_sat, j],
                                         p[P.x_open, j], p[P.Q_pump, j], f)
    else:
        Q_A, Q_B, G_A, G_B = valve_flows_ideal(x_s, p_A, p_B, offset, p_S, p_T, K_PA, K_AT, K_PB, K_BT, K_leak_PA,
                                               K_leak_AT, K_leak_PB, K_leak_BT, leak_band, lap, f)
    K_bypass = p[P.K_bypass, j]
    Q_bypass = K_bypass * (p_A - p_B)
    Q_int = Q_extA = Q_extB = f(0.0)
    G_AB = K_bypass  # the paths between the chambers
    if leaks:
        K_int, K_extA, K_extB = p[P.K_int, j], p[P.K_extA, j], p[P.K_extB, j]
        Q_int, Q_extA, Q_extB = fault_leakages(p_A, p_B, p_T, K_int, K_extA, K_extB)
        G_A += leak_conductance(Q_extA, p_A - p_T, K_extA, f)
        G_B += leak_conductance(Q_extB, p_B - p_T, K_extB, f)
        G_AB = leak_conductance(Q_int, p_A - p_B, K_int, f) + K_bypass
    Q_netA = Q_A - Q_int - Q_extA - Q_bypass + p[P.Q_dA, j] - A_A * v
    Q_netB = Q_B + Q_int - Q_extB + Q_bypass + p[P.Q_dB, j] + A_B * v
    B_eff, air, C_hose = p[P.B_eff, j], p[P.air_fraction, j], p[P.C_hose, j]
    c_A = inverse_capacitance(p[P.V_0A, j] + A_A * x, p_A, B_eff, air, C_hose, f, effects)
    c_B = inverse_capacitance(p[P.V_0B, j] + A_B * (p[P.x_max, j] - x), p_B, B_eff, air, C_hose, f, effects)

    # Spool, Eq. (15), with the dimensionally consistent K omega_n^2 u
    w = p[P.omega_n, j]
    ddx_s = p[P.K_u, j] * w * w * u - f(2.0) * w * p[P.zeta, j] * dx_s - w * w * x_s

    # Boom seen at the piston, Eqs. (5), (16), (20), (21)
    L_1, L_2, L_3 = p[P.L_1, j], p[P.L_2, j], p[P.L_3, j]
    cos_theta = cos_joint_angle(x, L_1, L_2, L_3, f)
    sin_theta = sqrt(f(1.0) - cos_theta * cos_theta)
    r = torque_arm_cs(x, sin_theta, L_1, L_2, L_3)
    inv_r = quot(f(1.0), r)  # divisions are the step's dearest operations: one here serves three
    inv_m_red = r * r * d[D.inv_J_tot, j]  # 1 / m_reduced, Eq. (20)
    tau = load_torque_cs(
        cos_theta, sin_theta, d[D.cos_level, j], d[D.sin_level, j], d[D.cos_cog, j], d[D.sin_cog, j],
        p[P.m_B, j], p[P.r_B, j], p[P.m_L, j], p[P.m_R, j], p[P.L, j], f,
    )
    F_ext = tau * inv_r + p[P.F_d, j]

    # LuGre friction, Eq. (17), its levels raised by the pressures on the seals (Effects; F + 0 is F)
    F_C, F_S, k_fric_p, sigma_0 = p[P.F_C, j], p[P.F_S, j], p[P.k_fric_p, j], p[P.sigma_0, j]
    if effects:
        rise = seal_pressure_rise(p_A, p_B, p[P.k_fric_dp, j], p[P.k_fric_rod, j], f)
        F_C, F_S = F_C + rise, F_S + rise
    g = stribeck(v, seal_loaded(F_C, p_A, p_B, k_fric_p, f), seal_loaded(F_S, p_A, p_B, k_fric_p, f), p[P.v_s, j])
    dz = bristle_rate(v, z, g, sigma_0)
    F_mu = lugre_force(v, z, dz, sigma_0, d[D.sigma_1_r, j] * inv_r, p[P.b, j])

    dv = (p_A * A_A - p_B * A_B - F_mu - F_ext) * inv_m_red
    if effects:
        # Eq. (7)'s R-dot term, which Eq. (19) neglects: v = r omega, so dv/dt = r omega' + r'(theta) omega^2
        arm_rate = torque_arm_slope_cs(x, cos_theta, r, L_1, L_2, L_3) * v * v * inv_r * inv_r
        dv = where(p[P.arm_rate_torque, j] != f(0.0), dv + arm_rate, dv)
        # an elastic end stop, Eq. (C1) (sam.contact); k_stop = 0: the rigid stop of _advance
        contact = stop_acceleration(x, v, d[D.x_end, j], p[P.k_stop, j], p[P.zeta_stop, j], inv_m_red, f)
        dv = where(p[P.k_stop, j] > f(0.0), dv + contact, dv)
    return (Q_netA * c_A, Q_netB * c_B, dx_s, ddx_s, v, dv, dz), c_A, c_B, G_A, G_B, G_AB


@jit
def rhs(s, u, p, d, ds):
    """Eq. (19) (:func:`rates`): write ds/dt of state ``s`` (7,) under control ``u`` [V] into
    ``ds`` (7,); ``p`` is one parameter vector (len(P),) and ``d`` its :func:`derive`d constants."""
    dy = rates((s[0], s[1], s[2], s[3], s[4], s[5], s[6]), u, _column(p), _column(d), 0)[0]
    for i in range(N_STATES):
        ds[i] = dy[i]


@jit
def _stiff_share(hG, f=np.float64):
    """w = max(0, 1 - 1/hG) of a path whose pressure relaxes at hG per step: the least weight
    of its implicit part that keeps a turbulent path's step monotone (for ``q = k sqrt(dp)``
    the step multiplies dp by 1 - hG / (1 + w hG) >= 0; at w = 1 - 1/hG it lands, 0). It is 0
    up to hG = 1, where forward Euler cannot overshoot, and grows continuously from there."""
    return where(hG > f(1.0), f(1.0) - quot(f(1.0), hG), f(0.0))


@jit
def stiff_pressure_rates(r_A, r_B, h_A, h_B, a, b, g, f=np.float64):
    """The chamber pressure rates [Pa/s] of the semi-implicit step: each path's flow written as
    ``G_i (p_i - p)`` with G_i at the step's start, the weighted share (a, b to the rails of A
    and B, g between them [m^3/(s Pa)]; :func:`_stiff_share`) taken at the step's END, the
    rest explicit: the 2 x 2 linear system

        (1 + h_A (a + g)) dA - h_A g dB = dt r_A
        -h_B g dA + (1 + h_B (b + g)) dB = dt r_B

    (h = dt c [Pa s/m^3]; r_A, r_B the forward-Euler rates) solved for the increments dA, dB,
    returned as rates dA / dt, dB / dt. The path between the chambers moves volume from one to
    the other, so the step conserves what it moves (dA / h_A + dB / h_B is the same as forward
    Euler's but for the rail paths' share): the common pressure still follows the piston's
    displacement flows while the difference lands on its balance. With no stiff path
    (a = b = g = 0) it returns (r_A, r_B) exactly: forward Euler."""
    m_A = f(1.0) + h_A * (a + g)
    m_B = f(1.0) + h_B * (b + g)
    det = m_A * m_B - h_A * h_B * g * g
    return quot(r_A * m_B + h_A * g * r_B, det), quot(r_B * m_A + h_B * g * r_A, det)


@jit
def _stiff_shares(dt, c_A, c_B, G_A, G_B, G_AB, leaks=True, f=np.float64):
    """The stiff share [m^3/(s Pa)] of each path of :func:`rates` at a step of dt [s]: to the rails
    of A and B, and between the chambers (:func:`_stiff_share`); all 0 where no path is stiff."""
    h_A, h_B = dt * c_A, dt * c_B
    g = _stiff_share((h_A + h_B) * G_AB, f) * G_AB if leaks else f(0.0)
    return _stiff_share(h_A * G_A, f) * G_A, _stiff_share(h_B * G_B, f) * G_B, g


@jit_inline
def _advance(y, dy, h, c_A, c_B, G_A, G_B, G_AB, A_A, A_B, x_end, rigid, leaks=True, f=np.float64):
    """Eq. (22)'s update of ``y`` by ``h dy`` (7-tuples), from the rates :func:`rates` returned at
    ``y`` (and the capacitances and conductances with them): the pressures semi-implicit where a
    path is stiff, the end stops (where ``rigid``; an elastic stop acts through :func:`rates`) and
    the cavitation floor applied. Returns (new y, flags).

    ``dy[4]`` is the velocity the piston moves at over the step (``y[5]`` for forward Euler; the
    new velocity for the semi-implicit scheme): the displacement flows of Eqs. (8)-(9), which
    :func:`rates` wrote with ``y[5]``, are corrected to the travel it makes (by 0 where it
    reaches no stop)."""
    p_A, p_B, x_s, dx_s, x, v, z = y
    v_disp = where(rigid, stop_travel_velocity(x, dy[4], h, x_end, f), dy[4])
    r_A = dy[0] + c_A * A_A * (v - v_disp)
    r_B = dy[1] - c_B * A_B * (v - v_disp)
    # the stiff share of each path (0 where forward Euler cannot overshoot: then this is Euler's)
    a, b, g = _stiff_shares(h, c_A, c_B, G_A, G_B, G_AB, leaks, f)
    r_A, r_B = stiff_pressure_rates(r_A, r_B, h * c_A, h * c_B, a, b, g, f)
    p_A, p_B = p_A + h * r_A, p_B + h * r_B
    x, v = x + h * dy[4], v + h * dy[5]
    zero, floor = f(0.0), f(P_CAVITATION)
    cavitates = (p_A < floor) | (p_B < floor)
    on_retracted, on_extended = rigid & (x <= zero), rigid & (x > zero) & (x >= x_end)
    into_stop = (on_retracted & (v < zero)) | (on_extended & (v > zero))
    y = (where(p_A < floor, floor, p_A), where(p_B < floor, floor, p_B), x_s + h * dy[2], dx_s + h * dy[3],
         where(on_retracted, zero, where(on_extended, x_end, x)), where(into_stop, zero, v), z + h * dy[6])
    return y, where(cavitates, np.int64(FLAG_CAVITATION), np.int64(0))


class Scheme(IntEnum):
    """The integration scheme of each sub-step of the step."""

    EULER = 0  #: Eq. (22): forward Euler, the pressures semi-implicit where stiff
    SEMI_IMPLICIT = 1  #: symplectic Euler: v, then x and the displacement flows; dx_s/dt, then x_s
    HEUN = 2  #: explicit trapezoidal rule (2nd order)
    RK4 = 3  #: classical Runge-Kutta (4th order)


#: Scheme names as a scenario or a caller gives them.
SCHEMES = {"euler": Scheme.EULER, "semi_implicit": Scheme.SEMI_IMPLICIT, "heun": Scheme.HEUN, "rk4": Scheme.RK4}
#: Length of the scratch array :func:`step` accepts (kept for its callers; the step needs none).
N_SCRATCH = 6 * N_STATES


@jit_inline
def first_order_step(y, u, p, d, j, h, semi_implicit, leaks=True, effects=True, f=np.float64):
    """One sub-step of h [s] of lane j from ``y``: Eq. (22) (:func:`_advance` of the rates at
    ``y``), or with ``semi_implicit`` symplectic Euler on the model's two oscillators: the
    piston's velocity is advanced first and the position, and the displacement flows of
    Eqs. (8)-(9), move with the new one (the hydraulic spring and the load); the spool's
    velocity first, then its position (Eq. (15)). First order, like forward Euler, but without
    its growth of the undamped modes' energy (|1 + i h omega| > 1). Returns (new y, flags)."""
    dy, c_A, c_B, G_A, G_B, G_AB = rates(y, u, p, d, j, leaks, effects, f)
    moving = (dy[0], dy[1], where(semi_implicit, y[3] + h * dy[3], dy[2]), dy[3],
              where(semi_implicit, y[5] + h * dy[5], dy[4]), dy[5], dy[6])
    return _advance(y, moving, h, c_A, c_B, G_A, G_B, G_AB, d[D.A_A, j], d[D.A_B, j], d[D.x_end, j],
                    _rigid(p, j, effects, f), leaks, f)


@jit_inline
def heun_step(y, u, p, d, j, h, leaks=True, effects=True, f=np.float64):
    """One sub-step of h [s] of lane j from ``y`` by Heun's method (the explicit trapezoidal
    rule); Euler's sub-step instead where :func:`_rough` says so. Returns (new y, flags)."""
    k1, c_A, c_B, G_A, G_B, G_AB = rates(y, u, p, d, j, leaks, effects, f)
    k2 = rates(_along(y, h, k1), u, p, d, j, leaks, effects, f)[0]
    new = _along(y, f(0.5) * h, _sum(k1, k2))
    return _rough(y, new, k1, h, c_A, c_B, G_A, G_B, G_AB, d[D.A_A, j], d[D.A_B, j], d[D.x_end, j],
                  _rigid(p, j, effects, f), leaks, f)


@jit_inline
def rk4_step(y, u, p, d, j, h, leaks=True, effects=True, f=np.float64):
    """One sub-step of h [s] of lane j from ``y`` by the classical Runge-Kutta method; Euler's
    sub-step instead where :func:`_rough` says so. Returns (new y, flags)."""
    k1, c_A, c_B, G_A, G_B, G_AB = rates(y, u, p, d, j, leaks, effects, f)
    k2 = rates(_along(y, f(0.5) * h, k1), u, p, d, j, leaks, effects, f)[0]
    k3 = rates(_along(y, f(0.5) * h, k2), u, p, d, j, leaks, effects, f)[0]
    k4 = rates(_along(y, f(1.0) * h, k3), u, p, d, j, leaks, effects, f)[0]
    new = _along(y, h / f(6.0), _sum(_sum(_sum(k1, _times(f(2.0), k2)), _times(f(2.0), k3)), k4))
    return _rough(y, new, k1, h, c_A, c_B, G_A, G_B, G_AB, d[D.A_A, j], d[D.A_B, j], d[D.x_end, j],
                  _rigid(p, j, effects, f), leaks, f)


@jit_inline
def _rough(y, new, k1, h, c_A, c_B, G_A, G_B, G_AB, A_A, A_B, x_end, rigid, leaks, f):
    """The Runge-Kutta sub-step ``new`` from ``y`` (first stage's rates ``k1``, with the
    capacitances and conductances :func:`rates` returned with them), or forward Euler's where a
    path is stiff at the sub-step, where the sub-step reaches an end stop, or where ``new`` would
    leave the stroke or fall below the cavitation floor: the rails and the stops are where the
    solution is not smooth and a higher order buys nothing. Returns (new y, flags)."""
    euler, flags = _advance(y, k1, h, c_A, c_B, G_A, G_B, G_AB, A_A, A_B, x_end, rigid, leaks, f)
    a, b, g = _stiff_shares(h, c_A, c_B, G_A, G_B, G_AB, leaks, f)
    zero, floor = f(0.0), f(P_CAVITATION)
    rough = ((a > zero) | (b > zero) | (g > zero) | (stop_travel_velocity(y[4], y[5], h, x_end, f) != y[5])
             | (new[0] < floor) | (new[1] < floor) | (new[4] < zero) | (new[4] > x_end))
    return _choose(rough, euler, new), where(rough, flags, np.int64(0))


@jit_inline
def _rigid(p, j, effects, f):
    """Whether lane j's end stops are rigid (k_stop = 0; always without the ``effects`` variant)."""
    return (not effects) or p[P.k_stop, j] == f(0.0)


@jit
def _along(y, h, k):
    """The state ``y + h k`` (7-tuples)."""
    return _sum(y, _times(h, k))


@jit
def _sum(a, b):
    return a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5], a[6] + b[6]


@jit
def _times(c, a):
    return c * a[0], c * a[1], c * a[2], c * a[3], c * a[4], c * a[5], c * a[6]


@jit
def _choose(cond, a, b):
    """The 7-tuple ``a`` where ``cond`` else ``b``."""
    return (where(cond, a[0], b[0]), where(cond, a[1], b[1]), where(cond, a[2], b[2]), where(cond, a[3], b[3]),
            where(cond, a[4], b[4]), where(cond, a[5], b[5]), where(cond, a[6], b[6]))


@jit_inline
def _load(s, j):
    """Lane j of the states s (7, W) as a 7-tuple."""
    return s[0, j], s[1, j], s[2, j], s[3, j], s[4, j], s[5, j], s[6, j]


@jit_inline
def _first_order_lane(s, u, p, d, j, h, flags, semi_implicit, leaks, effects, f):
    """Lane j of a block (states s, inputs u, parameters p, constants d; flags ORed) advanced by
    :func:`first_order_step`, in place."""
    y, fl = first_order_step(_load(s, j), u[j], p, d, j, h, semi_implicit, leaks, effects, f)
    _store(s, j, y, flags, fl)


@jit_inline
def _heun_lane(s, u, p, d, j, h, flags, leaks, effects, f):
    """:func:`_first_order_lane` by :func:`heun_step`."""
    y, fl = heun_step(_load(s, j), u[j], p, d, j, h, leaks, effects, f)
    _store(s, j, y, flags, fl)


@jit_inline
def _rk4_lane(s, u, p, d, j, h, flags, f):
    """:func:`_first_order_lane` by :func:`rk4_step` (its general variant)."""
    y, fl = rk4_step(_load(s, j), u[j], p, d, j, h, True, True, f)
    _store(s, j, y, flags, fl)


@jit_inline
def _store(s, j, y, flags, fl):
    """Lane j's new state ``y`` into s (7, W), its flags ORed into ``flags`` (constant indices: a
    loop over the tuple would index it through memory, which stops the vectoriser)."""
    s[0, j], s[1, j], s[2, j], s[3, j], s[4, j], s[5, j], s[6, j] = y
    flags[j] |= fl


@jit_inline
def _fixed(s, p, d):
    """The arrays of a block (LANES columns) with their shapes as constants (sam.views.fixed)."""
    return views.fixed(s, N_STATES, LANES), views.fixed(p, N_PARAMS, LANES), views.fixed(d, N_DERIVED, LANES)


@jit_inline
def _lanes(n):
    """range(n) as unsigned lane indices: indexing with them has no wrap-around of negative
    indices, a select the vectoriser cannot always see through."""
    return range(np.uint64(n))


# The lane loops: LLVM vectorises each. leaks and effects are constants in each loop (four
# compiled loops per scheme), so its body is straight-line arithmetic without the zeros.
@jit_lanes
def _first_order_lanes(s, u, p, d, h, flags, n, semi_implicit, leaks, effects):
    f = float_type(s)
    s, p, d = _fixed(s, p, d)
    if leaks and effects:
        for j in _lanes(n):
            _first_order_lane(s, u, p, d, j, h, flags, semi_implicit, True, True, f)
    elif leaks:
        for j in _lanes(n):
            _first_order_lane(s, u, p, d, j, h, flags, semi_implicit, True, False, f)
    elif effects:
        for j in _lanes(n):
            _first_order_lane(s, u, p, d, j, h, flags, semi_implicit, False, True, f)
    else:
        for j in _lanes(n):
            _first_order_lane(s, u, p, d, j, h, flags, semi_implicit, False, False, f)


@jit_lanes
def _heun_lanes(s, u, p, d, h, flags, n, leaks, effects):
    f = float_type(s)
    s, p, d = _fixed(s, p, d)
    if leaks and effects:
        for j in _lanes(n):
            _heun_lane(s, u, p, d, j, h, flags, True, True, f)
    elif leaks:
        for j in _lanes(n):
            _heun_lane(s, u, p, d, j, h, flags, True, False, f)
    elif effects:
        for j in _lanes(n):
            _heun_lane(s, u, p, d, j, h, flags, False, True, f)
    else:
        for j in _lanes(n):
            _heun_lane(s, u, p, d, j, h, flags, False, False, f)


@jit_lanes
def _rk4_lanes(s, u, p, d, h, flags, n):
    f = float_type(s)
    s, p, d = _fixed(s, p, d)
    for j in _lanes(n):
        _rk4_lane(s, u, p, d, j, h, flags, f)


@jit
def step_lanes(s, u, p, d, dt, flags, n, substeps=1, scheme=0, leaks=True, effects=True):
    """The model's one step on a block of lanes: advance lanes 0..n-1 of ``s`` (7, W) in place
    over ``dt`` [s] under the held inputs ``u`` (W,) [V], in ``substeps`` sub-steps of the
    :class:`Scheme` ``scheme``; OR each lane's flags into ``flags`` (W,) int64. ``p`` (len(P), W)
    and ``d`` (len(D), W) are the lanes' parameters and :func:`derive`d constants, of the dtype
    of ``s`` (float64, or float32 for the GSA's optional single-precision kernel).

    The arrays have :data:`LANES` columns (those beyond n are left as they are). The defaults are
    Eq. (22) at ``dt``. ``leaks`` and ``effects`` may be False where
    :func:`kernel_variant` says so (then the lanes skip arithmetic that would give zeros; the
    numbers are the same). RK4, the reference scheme, always runs the general variant.
    """
    if s.shape[1] != LANES or p.shape[1] != LANES or d.shape[1] != LANES or not 0 <= n <= LANES:
        raise ValueError("step_lanes: a block's arrays have LANES columns and at most LANES lanes are used")
    f = float_type(s)
    h = f(dt / substeps)
    for _ in range(substeps):
        if scheme == Scheme.EULER or scheme == Scheme.SEMI_IMPLICIT:
            _first_order_lanes(s, u, p, d, h, flags, n, scheme == Scheme.SEMI_IMPLICIT, leaks, effects)
        elif scheme == Scheme.HEUN:
            _heun_lanes(s, u, p, d, h, flags, n, leaks, effects)
        else:
            _rk4_lanes(s, u, p, d, h, flags, n)


@jit
def step(s, u, p, d, dt, ds, substeps=1, scheme=0):
    """The step (:func:`step_lanes`) of one state ``s`` (7,), in place, under ``u`` [V], with the
    parameter vector ``p`` (len(P),) and its :func:`derive`d constants ``d``; ``ds`` is unused
    (kept for callers). The defaults are Eq. (22) at ``dt``. Returns the flags. (A block of
    LANES lanes of which one is used: for a single state; batches go through the lanes.)"""
    block_s, block_u = np.zeros((N_STATES, LANES)), np.full(LANES, u)
    block_p, block_d = np.zeros((N_PARAMS, LANES)), np.zeros((N_DERIVED, LANES))
    block_s[:, 0], block_p[:, 0], block_d[:, 0] = s, p, d
    flags = np.zeros(LANES, dtype=np.int64)
    step_lanes(block_s, block_u, block_p, block_d, dt, flags, 1, substeps, scheme)
    s[:] = block_s[:, 0]
    return flags[0]


@jit
def euler_step(s, u, p, d, dt, ds):
    """Eq. (22): :func:`step` with its defaults, one forward-Euler step of ``dt`` [s] of ``s`` (7,),
    a chamber pressure semi-implicit where it is stiff.

    Stiff chambers: a chamber joined through an open metering edge to the tank or the supply
    with little flow (the piston on an end stop or stalled, the valve open) relaxes onto that
    rail at a rate c G (:func:`rates`) that grows without bound as the edge's pressure drop
    vanishes (the slope of ``sqrt(dp)``). Forward Euler with dt c G > 1 steps across the rail,
    and at 1 ms it settles into a period-2 oscillation around it, of amplitude
    (dt c K_v x_s)^2 / 4: 11 kPa in p_A on the retracted stop at 2.4 V (docs/model.md, "Numerics");
    a leak across the piston at a small pressure difference does the same to the difference. Where
    a path is stiff, the pressures take the linearised backward-Euler step of
    :func:`stiff_pressure_rates`, landing on the rail (or balance); elsewhere forward Euler's.
    Afterwards the state is kept physical:

    * pressures are clamped at the cavitation floor :data:`P_CAVITATION`
      (flagged with :data:`FLAG_CAVITATION`, since Eqs. (8)-(9) no longer hold);
    * the piston stops at its end stops, x in [0, stroke_end(p)], its velocity into the stop
      zeroed (a rigid, inelastic stop; with k_stop > 0 the contact of :mod:`sam.contact` instead); a
      step that reaches a stop compresses the chambers only by the travel to it (:func:`stop_travel_velocity`), so volume is conserved there too.

    Returns the flag word (0 when nothing was clamped but the end stops).
    """
    return step(s, u, p, d, dt, ds)
