"""Valve, leakage and chamber equations, Eqs. (8)-(14) and (41)-(43).

Each function is compiled by numba for scalar arguments: the model kernel calls them per run
and per step, for many runs in one vectorised loop, so they are branch-free (:func:`sam.simd.where`):
a closed edge or an absent leak goes through the same arithmetic and comes out 0. The optional
``f`` argument is the float type of the arithmetic (np.float32 in the GSA's single-precision
kernel). Flows are in m^3/s, positive into the chamber; pressures in Pa (gauge).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .constants import KAPPA_AIR, LEAK_REFERENCE_DP, LPM, P_ATM, P_CAVITATION
from .params import P
from .simd import quot, sqrt, where
from .supply import pump_limited, pump_share

# error_model="numpy": IEEE results (inf, nan) instead of a zero-division check per division
jit = numba.njit(cache=True, error_model="numpy")
# inlined where the kernel calls it: too large for LLVM's inliner, and a call stops the vectoriser
jit_inline = numba.njit(cache=True, inline="always", error_model="numpy")


@jit
def ssqrt(dp):
    """Sign-preserving square root, sgn(dp) sqrt(|dp|): turbulent flow in either direction."""
    return np.copysign(sqrt(abs(dp)), dp)


@jit
def flow_coefficient(Q_N, dp_N):
    """Eq. (12): K_v = Q_N / sqrt(dp_N) [m^3/(s Pa^0.5)]."""
    return Q_N / math.sqrt(dp_N)


@jit
def orifice_flow(K_v, opening, dp, R_supply, Q_sat):
    """Turbulent flow [m^3/s] through one metering edge, the building block of Eqs. (10)-(11).

    ``q = K_v * opening * ssqrt(dp)``, with two optional effects:

    * supply droop: the upstream pressure falls by ``R_supply * q``. Solving
      ``q = k sqrt(dp - R q)`` for q gives ``q = k (sqrt((R k)^2 + 4 dp) - R k) / 2``
      (k = K_v * opening), exact and explicit, which reduces to ``k sqrt(dp)`` at R = 0.
      For notches draining to tank pass ``R_supply = 0``.
    * flow saturation: ``|q| <= Q_sat`` (``inf`` disables it).
    """
    return orifice_flow_conductance(K_v, opening, dp, R_supply, Q_sat)[0]


#: Pa: the chord conductance q / dp of a turbulent path (:func:`orifice_flow_conductance`,
#: :func:`leak_conductance`), infinite at dp = 0, is evaluated at a pressure difference of at
#: least this; a chamber that relaxes onto a rail through such a path then rests within about a
#: quarter of it (0.25 Pa). Measured: at 1e-3 Pa instead, the nuisance study's healthy spread of
#: the offset estimate in motion came out half again as large (0.21 -> 0.31 % extending), and
#: the rule withdrew the offset's votes there (held out, +1 % offsets 91 -> 80 %): a few of its
#: 1408 runs, which sit on a rail, take another course. Nothing physical lies below 1 Pa.
DP_CONDUCTANCE_MIN = 1.0


@jit
def orifice_flow_conductance(K_v, opening, dp, R_supply, Q_sat, f=np.float64):
    """(q, G) of one metering edge of Eqs. (10)-(11): the flow of :func:`orifice_flow` [m^3/s]
    and its chord conductance G = q / dp [m^3/(s Pa)], ``2 k / (sqrt((R k)^2 + 4 |dp|) + R k)``
    (``k / sqrt(|dp|)`` without the droop; ``Q_sat / |dp|`` when saturated), taken at
    |dp| >= DP_CONDUCTANCE_MIN. G is what the semi-implicit pressure step needs
    (:func:`sam.dynamics.rates`). Branch-free: a closed edge (k = 0) gives (0, 0) through the
    same arithmetic; ``f`` is the float type (np.float32 in the GSA's single-precision kernel)."""
    k = K_v * opening
    Rk = R_supply * k
    root = sqrt(Rk * Rk + f(4.0) * abs(dp))
    q = np.copysign(k * f(0.5) * (root - Rk), dp)
    # the chord at the floor: the same square root unless |dp| is below it
    G = f(2.0) * k / (sqrt(Rk * Rk + f(4.0) * max(abs(dp), f(DP_CONDUCTANCE_MIN))) + Rk)
    return saturated(q, G, dp, Q_sat, f)


@jit
def turbulent_flow_conductance(k, dp, f=np.float64):
    """(q, G) of :func:`orifice_flow_conductance` without the droop and the flow limit (R_supply = 0,
    Q_sat = inf), for a path of coefficient k = K_v * opening [m^3/(s Pa^0.5)]: ``q = k ssqrt(dp)``
    and ``G = k / sqrt(max(|dp|, DP_CONDUCTANCE_MIN))``, from one square root. The same numbers
    to the last bit."""
    root = sqrt(f(4.0) * abs(dp))
    return np.copysign(k * f(0.5) * root, dp), quot(f(2.0) * k, max(root, f(_ROOT_MIN)))


_SQRT_DP_MIN = math.sqrt(DP_CONDUCTANCE_MIN)
_ROOT_MIN = math.sqrt(4.0 * DP_CONDUCTANCE_MIN)  # the root of turbulent_flow_conductance at the floor


@jit
def saturated(q, G, dp, Q_sat, f=np.float64):
    """(q, G) of a path held at the flow limit |q| <= Q_sat [m^3/s] (``inf`` disables it)."""
    sat = abs(q) > Q_sat
    return where(sat, np.copysign(Q_sat, q), q), where(sat, Q_sat / max(abs(dp), f(DP_CONDUCTANCE_MIN)), G)


@jit
def edge_openings(x_s, offset, lap, f=np.float64):
    """Openings (fraction of full travel) of the edges P->A/B->T and P->B/A->T.

    Eqs. (10)-(11) open P->A and B->T by ``x_s + offset`` when positive and P->B
    and A->T by ``-(x_s + offset)`` when negative. A lap shifts both edges: an
    overlap (lap > 0) is a deadband; an underlap (lap < 0) opens all four edges
    a little around null. At lap = 0 this is exactly the paper's valve.
    """
    x_o = x_s + offset
    return max(x_o - lap, f(0.0)), max(-x_o - lap, f(0.0))


@jit
def limited_openings(x_s, offset, lap, x_open, f=np.float64):
    """:func:`edge_openings`, each at most ``x_open`` (fraction of travel): the valve's opening
    limit. A notch's area stops growing once the spool has uncovered its whole port, so beyond
    x_open the edge is a fixed orifice whose flow still rises with sqrt(dp) (a flow limit,
    ``Q_sat``, would not). ``x_open = inf`` gives :func:`edge_openings` to the last bit."""
    a_PA_BT, a_PB_AT = edge_openings(x_s, offset, lap, f)
    return min(a_PA_BT, x_open), min(a_PB_AT, x_open)


@jit
def null_leakage(p_chamber, p_S, p_T, K_leak_in, K_leak_out):
    """Eqs. (13)-(14): laminar null leakage [m^3/s] into a chamber, from the supply and out to
    the tank. It flows while the spool is near centre, ``|x_s + offset| < leak_band`` (the paper
    writes ``|x_s|``; with offset = 0 they agree): :func:`valve_flows` applies the band."""
    return K_leak_in * (p_S - p_chamber) - K_leak_out * (p_chamber - p_T)


@jit_inline
def valve_flows(x_s, p_A, p_B, offset, p_S, p_T, K_PA, K_AT, K_PB, K_BT,
                K_leak_PA, K_leak_AT, K_leak_PB, K_leak_BT, leak_band, lap, R_supply, Q_sat, x_open=math.inf,
                Q_pump=math.inf, f=np.float64):
    """Eqs. (10)-(14): (Q_A, Q_B, G_A, G_B), the valve flows [m^3/s] into chambers A and B and,
    per chamber, the sum of the chord conductances q / dp [m^3/(s Pa)] of the valve paths that
    join it to the supply and the tank (the open metering edges, :func:`orifice_flow_conductance`,
    each opened at most ``x_open``: :func:`limited_openings`, and the laminar null leakage,
    :func:`null_leakage`). Every edge is evaluated (an underlapped spool opens all four);
    :func:`valve_flows_ideal` is the same for a valve that opens at most two. The supply edges
    together draw at most the pump's ``Q_pump`` (sam.supply; inf: an ideal source)."""
    a_PA_BT, a_PB_AT = limited_openings(x_s, offset, lap, x_open, f)
    q_PA, g_PA = orifice_flow_conductance(K_PA, a_PA_BT, p_S - p_A, R_supply, Q_sat, f)
    q_AT, g_AT = _tank_edge(K_AT * a_PB_AT, p_A - p_T, Q_sat, f)
    q_PB, g_PB = orifice_flow_conductance(K_PB, a_PB_AT, p_S - p_B, R_supply, Q_sat, f)
    share = pump_share(q_PA, q_PB, Q_pump, f)
    q_PA, g_PA = pump_limited(q_PA, g_PA, share, f)
    q_PB, g_PB = pump_limited(q_PB, g_PB, share, f)
    q_BT, g_BT = _tank_edge(K_BT * a_PA_BT, p_B - p_T, Q_sat, f)
    return _with_null_leakage(q_PA - q_AT, q_PB - q_BT, g_PA + g_AT, g_PB + g_BT, x_s, p_A, p_B, offset, p_S, p_T,
                              K_leak_PA, K_leak_AT, K_leak_PB, K_leak_BT, leak_band)


@jit
def _tank_edge(k, dp, Q_sat, f):
    """(q, G) of an edge draining to the tank: no supply droop on it."""
    q, G = turbulent_flow_conductance(k, dp, f)
    return saturated(q, G, dp, Q_sat, f)


@jit
def valve_flows_ideal(x_s, p_A, p_B, offset, p_S, p_T, K_PA, K_AT, K_PB, K_BT,
                      K_leak_PA, K_leak_AT, K_leak_PB, K_leak_BT, leak_band, lap, f=np.float64):
    """:func:`valve_flows` of a valve without underlap, supply droop, flow or opening limit (lap >= 0,
    R_supply = 0, Q_sat = inf, x_open = inf; the paper's valve): at most one pair of edges is open, so
    the pair is chosen first, by the sign of the opening, and two square roots serve where four would.
    The same numbers to the last bit."""
    a_PA_BT, a_PB_AT = edge_openings(x_s, offset, lap, f)
    extend = a_PA_BT > f(0.0)  # P->A and B->T open (else P->B and A->T, or none)
    q_s, g_s = turbulent_flow_conductance(where(extend, K_PA * a_PA_BT, K_PB * a_PB_AT),
                                          where(extend, p_S - p_A, p_S - p_B), f)
    q_t, g_t = turbulent_flow_conductance(where(extend, K_BT * a_PA_BT, K_AT * a_PB_AT),
                                          where(extend, p_B - p_T, p_A - p_T), f)
    zero = f(0.0)  # the closed edges' flow, subtracted as valve_flows does
    return _with_null_leakage(where(extend, q_s, zero - q_t), where(extend, zero - q_t, q_s),
                              where(extend, g_s, g_t), where(extend, g_t, g_s), x_s, p_A, p_B, offset, p_S, p_T,
                              K_leak_PA, K_leak_AT, K_leak_PB, K_leak_BT, leak_band)


@jit
def _with_null_leakage(Q_A, Q_B, G_A, G_B, x_s, p_A, p_B, offset, p_S, p_T,
                       K_leak_PA, K_leak_AT, K_leak_PB, K_leak_BT, leak_band):
    """The metering edges' (Q_A, Q_B, G_A, G_B) plus the null leakage while the spool is in its band."""
    band = abs(x_s + offset) < leak_band
    return (where(band, Q_A + null_leakage(p_A, p_S, p_T, K_leak_PA, K_leak_AT), Q_A),
            where(band, Q_B + null_leakage(p_B, p_S, p_T, K_leak_PB, K_leak_BT), Q_B),
            where(band, G_A + (K_leak_PA + K_leak_AT), G_A), where(band, G_B + (K_leak_PB + K_leak_BT), G_B))


@jit
def leak_conductance(q, dp, K, f=np.float64):
    """Chord conductance q / dp [m^3/(s Pa)] of a turbulent leak ``q = K ssqrt(dp)`` (Eqs. (41)-(43))
    that passes ``q`` at ``dp``: from the flow already computed, a division and no square root;
    below |dp| = DP_CONDUCTANCE_MIN the chord there, ``K / sqrt(DP_CONDUCTANCE_MIN)``; 0 without
    the leak."""
    G = where(abs(dp) < f(DP_CONDUCTANCE_MIN), quot(K, f(_SQRT_DP_MIN)), quot(abs(q), abs(dp)))
    return where(K == f(0.0), f(0.0), G)


@jit
def supply_flow(x_s, p_A, p_B, offset, p_S, K_PA, K_PB, lap, R_supply, Q_sat, x_open=math.inf, Q_pump=math.inf):
    """Flow drawn from the supply through P->A and P->B [m^3/s] (for the droop of p_S), at most the
    pump's Q_pump (sam.supply)."""
    a_PA_BT, a_PB_AT = limited_openings(x_s, offset, lap, x_open)
    q_PA = orifice_flow(K_PA, a_PA_BT, p_S - p_A, R_supply, Q_sat)
    q_PB = orifice_flow(K_PB, a_PB_AT, p_S - p_B, R_supply, Q_sat)
    share = pump_share(q_PA, q_PB, Q_pump)
    return pump_limited(q_PA, 0.0, share)[0] + pump_limited(q_PB, 0.0, share)[0]


@jit
def fault_leakages(p_A, p_B, p_T, K_int, K_extA, K_extB):
    """Eqs. (41)-(43): turbulent fault leakages [m^3/s].

    Returns (Q_int from A to B, Q_extA out of A, Q_extB out of B). The paper
    assumes p_T = 0 and positive pressure differences; the sign-preserving
    square root keeps the flows defined (and reversing) when p_A < p_B or a
    pressure is at or below tank pressure. A leak of K = 0 is 0.
    """
    return K_int * ssqrt(p_A - p_B), K_extA * ssqrt(p_A - p_T), K_extB * ssqrt(p_B - p_T)


@jit
def fault_leakages_batch(p_A, p_B, p_T, K_int, K_extA, K_extB):
    """Eqs. (41)-(43) of :func:`fault_leakages` over recordings: pressures p_A, p_B (B, T) [Pa],
    tank pressure p_T (B,) [Pa] and leak coefficients K_* (B, T) [m^3/(s Pa^0.5)] (a fault that
    changes in time); returns (3, B, T) [m^3/s]: Q_int from A to B, Q_extA, Q_extB."""
    B, T = p_A.shape
    out = np.empty((3, B, T))
    for b in range(B):
        for k in range(T):
            out[0, b, k], out[1, b, k], out[2, b, k] = fault_leakages(
                p_A[b, k], p_B[b, k], p_T[b], K_int[b, k], K_extA[b, k], K_extB[b, k])
    return out


@jit
def effective_bulk_modulus(p, B_eff, air_fraction, f=np.float64):
    """Bulk modulus [Pa] of oil with entrained free air, at gauge pressure p [Pa].

    ``1/B = 1/B_eff + eps(p) / (kappa p_abs)``, with the free-air fraction
    ``eps(p) = air_fraction (p_atm / p_abs)^(1/kappa)`` compressed polytropically.
    At air_fraction = 0 it is the paper's constant B_eff. The stiffness falls
    steeply at low pressure: the hallmark of entrained air.
    """
    p_abs = max(p + f(P_ATM), f(P_CAVITATION + P_ATM))
    eps = air_fraction * (f(P_ATM) / p_abs) ** f(1.0 / KAPPA_AIR)
    B = f(1.0) / (f(1.0) / B_eff + eps / (f(KAPPA_AIR) * p_abs))
    return where(air_fraction == f(0.0), B_eff, B)


@jit
def inverse_capacitance(V, p, B_eff, air_fraction, C_hose, f=np.float64, air=True):
    """Eqs. (8)-(9): dp/dt per unit net inflow [Pa/m^3] of a chamber of volume V [m^3] at
    pressure p [Pa], ``1 / (V/B + C_hose)``: its bulk modulus over its volume, plus an
    optional hose compliance C_hose [m^3/Pa]. ``dp/dt = Q_net / (V/B + C_hose)``, where
    ``Q_net`` includes the piston's displacement flow. ``air=False`` promises air_fraction = 0
    (the kernel's batches without the effect: no powers to compute)."""
    B = effective_bulk_modulus(p, B_eff, air_fraction, f) if air else B_eff
    return quot(B, V + C_hose * B)  # = 1 / (V/B + C_hose), with one division


def supply_flow_array(x_s, p_A, p_B, p, pump=True):
    """:func:`supply_flow` over trajectories (n,), for one parameter vector ``p``; ``pump=False``:
    the flow the valve would draw from the relief's pressure without the pump limit."""
    K_PA = flow_coefficient(p[P.Q_N_PA], p[P.dp_N_PA])
    K_PB = flow_coefficient(p[P.Q_N_PB], p[P.dp_N_PB])
    return _supply_flow_loop(x_s, p_A, p_B, p[P.offset], p[P.p_S], K_PA, K_PB, p[P.lap], p[P.R_supply], p[P.Q_sat],
                             p[P.x_open], p[P.Q_pump] if pump else math.inf)


@jit
def _supply_flow_loop(x_s, p_A, p_B, offset, p_S, K_PA, K_PB, lap, R_supply, Q_sat, x_open, Q_pump):
    out = np.empty(x_s.shape[0])
    for k in range(x_s.shape[0]):
        out[k] = supply_flow(x_s[k], p_A[k], p_B[k], offset, p_S, K_PA, K_PB, lap, R_supply, Q_sat, x_open, Q_pump)
    return out


def leak_coefficient(lpm):
    """K [m^3/(s Pa^0.5)] of a turbulent leak (Eqs. (41)-(43)) passing ``lpm`` L/min at 10 MPa.

    Table 5's upper bound: 1 L/min at 10 MPa is K = 5.27e-9.
    """
    return lpm * LPM / math.sqrt(LEAK_REFERENCE_DP)


def leak_lpm(K):
    """The flow [L/min] of a turbulent leak coefficient K [m^3/(s Pa^0.5)] at 10 MPa."""
    return K * math.sqrt(LEAK_REFERENCE_DP) / LPM
