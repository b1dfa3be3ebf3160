"""What the machine can do: its hydraulic natural frequency over the stroke (the paper's Fig. 4)
and the loads it can lift.

Both come from the one model. The natural frequency is the hydraulic mode of the Jacobian of
:func:`sam.dynamics.rhs` with the valve centred and the load held at rest; the lift check is the
piston's force balance at rest (Eq. (19) with v = 0) along the stroke, confirmed by a simulated
run at full opening.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dynamics import N_DERIVED, S, areas, derive, rhs, stroke_ends
from .geometry import external_force
from .params import P, Plant
from .simulate import initial_state, simulate_batch

#: State indices of the hydraulic-mechanical block (p_A, p_B, x, v, z): the spool's states are
#: driven by the input only (no flow forces), so its modes separate from these exactly.
_MODE_STATES = np.array([S.p_A, S.p_B, S.x, S.v, S.z])
#: Scale of each state (Eq. (18): Pa, Pa, 1, 1/s, m, m/s, m) for the central differences of
#: :func:`jacobian`: a state at zero is stepped by 1e-6 of it.
_STEP_SCALE = np.array([1e5, 1e5, 1e-3, 1e-1, 1e-3, 1e-3, 1e-6])


def load_force(params: np.ndarray, x) -> np.ndarray:
    """Eq. (21): F_ext [N] at piston position(s) x [m] of one parameter vector (len(P),)."""
    p = params
    return external_force(np.asarray(x, dtype=float), p[P.L_1], p[P.L_2], p[P.L_3], p[P.theta_level],
                          p[P.cog_angle], p[P.m_B], p[P.r_B], p[P.m_L], p[P.m_R], p[P.L])


def held_state(params: np.ndarray, x: float) -> np.ndarray:
    """(7,) the state at rest at x [m] with the valve centred: p_B where its null leakages
    balance, p_A carrying the load (``p_A A_A = p_B A_B + F_ext``, on the stop as well)."""
    s = initial_state(params, max(x, 1e-12))  # x > 0: chamber A holds the load
    s[S.x] = x
    return s


def jacobian(params: np.ndarray, state: np.ndarray, u: float = 0.0) -> np.ndarray:
    """(7, 7) d(ds/dt)/ds of Eq. (19) at ``state`` under input u [V], by central differences."""
    d = np.empty(N_DERIVED)
    derive(params, d)
    ds = np.empty(7)
    J = np.empty((7, 7))
    for j in range(7):
        h = 1e-6 * max(abs(state[j]), _STEP_SCALE[j])
        cols = []
        for sign in (1.0, -1.0):
            s = state.copy()
            s[j] += sign * h
            rhs(s, u, params, d, ds)
            cols.append(ds.copy())
        J[:, j] = (cols[0] - cols[1]) / (2 * h)
    return J


def natural_frequency(params: np.ndarray, x: float) -> float:
    """Hz: the hydraulic natural frequency |lambda| / 2 pi at piston position x [m], lambda the
    complex eigenvalue of the linearised model with the valve centred and the load held at rest
    (the oil columns of both chambers against the reduced mass, Eq. (20), with the seal's
    bristle stiffness; no end stop). NaN if that mode is overdamped."""
    J = jacobian(params, held_state(params, x))
    ev = np.linalg.eigvals(J[np.ix_(_MODE_STATES, _MODE_STATES)])
    ev = ev[np.abs(ev.imag) > 1e-6 * np.abs(ev)]
    return float(np.abs(ev[0]) / (2 * np.pi)) if ev.size else float("nan")


def natural_frequency_over_stroke(params: np.ndarray, n: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """(x [m], f [Hz]), each (n,): :func:`natural_frequency` from the retracted end to the
    extension end stop (the paper's Fig. 4)."""
    x = np.linspace(0.0, float(stroke_ends(params)), n)
    return x, np.array([natural_frequency(params, xi) for xi in x])


def lift_pressure(params: np.ndarray, x, *, breakaway: bool) -> np.ndarray:
    """Pa: the piston-side pressure that moves the load up at piston position(s) x [m] from rest,
    with the rod side drained to tank: ``(F_ext + F_friction + p_T A_B) / A_A``, the friction the
    static F_S to break away and the Coulomb F_C once sliding (Eq. (17), slow: no viscous part)."""
    A_A, A_B = areas(params[P.D_piston], params[P.D_rod])
    friction = params[P.F_S] if breakaway else params[P.F_C]
    return (load_force(params, x) + friction + params[P.p_T] * A_B) / A_A


@dataclass(frozen=True)
class Lift:
    """Whether one load is lifted from ``x_from`` through the stroke (:func:`lift_check`)."""

    m_L: float  #: kg, the load
    x_from: float  #: m, where it starts at rest
    pressure_needed: float  #: Pa, the largest :func:`lift_pressure` from x_from to the end stop
    lifts: bool  #: the supply can provide it everywhere
    stalls_at: float  #: m, the first position where it cannot (NaN if it lifts)
    travel: float  #: m, how far a simulated run at full opening moved the load up
    reached_end: bool  #: that run reached the extension end stop


def max_liftable_mass(plant: Plant, x_from: float, n: int = 400) -> float:
    """kg: the largest m_L the supply lifts from rest at x_from [m] to the end stop (inf if the
    load never opposes extension there). F_ext is linear in m_L, so this is the smallest of
    (supply force - friction - the rest of F_ext) / (F_ext per kg) over the stroke."""
    p = plant.vector()
    x = np.linspace(x_from, float(stroke_ends(p)), n)
    A_A, _ = areas(p[P.D_piston], p[P.D_rod])
    p0, p1 = p.copy(), p.copy()
    p0[P.m_L], p1[P.m_L] = 0.0, 1.0
    per_kg = load_force(p1, x) - load_force(p0, x)
    spare = p[P.p_S] * A_A - A_A * np.where(x == x_from, lift_pressure(p0, x, breakaway=True),
                                             lift_pressure(p0, x, breakaway=False))
    limit = np.where(per_kg > 0, spare / np.where(per_kg > 0, per_kg, 1.0), np.inf)
    return float(max(np.min(limit), 0.0))


def lift_check(plant: Plant, masses, x_from: float = 0.05, *, u_V: float = 10.0, duration_s: float = 5.0,
               dt: float = 1e-3, n: int = 400) -> tuple[Lift, ...]:
    """Which loads m_L [kg] the plant lifts from rest at x_from [m]: the static check along the
    stroke (:func:`lift_pressure` against the supply pressure), and a simulated run of
    duration_s at u_V (from :func:`sam.initial_state` at x_from) for how far it actually went."""
    base = plant.vector()
    params = np.tile(base, (len(masses), 1))
    params[:, P.m_L] = masses
    x_end = float(stroke_ends(base))
    x = np.linspace(x_from, x_end, n)
    res = simulate_batch(params, np.full(int(round(duration_s / dt)), u_V), dt,
                         x0=initial_state(params, x_from), channels=("x",))
    out = []
    for row, m, x_final in zip(params, masses, res["x"][:, -1]):
        need = np.where(x == x_from, lift_pressure(row, x, breakaway=True), lift_pressure(row, x, breakaway=False))
        short = np.flatnonzero(need > row[P.p_S])
        out.append(Lift(float(m), x_from, float(need.max()), short.size == 0,
                        float(x[short[0]]) if short.size else float("nan"),
                        float(x_final - x_from), bool(x_final >= x_end - 1e-3)))
    return tuple(out)
