"""The model's state, right-hand side (Eq. (19)) and its one step, :func:`step`: Eq. (22)'s forward
Euler by default (semi-implicit where a chamber pressure is stiff, :func:`euler_step`), or
sub-steps of a higher-order scheme (:class:`Scheme`).

This module is the one place where the physics is assembled. The batch
simulator, the global sensitivity analysis and the Unscented Kalman Filter all
advance the model through :func:`step`; nothing else writes an equation.

State vector, Eq. (18), indexed by :data:`S`::

    [p_A, p_B, x_s, dx_s/dt, x, v, z]
     Pa   Pa   1    1/s      m  m/s m

Parameters are the flat vector of :mod:`sam.params`, indexed by :data:`P`.
"""

from __future__ import annotations

from enum import IntEnum

import numba
import numpy as np

from . import views
from .constants import P_CAVITATION
from .friction import bristle_damping, bristle_rate, lugre_force, seal_loaded, stribeck
from .geometry import (
    cos_joint_angle, load_torque_cs, quarter_turn_cos_sin, stroke_end, torque_arm_cs, torque_arm_slope_cs,
    total_inertia,
)
from .hydraulics import fault_leakages, flow_coefficient, inverse_capacitance, leak_conductance, valve_flows
from .params import P

# error_model="numpy": IEEE results (inf, nan) instead of a zero-division check per division
jit = numba.njit(cache=True, error_model="numpy")
# The per-step functions are inlined into their callers' loops: a numba call that
# passes arrays costs reference-count traffic that doubled the time of a step.
jit_inline = numba.njit(cache=True, inline="always", error_model="numpy")


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

#: Bits of the flag word returned by :func:`euler_step`.
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
#: Their columns of a parameter vector, in the order of P: the geometry's, and the others'.
GEOMETRY_COLS = np.array(sorted(int(P[name]) for name in GEOMETRY_INPUTS), dtype=np.int64)
MACHINE_COLS = np.array(sorted(int(P[name]) for name in DERIVE_INPUTS - GEOMETRY_INPUTS), dtype=np.int64)


@jit
def areas(D_piston, D_rod):
    """Piston and annulus areas (A_A, A_B) [m^2] from the diameters (Appendix 2)."""
    A_A = np.pi * D_piston**2 / 4.0
    return A_A, A_A - np.pi * D_rod**2 / 4.0


def stroke_ends(params) -> np.ndarray:
    """m, (...,): the extension end stop (:func:`stroke_end`) of every parameter row of
    ``params`` (..., len(P)); the retraction stop is x = 0. :func:`euler_step` clamps there."""
    p = np.asarray(params, dtype=float)
    return stroke_end(p[..., P.x_max], p[..., P.theta_max], p[..., P.L_1], p[..., P.L_2], p[..., P.L_3])


@jit
def derive(p, d):
    """Fill ``d`` (len(D),) with the constants of parameter vector ``p``.

    They hold for a whole run (or until a parameter they depend on changes), so
    the square roots and trigonometry here are not repeated at every step.
    """
    derive_geometry(p, d)
    derive_machine(p, d)


@jit_inline
def derive_geometry(p, d):
    """The constants of :func:`derive` that depend on GEOMETRY_INPUTS only: cos and sin of the
    boom's conventions (theta_level, cog_angle) and the extension end stop."""
    d[D.cos_level], d[D.sin_level] = quarter_turn_cos_sin(p[P.theta_level])
    d[D.cos_cog], d[D.sin_cog] = quarter_turn_cos_sin(p[P.cog_angle])
    d[D.x_end] = stroke_end(p[P.x_max], p[P.theta_max], p[P.L_1], p[P.L_2], p[P.L_3])


