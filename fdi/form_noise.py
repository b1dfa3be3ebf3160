"""Process noise on the chamber pressures where the model's form is known to be uncertain.

The filter's pressure states walk with the model's flow error (``PROCESS_NOISE["p_A"]``), the
same everywhere. In two places a real machine departs from the form of Eqs. (8)-(14) by far
more, and the filter is told so there (:class:`fdi.config.FormNoise`), so that what the model
cannot predict is not read as a fault:

* **the null-leakage band's edge.** Eqs. (13)-(14) let the laminar null leakage flow while
  |x_s + offset| < leak_band and stop it in one step at the edge. A real valve's leakage fades
  over a width nobody measured, and a position loop holding a load parks the spool exactly there
  (inside the band the null leakage drains the loaded chamber, outside it the metering edge
  fills it: the step is the loop's equilibrium). There each of the chamber's two null-leakage
  paths may or may not flow: its flow is uncertain by s_c, the root sum of squares of the two
  paths' flows at the measured pressure. The spool position is the input through Eq. (15),
  which the filter integrates too (at rest x_s = K_u u, and a loop's u is logged).
* **near cavitation.** Below ``low_pressure`` a chamber's oil releases air and vapour, its
  bulk modulus falls by orders of magnitude and its pressure stops following the displacement
  flow until the cavity is filled again; Eqs. (8)-(9) with a constant B_eff and a clamp at the
  vapour pressure draw neither. There the pressure rate is uncertain by the displacement flow's
  whole effect, s_c = A_c |v|, with v the measured position's rate over ``velocity_window_s``.
* **at the transmitter's floor.** A reading at the bottom of a transmitter's range is missing to
  the filter (``InputChecks.floor_band_Pa``): the chamber may be cavitating, and then a void of
  unknown size absorbs the flow through it (valve inflow and displacement) until it is filled,
  while Eqs. (8)-(9) raise the pressure at once. Over a run of missing readings that began after
  a reading below ``low_pressure``, that flow could build S_c = share int (Q_in + A_c |v|)
  B_eff / V_c dt (at most p_S - p_T), Q_in the supply's flow into the chamber at tank pressure
  through Eqs. (10)-(12) at the spool position; the pressure's variance is widened by S_c^2 once,
  where the reading comes back (a bias of the whole run, not a walk).
* **at an end stop.** Within ``stop_margin_m`` of a stop the piston may be in contact: a real
  stop gives and rebounds, the model's stops the piston dead (an inelastic stop), so the
  displacement flow is uncertain by its whole size, s_c = A_c |v| (v measured, as above), where
  the piston is driven into the stop: moving toward it, or with the valve driving it there (a
  rebound runs against the valve). A piston that leaves a stop under its valve's drive leaves a
  contact that stored next to nothing: the model's stop is exact for it.

Each pressure term but the floor's adds the variance of the pressure its flow error builds in
one sample of dt,

    q_extra^2 = (share s_c B_eff / V_c dt)^2       [Pa^2 per sample],

V_c the chamber's volume at the measured position (Eqs. (8)-(9)); the kernel's process-noise gates
carry it as a factor 1 + q_extra^2 / (q^2 dt) on the state's own variance (:func:`form_gates`).
This makes the model honest where it is known to be uncertain; it assumes no fade shape and no
air law.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.signal import cont2discrete, lfilter, lfilter_zi

from sam import D, P, derive
from sam.dynamics import N_DERIVED, areas, stroke_ends
from sam.geometry import piston_position

from .states import POS_X


def spool_positions(u: np.ndarray, params: np.ndarray, dt: float) -> np.ndarray:
    """(B, T) spool position x_s [1, fraction of travel] of inputs ``u`` (B, T) [V] through Eq.
    (15), x_s'' = K_u w^2 u - 2 zeta w x_s' - w^2 x_s, discretised exactly for an input held
    over each sample of ``dt`` [s], from rest at the first input (x_s = K_u u[0])."""
    u = np.nan_to_num(np.asarray(u, dtype=float))
    xs = np.empty_like(u)
    spool = params[:, [P.K_u, P.omega_n, P.zeta]]
    for key in np.unique(spool, axis=0):
        rows = np.flatnonzero((spool == key).all(axis=1))
        b, a, zi = spool_filter(*map(float, key), float(dt))
        xs[rows], _ = lfilter(b, a, u[rows], axis=-1, zi=zi[None, :] * u[rows, :1])
    return xs


@functools.lru_cache(maxsize=64)
def spool_filter(K: float, w: float, zeta: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(b, a, zi) of Eq. (15) with gain K [1/V], natural frequency w [rad/s] and damping zeta,
    discretised exactly for an input held over each sample of ``dt`` [s], and its filter state at
    rest under a unit input. Cached: every filter run of a plant needs the same one, and scipy's
    matrix exponential (with the BLAS threads it wakes) cost a bank's short runs more than the filtering."""
    b, a, _ = cont2discrete(([K * w * w], [1.0, 2.0 * zeta * w, w * w]), dt, method="zoh")
    b = np.ravel(b)
    out = (b, a, lfilter_zi(b, a))
    for x in out:
        x.setflags(write=False)
    return out


