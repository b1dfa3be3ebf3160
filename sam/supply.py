"""A pump-limited supply: a fixed-displacement pump behind a relief valve (docs/model.md, "Pump and
relief valve").

The pump delivers Q_pump; the relief valve cracks at p_S - R_supply Q_pump and passes the full pump
flow at p_S, linearly in between (its override). While the valve draws q <= Q_pump the relief takes
the rest and the supply pressure at the valve is ``p_S - R_supply q`` (the linear droop that
:func:`sam.hydraulics.orifice_flow_conductance` already solves); once the valve would draw more, the
relief is shut and the supply pressure falls to whatever makes the valve pass exactly Q_pump. The
supply line's oil volume is neglected: the supply pressure is the static balance at every instant.
``Q_pump = inf`` is the ideal source of the paper, to the last bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .simd import where

# error_model="numpy": IEEE results (inf, nan) instead of a zero-division check per division
jit = numba.njit(cache=True, error_model="numpy")


@jit
def pump_share(q_PA, q_PB, Q_pump, f=np.float64):
    """The factor [1] on the flows the supply edges P->A and P->B draw (m^3/s, positive out of the
    supply) that keeps their sum at most the pump's delivery Q_pump [m^3/s]: 1 while the relief is
    open (the sum below Q_pump), Q_pump / sum once it shuts. Exact for one open supply edge (the valve
    with lap >= 0): the edge passes Q_pump; with both open (an underlap, near null) it shares the pump
    flow in the ratio of their unlimited flows."""
    drawn = max(q_PA, f(0.0)) + max(q_PB, f(0.0))
    return where(drawn > Q_pump, Q_pump / drawn, f(1.0))


@jit
def pump_limited(q, G, share, f=np.float64):
    """(q, G) of a supply edge [m^3/s, m^3/(s Pa)] after :func:`pump_share`: a drawing edge scaled by
    it (flow and chord conductance alike), a back-flowing one left as it is."""
    draws = q > f(0.0)
    return where(draws, q * share, q), where(draws, G * share, G)


@jit
def supply_pressure(q_open, p_S, R_supply, Q_pump, k, p_load):
    """The supply pressure at the valve [Pa] of a pump-limited supply, the valve drawing q_open [m^3/s]
    at the relief's pressure (the flow it would draw without the pump limit): ``p_S - R_supply q_open``
    while q_open <= Q_pump (the relief open); else the pressure at which the open supply edge,
    ``q = k sqrt(p - p_load)`` (k [m^3/(s Pa^0.5)], the edge's K_v times its opening; p_load [Pa], the
    chamber it feeds), passes Q_pump: ``p_load + (Q_pump / k)^2``."""
    if q_open <= Q_pump or k <= 0.0:
        return p_S - R_supply * q_open
    return p_load + (Q_pump / k) ** 2


def relief_cracking_pressure(p_S: float, R_supply: float, Q_pump: float) -> float:
    """Pa: the pressure at which the relief valve starts to open, p_S - R_supply Q_pump (it passes the
    whole pump flow at p_S); p_S for an ideal relief (R_supply = 0) or an ideal source."""
    return p_S if math.isinf(Q_pump) else p_S - R_supply * Q_pump