@jit_inline
def derive_machine(p, d):
    """The other constants of :func:`derive`: the notches' flow coefficients (Eq. (12)), the
    areas, the inertia (Eq. (16)) and the bristle damping."""
    d[D.K_PA] = flow_coefficient(p[P.Q_N_PA], p[P.dp_N_PA])
    d[D.K_AT] = flow_coefficient(p[P.Q_N_AT], p[P.dp_N_AT])
    d[D.K_PB] = flow_coefficient(p[P.Q_N_PB], p[P.dp_N_PB])
    d[D.K_BT] = flow_coefficient(p[P.Q_N_BT], p[P.dp_N_BT])
    d[D.A_A], d[D.A_B] = areas(p[P.D_piston], p[P.D_rod])
    J_tot = total_inertia(p[P.m_B], p[P.L_B], p[P.m_L], p[P.m_R], p[P.L])
    d[D.inv_J_tot] = 1.0 / J_tot
    # sigma_1 = 2 sqrt(sigma_0 J_tot / r^2) = bristle_damping(sigma_0, J_tot) / r
    d[D.sigma_1_r] = bristle_damping(p[P.sigma_0], J_tot)


@jit_inline
def rhs(s, u, p, d, ds):
    """Eq. (19): write ds/dt of state ``s`` (7,) under control ``u`` [V] into ``ds`` (7,).

    ``p`` is one parameter vector (len(P),) and ``d`` its :func:`derive`d
    constants. Friction is LuGre (Eq. (17)); the load force is Eq. (21) plus the
    disturbance force F_d; leak faults are Eqs. (41)-(43); the optional effects
    of :class:`sam.params.Effects` enter through the hydraulics and friction
    functions; Eq. (7)'s R-dot term where the plant's ``[equations]`` keep it.
    """
    rates(s, u, p, d, ds)


@jit_inline
def rates(s, u, p, d, ds):
    """Eq. (19) as :func:`rhs` writes it into ``ds``, and returns what the semi-implicit pressure
    step needs (:func:`stiff_pressure_rates`): (c_A, c_B) [Pa/m^3], each chamber's inverse
    capacitance d(dp/dt)/dQ (Eqs. (8)-(9)); (G_A, G_B) [m^3/(s Pa)], the sum of the chord
    conductances q / dp of its paths to the supply and the tank (the open metering edges, the
    null leakage, the external leak); and G_AB, that of the paths between the chambers (the
    internal leak, the bypass)."""
    p_A, p_B, x_s, dx_s, x, v, z = s[0], s[1], s[2], s[3], s[4], s[5], s[6]
    A_A, A_B = d[D.A_A], d[D.A_B]

    # Hydraulics, Eqs. (8)-(14), (41)-(43)
    Q_A, Q_B, G_A, G_B = valve_flows(
        x_s, p_A, p_B, p[P.offset], p[P.p_S], p[P.p_T],
        d[D.K_PA], d[D.K_AT], d[D.K_PB], d[D.K_BT],
        p[P.K_leak_PA], p[P.K_leak_AT], p[P.K_leak_PB], p[P.K_leak_BT], p[P.leak_band],
        p[P.lap], p[P.R_supply], p[P.Q_sat],
    )
    p_T, K_int, K_extA, K_extB = p[P.p_T], p[P.K_int], p[P.K_extA], p[P.K_extB]
    Q_int, Q_extA, Q_extB = fault_leakages(p_A, p_B, p_T, K_int, K_extA, K_extB)
    Q_bypass = p[P.K_bypass] * (p_A - p_B)
    Q_netA = Q_A - Q_int - Q_extA - Q_bypass + p[P.Q_dA] - A_A * v
    Q_netB = Q_B + Q_int - Q_extB + Q_bypass + p[P.Q_dB] + A_B * v
    G_A += leak_conductance(Q_extA, p_A - p_T, K_extA)
    G_B += leak_conductance(Q_extB, p_B - p_T, K_extB)
    G_AB = leak_conductance(Q_int, p_A - p_B, K_int) + p[P.K_bypass]  # the paths between the chambers
    B_eff, air, C_hose = p[P.B_eff], p[P.air_fraction], p[P.C_hose]
    c_A = inverse_capacitance(p[P.V_0A] + A_A * x, p_A, B_eff, air, C_hose)
    c_B = inverse_capacitance(p[P.V_0B] + A_B * (p[P.x_max] - x), p_B, B_eff, air, C_hose)
    ds[0] = Q_netA * c_A  # Eqs. (8)-(9)
    ds[1] = Q_netB * c_B

    # Spool, Eq. (15), with the dimensionally consistent K omega_n^2 u
    w = p[P.omega_n]
    ds[2] = dx_s
    ds[3] = p[P.K_u] * w * w * u - 2.0 * w * p[P.zeta] * dx_s - w * w * x_s

    # Boom seen at the piston, Eqs. (5), (16), (20), (21)
    cos_theta = cos_joint_angle(x, p[P.L_1], p[P.L_2], p[P.L_3])
    sin_theta = np.sqrt(1.0 - cos_theta * cos_theta)
    r = torque_arm_cs(x, sin_theta, p[P.L_1], p[P.L_2], p[P.L_3])
    inv_r = 1.0 / r  # divisions are the step's dearest operations: one here serves three
    inv_m_red = r * r * d[D.inv_J_tot]  # 1 / m_reduced, Eq. (20)
    tau = load_torque_cs(
        cos_theta, sin_theta, d[D.cos_level], d[D.sin_level], d[D.cos_cog], d[D.sin_cog],
        p[P.m_B], p[P.r_B], p[P.m_L], p[P.m_R], p[P.L],
    )
    F_ext = tau * inv_r + p[P.F_d]

    # LuGre friction, Eq. (17)
    g = stribeck(
        v,
        seal_loaded(p[P.F_C], p_A, p_B, p[P.k_fric_p]),
        seal_loaded(p[P.F_S], p_A, p_B, p[P.k_fric_p]),
        p[P.v_s],
    )
    dz = bristle_rate(v, z, g, p[P.sigma_0])
    F_mu = lugre_force(v, z, dz, p[P.sigma_0], d[D.sigma_1_r] * inv_r, p[P.b])

    ds[4] = v
    ds[5] = (p_A * A_A - p_B * A_B - F_mu - F_ext) * inv_m_red
    if p[P.arm_rate_torque] != 0.0:
        # Eq. (7)'s R-dot term, which Eq. (19) neglects: v = r omega, so dv/dt = r omega' + r'(theta) omega^2
        ds[5] += torque_arm_slope_cs(x, cos_theta, r, p[P.L_1], p[P.L_2], p[P.L_3]) * v * v * inv_r * inv_r
    ds[6] = dz
    return c_A, c_B, G_A, G_B, G_AB