def near_band_edge(x_s: np.ndarray, params: np.ndarray, margin: float) -> np.ndarray:
    """(B, T) bool: |x_s + offset| within ``margin`` x leak_band of the band's edge leak_band
    (Eqs. (13)-(14); offset and leak_band of each run's plant vector params (B, len(P)))."""
    band = params[:, P.leak_band][:, None]
    return np.abs(np.abs(x_s + params[:, P.offset][:, None]) - band) <= margin * band


def null_flow_spread(pA: np.ndarray, pB: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s_A, s_B) (B, T) [m^3/s]: the root sum of squares of the two laminar null-leakage paths
    of Eqs. (13)-(14) into and out of chambers A and B at pressures pA, pB (B, T) [Pa] (supply and
    tank of the plant vectors params (B, len(P))): at the edge each path's leakage may or may not
    flow (the one closing there depends on the side), independently."""
    p = lambda name: params[:, P[name]][:, None]  # noqa: E731
    pS, pT = p("p_S"), p("p_T")
    return (np.hypot(p("K_leak_PA") * (pS - pA), p("K_leak_AT") * (pA - pT)),
            np.hypot(p("K_leak_PB") * (pS - pB), p("K_leak_BT") * (pB - pT)))


def chamber_capacitances(x: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B_eff / V_A, B_eff / V_B) (B, T) [Pa/m^3] at piston positions x (B, T) [m] (Eqs. (8)-(9)'s
    volumes); mid-stroke where x is missing."""
    p = lambda name: params[:, P[name]][:, None]  # noqa: E731
    x = np.clip(np.where(np.isfinite(x), x, 0.5 * p("x_max")), 0.0, p("x_max"))
    A_A, A_B = areas(p("D_piston"), p("D_rod"))
    return p("B_eff") / (p("V_0A") + A_A * x), p("B_eff") / (p("V_0B") + A_B * (p("x_max") - x))


def measured_rates(x: np.ndarray, dt: float, window_s: float) -> np.ndarray:
    """(B, T) piston rate [m/s] of positions x (B, T) [m]: the causal difference over
    ``window_s`` (one sample at least; 0 where a reading is missing and before the window fills)."""
    w = max(1, int(round(window_s / dt)))
    v = np.zeros_like(x)
    v[:, w:] = (x[:, w:] - x[:, :-w]) / (w * dt)
    return np.nan_to_num(v)


def at_floor(p: np.ndarray, low: float) -> np.ndarray:
    """(B, T) bool: readings p (B, T) [Pa] missing after a finite reading below ``low`` [Pa],
    through the whole run of missing samples (causal: the last reading before it decides)."""
    T = p.shape[1]
    k = np.where(np.isfinite(p), np.arange(T)[None, :], -1)
    last = np.maximum.accumulate(k, axis=1)
    before = np.take_along_axis(p, np.maximum(last, 0), axis=1)
    with np.errstate(invalid="ignore"):
        return ~np.isfinite(p) & (last >= 0) & (before < low)


