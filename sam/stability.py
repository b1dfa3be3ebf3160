"""Is a time step stable for a plant, and did a run diverge?

The model advances by one explicit step (Eq. (22), :func:`sam.dynamics.euler_step`).
Near a state s the step is the map s -> s + J (s' - s); a disturbance grows from
step to step when the spectral radius of J exceeds 1. :func:`step_growth` measures
that radius on the step itself (central differences through
:func:`sam.row_step.step_batch`), so the semi-implicit pressure treatment is
accounted for exactly as the simulator runs it. For the paper's plant the
radius is 1 (the position integrates) up to dt = 15.9 ms, where the spool's
second-order mode (omega_n = 126 rad/s, zeta = 1: 2 zeta / omega_n) goes
unstable; the batch simulator agrees (a 20 ms run leaves the finite range).

:func:`diverged` catches what the linearisation cannot promise: a run that left
the physics anyway (a stiff user plant, a load far outside the studied range).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dynamics import N_STATES, S, stroke_ends
from .row_step import step_batch
from .hydraulics import flow_coefficient
from .params import P
from .simulate import initial_state

#: growth per step above which a step is unstable: 1 is the position's integrator (marginal)
#: and the finite differences agree with the exact radius to ~1e-9; a growth of 1 + 1e-6 per
#: step is a factor 1.004 over a 4000-step run, below anything a figure shows
STABLE_GROWTH = 1.0 + 1e-6
#: size of the central-difference perturbation of each state, in its unit (Pa, 1, 1/s, m, m/s, m):
#: far above rounding, far below the nonlinearities' scales
_PERTURB = np.array([1e3, 1e3, 1e-6, 1e-4, 1e-7, 1e-6, 1e-9])
#: a run is diverged when a chamber pressure exceeds this many times the supply pressure, or its
#: speed this many times the fully open valve's flow through the rod-side area: an overrunning
#: load intensifies the supply pressure by the area ratio (about 2), ten times is no physics
DIVERGED_FACTOR = 10.0


@dataclass(frozen=True)
class Growth:
    """The largest growth per step of a disturbance and where it was found."""

    growth: float  #: spectral radius of the step's Jacobian (1: marginal)
    u: float  #: V, the control signal of that operating point
    row: int  #: which parameter row of the ones given


def step_growth(params: np.ndarray, dt: float, u_values) -> Growth:
    """The largest spectral radius of the step's Jacobian over parameter rows ``params`` (n, len(P))
    and control signals ``u_values`` [V], each at mid-stroke with the valve settled at K u."""
    params = np.atleast_2d(np.asarray(params, dtype=float))
    worst = Growth(0.0, 0.0, 0)
    for row, p in enumerate(params):
        x_mid = 0.5 * float(stroke_ends(p))
        for u in u_values:
            s0 = initial_state(p, x_mid)
            s0[S.x_s] = p[P.K_u] * u
            states = np.repeat(s0[None, :], 2 * N_STATES, axis=0)
            for j in range(N_STATES):
                states[2 * j, j] += _PERTURB[j]
                states[2 * j + 1, j] -= _PERTURB[j]
            out, _ = step_batch(states, np.full(len(states), float(u)), np.repeat(p[None, :], len(states), 0), dt)
            J = (out[0::2] - out[1::2]).T / (2 * _PERTURB)
            growth = float(np.max(np.abs(np.linalg.eigvals(J))))
            if not np.isfinite(growth):
                growth = np.inf
            if growth > worst.growth:
                worst = Growth(growth, float(u), row)
    return worst


def largest_stable_step(params: np.ndarray, u_values, dt_hi: float) -> float:
    """The largest step [s] below ``dt_hi`` (an unstable one) that :func:`step_growth` finds stable,
    by bisection to 1 % (growth rises with the step for every mode of this model)."""
    lo, hi = 0.0, dt_hi
    while hi - lo > 0.01 * hi:
        mid = 0.5 * (lo + hi)
        if step_growth(params, mid, u_values).growth <= STABLE_GROWTH:
            lo = mid
        else:
            hi = mid
    return lo


def diverged(states: dict[str, np.ndarray], params: np.ndarray) -> tuple[int, str] | None:
    """(first sample index, what) of the first sign that a run left the physics, or None.

    ``states``: recorded state name -> (n,) values of one run (``p_A``, ``p_B``, ``v`` used);
    ``params``: its parameter vector."""
    p = np.asarray(params, dtype=float)
    p_limit = DIVERGED_FACTOR * p[P.p_S]
    k_valve = max(flow_coefficient(p[P.Q_N_PA], p[P.dp_N_PA]), flow_coefficient(p[P.Q_N_PB], p[P.dp_N_PB]))
    A_B = 0.25 * np.pi * (p[P.D_piston] ** 2 - p[P.D_rod] ** 2)
    v_limit = DIVERGED_FACTOR * k_valve * np.sqrt(p[P.p_S] - p[P.p_T]) / A_B
    pressure = (p_limit, f"above {DIVERGED_FACTOR:g} x the supply pressure")
    limits = {"p_A": pressure, "p_B": pressure,
              "v": (v_limit, f"faster than {DIVERGED_FACTOR:g} x the fully open valve's flow can drive it")}
    first = None
    for name, (limit, words) in limits.items():
        if name not in states:
            continue
        values = np.asarray(states[name])
        hit = ~(np.abs(values) <= limit)  # NaN and inf count as hits
        if hit.any():
            k = int(np.argmax(hit))
            what = f"{name} = {values[k]:.3g} ({words if np.isfinite(values[k]) else 'not finite'})"
            if first is None or k < first[0]:
                first = (k, what)
    return first