@jit_inline
def stop_travel_velocity(x, v, dt, x_end):
    """The mean velocity [m/s] of a step of dt [s] from x [m] at v [m/s] that an end stop cuts
    short: the travel to the stop over dt, 0 from on (or beyond) it, v where the step does not
    reach it. The displacement flows A v of Eqs. (8)-(9) must use it, not v: the stop is rigid
    and inelastic, so a chamber is compressed only by the distance the piston really moves."""
    if v < 0.0 and x + dt * v < 0.0:
        return -max(x, 0.0) / dt
    if v > 0.0 and x + dt * v > x_end:
        return max(x_end - x, 0.0) / dt
    return v


@jit_inline
def _stiff_share(hG):
    """w = max(0, 1 - 1/hG) of a path whose pressure relaxes at hG per step: the least weight
    of its implicit part that keeps a turbulent path's step monotone (for ``q = k sqrt(dp)``
    the step multiplies dp by 1 - hG / (1 + w hG) >= 0; at w = 1 - 1/hG it lands, 0). It is 0
    up to hG = 1, where forward Euler cannot overshoot, and grows continuously from there."""
    return 1.0 - 1.0 / hG if hG > 1.0 else 0.0


@jit_inline
def stiff_pressure_rates(r_A, r_B, h_A, h_B, a, b, g):
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
    displacement flows while the difference lands on its balance."""
    m_A = 1.0 + h_A * (a + g)
    m_B = 1.0 + h_B * (b + g)
    det = m_A * m_B - h_A * h_B * g * g
    return (r_A * m_B + h_A * g * r_B) / det, (r_B * m_A + h_B * g * r_A) / det


@jit_inline
def euler_step(s, u, p, d, dt, ds):
    """Eq. (22): advance state ``s`` (7,) in place by one forward-Euler step of ``dt`` [s], a
    chamber pressure semi-implicit where it is stiff.

    ``p`` is the parameter vector, ``d`` its :func:`derive`d constants and
    ``ds`` (7,) scratch space.

    Stiff chambers: a chamber joined through an open metering edge to the tank or the supply
    with little flow (the piston on an end stop or stalled, the valve open) relaxes onto that
    rail at a rate c G (:func:`rates`) that grows without bound as the edge's pressure drop
    vanishes (the slope of ``sqrt(dp)``). Forward Euler with dt c G > 1 steps across the rail,
    and at 1 ms it settles into a period-2 oscillation around it, of amplitude
    (dt c K_v x_s)^2 / 4: 11 kPa in p_A on the retracted stop at 2.4 V (docs/model.md,
    "Numerics"). A path between the chambers (a leak across the piston at a small pressure
    difference) does the same to their difference. Where a path is stiff, the pressures take
    the linearised backward-Euler step of :func:`stiff_pressure_rates`, which lands on the rail
    (or the difference on its balance) instead of crossing it; elsewhere the step
    is forward Euler's, unchanged. Afterwards the state is kept physical:

    * pressures are clamped at the cavitation floor :data:`P_CAVITATION`
      (flagged with :data:`FLAG_CAVITATION`, since Eqs. (8)-(9) no longer hold);
    * the piston stops at its end stops, x in [0, stroke_end(p)], where the
      velocity into the stop is zeroed (an inelastic stop); a step that reaches a stop
      compresses the chambers only by the travel to it (:func:`stop_travel_velocity`), so
      volume is conserved there too.

    Returns the flag word (0 when nothing was clamped but the end stops).
    """
    c_A, c_B, G_A, G_B, G_AB = rates(s, u, p, d, ds)
    return _advance(s, d, dt, ds, c_A, c_B, G_A, G_B, G_AB)


@jit_inline
def _stiff_shares(dt, c_A, c_B, G_A, G_B, G_AB):
    """The stiff share [m^3/(s Pa)] of each path of :func:`rates` at a step of dt [s]: to the rails
    of A and B, and between the chambers (:func:`_stiff_share`); all 0 where no path is stiff."""
    h_A, h_B = dt * c_A, dt * c_B
    return (_stiff_share(h_A * G_A) * G_A, _stiff_share(h_B * G_B) * G_B,
            _stiff_share((h_A + h_B) * G_AB) * G_AB)


@jit_inline
def _advance(s, d, dt, ds, c_A, c_B, G_A, G_B, G_AB):
    """The update of :func:`euler_step` from the rates ``ds`` (7,) that :func:`rates` wrote at
    ``s`` (and the capacitances and conductances it returned): ``s += dt ds``, the pressures
    semi-implicit where a path is stiff, the end stops and the cavitation floor applied.

    ``ds[4]`` is the velocity the piston moves at over the step (``s[5]`` for forward Euler; the
    new velocity for the semi-implicit scheme of :func:`step`): the displacement flows of
    Eqs. (8)-(9), which :func:`rates` wrote with ``s[5]``, are corrected to the travel it makes."""
    # a step that reaches an end stop displaces oil only over the travel to it
    v_disp = stop_travel_velocity(s[4], ds[4], dt, d[D.x_end])
    if v_disp != s[5]:
        ds[0] += c_A * d[D.A_A] * (s[5] - v_disp)
        ds[1] -= c_B * d[D.A_B] * (s[5] - v_disp)
    # the stiff share of each path (0 where forward Euler cannot overshoot: the common case)
    a, b, g = _stiff_shares(dt, c_A, c_B, G_A, G_B, G_AB)
    if a > 0.0 or b > 0.0 or g > 0.0:
        ds[0], ds[1] = stiff_pressure_rates(ds[0], ds[1], dt * c_A, dt * c_B, a, b, g)
    for j in range(N_STATES):
        s[j] += dt * ds[j]
    flags = 0
    if s[0] < P_CAVITATION:
        s[0] = P_CAVITATION
        flags |= FLAG_CAVITATION
    if s[1] < P_CAVITATION:
        s[1] = P_CAVITATION
        flags |= FLAG_CAVITATION
    if s[4] <= 0.0:
        s[4] = 0.0
        if s[5] < 0.0:
            s[5] = 0.0
    elif s[4] >= d[D.x_end]:
        s[4] = d[D.x_end]
        if s[5] > 0.0:
            s[5] = 0.0
    return flags


class Scheme(IntEnum):
    """The integration scheme of each sub-step of :func:`step`."""

    EULER = 0  #: Eq. (22): forward Euler, the pressures semi-implicit where stiff
    SEMI_IMPLICIT = 1  #: symplectic Euler: v, then x and the displacement flows; dx_s/dt, then x_s
    HEUN = 2  #: explicit trapezoidal rule (2nd order)
    RK4 = 3  #: classical Runge-Kutta (4th order)


#: Scheme names as a scenario or a caller gives them.
SCHEMES = {"euler": Scheme.EULER, "semi_implicit": Scheme.SEMI_IMPLICIT, "heun": Scheme.HEUN, "rk4": Scheme.RK4}
#: Length of the scratch array :func:`step` needs: rates, the start state and the stage rates.
N_SCRATCH = 6 * N_STATES


@jit_inline
def step(s, u, p, d, dt, ds, substeps=1, scheme=0):
    """The model's one step: advance ``s`` (7,) in place over ``dt`` [s] under the held input
    ``u`` [V] in ``substeps`` sub-steps of the :class:`Scheme` ``scheme``. The defaults are
    Eq. (22) at ``dt``: exactly :func:`euler_step`, bit for bit.

    ``ds`` is scratch space: (7,) for forward Euler, (:data:`N_SCRATCH`,) for the others (numba
    does not check bounds: a shorter one is the caller's error).
    Every sub-step keeps the end stops, the cavitation floor and the stiff chambers of
    :func:`euler_step`: the Runge-Kutta schemes take a forward-Euler sub-step instead where a
    path is stiff at the sub-step, where the sub-step reaches an end stop, or where their result
    would leave the stroke or fall below the cavitation floor (the rails and the stops are where
    the solution is not smooth and a higher order buys nothing). Returns the OR of the flags.
    """
    h = dt / substeps
    flags = 0
    for _ in range(substeps):
        if scheme == Scheme.EULER:
            flags |= euler_step(s, u, p, d, h, ds)
        elif scheme == Scheme.SEMI_IMPLICIT:
            flags |= _semi_implicit_step(s, u, p, d, h, ds)
        else:
            flags |= _runge_kutta_step(s, u, p, d, h, ds, scheme == Scheme.RK4)
    return flags


@jit_inline
def _semi_implicit_step(s, u, p, d, h, ds):
    """Symplectic Euler on the model's two oscillators: the piston's velocity is advanced first
    and the position, and the displacement flows of Eqs. (8)-(9), move with the new one (the
    hydraulic spring and the load); the spool's velocity first, then its position (Eq. (15)).
    Pressures, friction and the stiff chambers as in :func:`euler_step`. First order, like
    forward Euler, but without its growth of the undamped modes' energy (|1 + i h omega| > 1)."""
    c_A, c_B, G_A, G_B, G_AB = rates(s, u, p, d, ds)
    ds[4] = s[5] + h * ds[5]
    ds[2] = s[3] + h * ds[3]
    return _advance(s, d, h, ds, c_A, c_B, G_A, G_B, G_AB)


@jit_inline
def _runge_kutta_step(s, u, p, d, h, w, fourth):
    """One sub-step of h [s] of RK4 (``fourth``) or Heun's method, in place on ``s`` (7,), with
    ``w`` (N_SCRATCH,) as scratch: w[0:7] the first stage's rates, w[7:14] the start state,
    w[14:21] the stage state, w[21:42] the later stages' rates. Falls back to
    :func:`euler_step`'s update from the first stage (see :func:`step`)."""
    n = N_STATES
    c_A, c_B, G_A, G_B, G_AB = rates(s, u, p, d, w)
    a, b, g = _stiff_shares(h, c_A, c_B, G_A, G_B, G_AB)
    if a > 0.0 or b > 0.0 or g > 0.0 or stop_travel_velocity(s[4], s[5], h, d[D.x_end]) != s[5]:
        return _advance(s, d, h, w, c_A, c_B, G_A, G_B, G_AB)
    for j in range(n):
        w[n + j] = s[j]  # the start state
    k = w[3 * n:]  # k[0:n], k[n:2n], k[2n:3n]: the rates of stages 2, 3, 4
    if fourth:
        for stage, frac in ((0, 0.5), (1, 0.5), (2, 1.0)):
            prev = w[0:n] if stage == 0 else k[(stage - 1) * n:stage * n]
            for j in range(n):
                w[2 * n + j] = w[n + j] + frac * h * prev[j]
            rates(w[2 * n:3 * n], u, p, d, k[stage * n:(stage + 1) * n])
        for j in range(n):
            s[j] = w[n + j] + h / 6.0 * (w[j] + 2.0 * k[j] + 2.0 * k[n + j] + k[2 * n + j])
    else:
        for j in range(n):
            w[2 * n + j] = w[n + j] + h * w[j]
        rates(w[2 * n:3 * n], u, p, d, k[0:n])
        for j in range(n):
            s[j] = w[n + j] + 0.5 * h * (w[j] + k[j])
    if s[0] < P_CAVITATION or s[1] < P_CAVITATION or s[4] < 0.0 or s[4] > d[D.x_end]:
        for j in range(n):  # back to the start: the forward-Euler update from the first stage
            s[j] = w[n + j]
        return _advance(s, d, h, w, c_A, c_B, G_A, G_B, G_AB)
    return 0


@jit
def step_batch(states, u, params, dt, substeps=1, scheme=0):
    """Advance a batch of states one model step (:func:`step`): the filter's process model.

    states (n, 7), u (n,) [V], params (n, len(P)) -> new states (n, 7), flags (n,).
    ``substeps`` and ``scheme`` (a :class:`Scheme`) as in :func:`step`; the defaults are
    Eq. (22) at ``dt``. The input arrays are not modified.
    """
    out = states.copy()
    flags = np.zeros(states.shape[0], dtype=np.int64)
    step_batch_inplace(out, u, params, dt, flags, substeps, scheme)
    return out, flags


@jit
def step_batch_inplace(states, u, params, dt, flags, substeps=1, scheme=0):
    """:func:`step_batch` in place: states (n, 7) C-contiguous, advanced; flags (n,) written.
    For the filter, which steps a few dozen sigma points per sample and reuses one array."""
    params = np.ascontiguousarray(params)  # the array itself when it is C-contiguous
    ds_owner, d_owner = np.empty(N_SCRATCH), np.empty(N_DERIVED)
    # borrowed views (sam.views): no reference counting per row, half the time of a step
    ds, d = views.whole(ds_owner), views.whole(d_owner)
    for i in range(states.shape[0]):
        p = views.row(params, i)
        # derive() is 40 % of a step (trigonometry, square roots, divisions). The sigma points of
        # a filter differ in parameters it does not read (faults, load force) or, for calibration
        # states, in a few it does, never in the geometry: derive again only what changed.
        if i == 0 or not _same(params, i, GEOMETRY_COLS):
            derive_geometry(p, d)
        if i == 0 or not _same(params, i, MACHINE_COLS):
            derive_machine(p, d)
        flags[i] = step(views.row(states, i), u[i], p, d, dt, ds, substeps, scheme)


@jit_inline
def _same(params, i, cols):
    """Row i of params (n, len(P)) equals row i - 1 in the columns cols."""
    for c in cols:
        if params[i, c] != params[i - 1, c]:
            return False
    return True
