"""The rig's valve, leaks and chambers, Eqs. (8)-(14) and (41)-(43), written over the oil each
chamber holds.

A chamber's state is the oil in it, counted as its volume at atmospheric pressure (its mass over
the oil's density there). The pressure is whatever squeezes that oil, with its free air, into the
chamber and its hoses: :func:`chamber_pressure` solves ``oil s(p) = V(p)``, where
``s(p) = exp(-p/B) + air (p_atm / p_abs)^(1/kappa)`` is the volume per unit of oil and
``V(p) = V_0 + A x + V_hose (1 + p / E_hose)`` the room. A flow Q into the chamber, counted at the
chamber's pressure, adds ``Q / s(p)`` of oil. Without air and hoses this is Eq. (8) exactly
(``dp/dt = B / V (Q - dV/dt)``), written another way: the two implementations check each other.
Below the vapour pressure the oil no longer fills the chamber, and the pressure stays there
while a void opens (cavitation), instead of falling further.

Flows are m^3/s, positive into a chamber; pressures Pa, gauge. Scalar functions compiled by numba.
"""

from __future__ import annotations

import math

import numba

from .layout import KAPPA, P_ATM, P_VAPOUR, C

jit = numba.njit(cache=True, error_model="numpy")

#: Newton on chamber_pressure stops below this change [Pa] (or after NEWTON_MAX steps).
NEWTON_TOL_PA = 1e-6
NEWTON_MAX = 50


@jit
def orifice(k, dp, dp_laminar):
    """A metering edge or leak path of Eqs. (10)-(11), (41)-(43): ``k sgn(dp) sqrt|dp|`` [m^3/s] far
    above ``dp_laminar`` [Pa], laminar ``k dp / sqrt(dp_laminar)`` far below it, as the flow through a
    small opening is once its jet no longer forms: ``k dp / (dp^2 + dp_laminar^2)^(1/4)``."""
    if k == 0.0:
        return 0.0
    return k * dp / math.sqrt(math.sqrt(dp * dp + dp_laminar * dp_laminar))


@jit
def metering_area(travel, lap, knee, exponent):
    """Open fraction [1] of an edge when the spool has travelled ``travel`` towards opening it: zero
    within its overlap ``lap`` (an underlap, lap < 0, opens it before centre), then the travel past
    it; a progressive notch grows as ``knee (a / knee)^exponent`` below its knee."""
    a = min(travel - lap, 1.0)
    if a <= 0.0:
        return 0.0
    if a < knee:
        return knee * (a / knee) ** exponent
    return a


@jit
def in_series(k_edge, k_port):
    """The coefficient [m^3/(s Pa^0.5)] of a metering edge ``k_edge`` in series with a fixed port
    restriction ``k_port`` (inf: none): two orifices share the pressure drop, so
    1 / k^2 = 1 / k_edge^2 + 1 / k_port^2, and the flow saturates at k_port sqrt(dp) as the edge opens."""
    if k_port == math.inf or k_edge == 0.0:
        return k_edge
    return k_edge * k_port / math.sqrt(k_edge * k_edge + k_port * k_port)


@jit
def valve_flows(x_s, p_A, p_B, p_S, c):
    """Eqs. (10)-(14): (Q_A, Q_B, Q_P) [m^3/s], the valve's flows into chambers A and B and the flow
    it draws from the supply line at p_S, at spool position x_s plus the offset."""
    x_o = x_s + c[C.offset]
    knee, expo, dp_l, p_T = c[C.notch_knee], c[C.notch_exponent], c[C.dp_laminar], c[C.p_T]
    port, full = c[C.port], c[C.full_area]  # the area stops growing once the notch uncovers its whole port
    q_PA = orifice(in_series(c[C.K_PA] * min(metering_area(x_o, c[C.lap_PA], knee, expo), full), port), p_S - p_A, dp_l)
    q_BT = orifice(in_series(c[C.K_BT] * min(metering_area(x_o, c[C.lap_BT], knee, expo), full), port), p_B - p_T, dp_l)
    q_PB = orifice(in_series(c[C.K_PB] * min(metering_area(-x_o, c[C.lap_PB], knee, expo), full), port), p_S - p_B, dp_l)
    q_AT = orifice(in_series(c[C.K_AT] * min(metering_area(-x_o, c[C.lap_AT], knee, expo), full), port), p_A - p_T, dp_l)
    Q_A, Q_B, Q_P = q_PA - q_AT, q_PB - q_BT, q_PA + q_PB
    lands = land_leakage_share(x_o, c[C.leak_band], c[C.leak_taper])
    if lands > 0.0:  # Eqs. (13)-(14): laminar leakage of the lands near centre
        l_PA, l_PB = lands * c[C.KL_PA] * (p_S - p_A), lands * c[C.KL_PB] * (p_S - p_B)
        Q_A += l_PA - lands * c[C.KL_AT] * (p_A - p_T)
        Q_B += l_PB - lands * c[C.KL_BT] * (p_B - p_T)
        Q_P += l_PA + l_PB
    return Q_A, Q_B, Q_P