def supply_inflows(x_s: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Q_A, Q_B) (B, T) [m^3/s]: the supply's flow into chambers A and B at tank pressure through
    the metering edges P->A and P->B of Eqs. (10)-(12), K_v (x_s + offset) sqrt(p_S - p_T), at spool
    positions x_s (B, T) [1] (0 through an edge that is closed)."""
    derived = np.empty((len(params), N_DERIVED))
    for row, d in zip(params, derived):
        derive(row, d)  # the notches' K_v of Eq. (12), as the model's step has them
    opening = x_s + params[:, P.offset, None]
    head = np.sqrt(np.maximum(params[:, P.p_S] - params[:, P.p_T], 0.0))[:, None]
    return (derived[:, D.K_PA, None] * np.maximum(opening, 0.0) * head,
            derived[:, D.K_PB, None] * np.maximum(-opening, 0.0) * head)


def floor_variance(floor: np.ndarray, rate: np.ndarray, cap: np.ndarray, dt: float) -> np.ndarray:
    """(B, T) [Pa^2]: at the first sample after each run of ``floor`` (B, T) bool, the square of
    the pressure ``rate`` (B, T) [Pa/s] builds over that run, dt times its sum, at most ``cap`` (B, 1)
    [Pa]; 0 elsewhere. Added there, not spread over the run: while the reading is missing the
    model's step clamps the sigma points at the vapour pressure, which would undo a walk."""
    r = np.where(floor, np.nan_to_num(rate), 0.0) * dt
    c = np.cumsum(r, axis=1)
    start = floor & ~np.concatenate([np.zeros_like(floor[:, :1]), floor[:, :-1]], axis=1)
    base = np.maximum.accumulate(np.where(start, c - r, 0.0), axis=1)  # the sum before each run
    back = np.zeros_like(floor)
    back[:, 1:] = floor[:, :-1] & ~floor[:, 1:]
    built = np.concatenate([np.zeros_like(c[:, :1]), (c - base)[:, :-1]], axis=1)  # the run's sum, one sample on
    return np.where(back, np.minimum(built, cap) ** 2, 0.0)


def form_gates(inp, noise, q_pA: float, q_pB: float) -> np.ndarray:
    """(B, T, 2) factors on the random walk of p_A and p_B (std ``q_pA``, ``q_pB`` [Pa/sqrt(s)])
    of the runs of ``inp`` (:class:`fdi.filter.FilterInput`) for the settings ``noise``
    (:class:`fdi.config.FormNoise`): 1 + q_extra^2 / (q^2 dt) (module docstring, the two terms'
    variances added), 1 where neither applies, where a reading is missing, and for a state
    without a random walk (nothing to scale)."""
    B, T = inp.u.shape
    gates = np.ones((B, T, 2))
    p = lambda name: inp.params[:, P[name]][:, None]  # noqa: E731
    x = inp.pos if inp.pos_kind == POS_X else piston_position(inp.pos, p("L_1"), p("L_2"), p("L_3"))
    caps = chamber_capacitances(x, inp.params)
    var = [np.zeros((B, T)), np.zeros((B, T))]  # (Pa/s)^2 of each chamber's pressure rate
    if noise.band_share > 0.0:
        edge = near_band_edge(spool_positions(inp.u, inp.params, inp.dt), inp.params, noise.band_margin)
        for c, flow in enumerate(null_flow_spread(inp.pA, inp.pB, inp.params)):
            var[c] += np.where(edge, (noise.band_share * flow * caps[c]) ** 2, 0.0)
    rate = measured_rates(x, inp.dt, noise.velocity_window_s)
    speed = np.abs(rate)
    chamber_areas = areas(p("D_piston"), p("D_rod"))
    if noise.low_share > 0.0:
        for c, (pc, area) in enumerate(zip((inp.pA, inp.pB), chamber_areas)):
            with np.errstate(invalid="ignore"):
                low = pc < noise.low_pressure
            var[c] += np.where(low, (noise.low_share * area * speed * caps[c]) ** 2, 0.0)
    if noise.stop_share > 0.0:
        x_end = stroke_ends(inp.params)[:, None]
        with np.errstate(invalid="ignore"):  # driven into a stop: arriving, or thrown back against the valve
            near = (((x <= noise.stop_margin_m) & ((rate < 0.0) | (inp.u < 0.0)))
                    | ((x >= x_end - noise.stop_margin_m) & ((rate > 0.0) | (inp.u > 0.0))))
        for c, area in enumerate(chamber_areas):
            var[c] += np.where(near, (noise.stop_share * area * speed * caps[c]) ** 2, 0.0)
    if noise.floor_share > 0.0:
        inflow = supply_inflows(spool_positions(inp.u, inp.params, inp.dt), inp.params)
        for c, (pc, area) in enumerate(zip((inp.pA, inp.pB), chamber_areas)):
            build = noise.floor_share * (inflow[c] + area * speed) * caps[c]  # Pa/s
            extra = floor_variance(at_floor(pc, noise.low_pressure), build, p("p_S") - p("p_T"), inp.dt)
            var[c] += extra / (inp.dt * inp.dt)
    for c, q in enumerate((q_pA, q_pB)):
        if q > 0.0:
            gates[:, :, c] = 1.0 + np.nan_to_num(var[c]) * inp.dt / (q * q)
    return gates