@jit
def land_leakage_share(x_o, band, taper):
    """Share [1] of Eqs. (13)-(14)'s null leakage at the spool's position x_o from centre: all of
    it within the band |x_o| < band, fading to none over its outer ``taper`` fraction (the paper's
    box has a step there, which an integrator resolves to first order only)."""
    inside = band - abs(x_o)
    if inside <= 0.0:
        return 0.0
    edge = taper * band
    return 1.0 if inside >= edge else inside / edge


@jit
def leak_flows(p_A, p_B, c):
    """Eqs. (41)-(43) and the laminar bypass: (Q_AB across the piston, Q_extA, Q_extB to ambient)
    [m^3/s]. The external leaks go to the atmosphere (0 Pa gauge), as the paper's do."""
    dp_l = c[C.dp_laminar]
    Q_AB = orifice(c[C.K_int], p_A - p_B, dp_l) + c[C.bypass] * (p_A - p_B)
    return Q_AB, orifice(c[C.K_extA], p_A, dp_l), orifice(c[C.K_extB], p_B, dp_l)


@jit
def specific_volume(p, air, B):
    """(s, ds/dp): volume [1] of a unit of oil (atmospheric volume) with its free air ``air`` at
    gauge pressure p [Pa], and its slope [1/Pa]."""
    oil = math.exp(-p / B)
    if air == 0.0:
        return oil, -oil / B
    p_abs = p + P_ATM
    gas = air * (P_ATM / p_abs) ** (1.0 / KAPPA)
    return oil + gas, -oil / B - gas / (KAPPA * p_abs)


@jit
def chamber_pressure(oil, V, air, hose, hose_modulus, B):
    """Gauge pressure [Pa] of ``oil`` [m^3] with free air ``air`` in a chamber of volume V [m^3] and a
    hose of volume ``hose`` [m^3] that swells as ``hose (1 + p / hose_modulus)``: the root of
    ``oil s(p) = V + hose (1 + p / hose_modulus)``; the vapour pressure where the oil no longer
    fills the room. Closed form without air and hose swelling (``p = B ln(oil / V)``); Newton's
    method, monotone on this convex equation, otherwise."""
    room = V + hose
    p = max(B * math.log(oil / room), P_VAPOUR)  # the root without air and swelling
    compliance = hose / hose_modulus
    if air == 0.0 and compliance == 0.0:
        return p
    s, ds = specific_volume(P_VAPOUR, air, B)
    if oil * s <= room + compliance * P_VAPOUR:
        return P_VAPOUR
    for _ in range(NEWTON_MAX):
        s, ds = specific_volume(p, air, B)
        step = (oil * s - room - compliance * p) / (oil * ds - compliance)
        p = max(p - step, P_VAPOUR)
        if abs(step) < NEWTON_TOL_PA:
            break
    return p


@jit
def oil_for_pressure(p, V, air, hose, hose_modulus, B):
    """The oil [m^3] that holds a chamber of volume V at pressure p: the inverse of
    :func:`chamber_pressure`."""
    return (V + hose * (1.0 + p / hose_modulus)) / specific_volume(p, air, B)[0]


@jit
def free_air_equilibrium(p, c):
    """Free air [1] per unit oil in equilibrium at gauge pressure p [Pa]: all of ``air_content`` at
    atmospheric pressure, less as more dissolves, none above ``air_dissolved`` (Henry's law,
    linearised)."""
    return c[C.air_content] * min(max(1.0 - p / c[C.air_dissolved], 0.0), 1.0)


@jit
def supply_line_flow(p_S, draw, c):
    """Net flow [m^3/s] into the supply line at p_S [Pa]: the fixed pump, less what the relief valve
    passes (linear from cracking to full pump flow at the plant's p_S), less the valve's ``draw``."""
    relief = c[C.relief_gain] * max(p_S - c[C.relief_crack], 0.0)
    return c[C.pump] - relief - draw
