"""The one step over rows of states: the process model of the filter, whose sigma points are a
few dozen rows that differ in a few parameters (:func:`step_batch`, :func:`step_batch_inplace`).

Each block of rows goes into the lanes of :func:`sam.dynamics.step_lanes` and back; the per-run
constants of :func:`sam.dynamics.derive` are derived again only where a row's parameters differ
from the row before."""

from __future__ import annotations

import numpy as np

from .dynamics import (
    DERIVE_INPUTS, GEOMETRY_INPUTS, LANES, N_DERIVED, N_PARAMS, N_STATES, D, derive_geometry, derive_machine, jit,
    jit_inline, kernel_variant, step_lanes,
)
from .params import P

#: The columns of a parameter vector that derive() reads, in the order of P: the geometry's, the others'.
GEOMETRY_COLS = np.array(sorted(int(P[name]) for name in GEOMETRY_INPUTS), dtype=np.int64)
MACHINE_COLS = np.array(sorted(int(P[name]) for name in DERIVE_INPUTS - GEOMETRY_INPUTS), dtype=np.int64)


@jit
def step_batch(states, u, params, dt, substeps=1, scheme=0):
    """Advance a batch of states one model step (:func:`sam.dynamics.step_lanes`): the filter's process model.

    states (n, 7), u (n,) [V], params (n, len(P)) -> new states (n, 7), flags (n,).
    ``substeps`` and ``scheme`` (a :class:`sam.dynamics.Scheme`) as in :func:`sam.dynamics.step_lanes`; the defaults are
    Eq. (22) at ``dt``. The input arrays are not modified.
    """
    out = states.copy()
    flags = np.zeros(states.shape[0], dtype=np.int64)
    step_batch_inplace(out, u, params, dt, flags, substeps, scheme)
    return out, flags


@jit
def step_batch_inplace(states, u, params, dt, flags, substeps=1, scheme=0):
    """:func:`step_batch` in place: states (n, 7) C-contiguous, advanced; flags (n,) written.
    For the filter, which steps a few dozen sigma points per sample and reuses one array: its
    rows go into the lanes of a block (transposed), and back."""
    params = np.ascontiguousarray(params)  # the array itself when it is C-contiguous
    n = states.shape[0]
    leaks, effects = kernel_variant(params)
    s, uu = np.empty((N_STATES, LANES)), np.empty(LANES)
    p, d = np.empty((N_PARAMS, LANES)), np.empty((N_DERIVED, LANES))
    fl = np.empty(LANES, dtype=np.int64)
    for lo in range(0, n, LANES):
        m = min(LANES, n - lo)
        for j in range(m):
            i = lo + j
            for c in range(N_STATES):
                s[c, j] = states[i, c]
            for c in range(N_PARAMS):
                p[c, j] = params[i, c]
            uu[j] = u[i]
            fl[j] = 0
            # derive() is 40 % of a step (trigonometry, square roots, divisions). The sigma points of
            # a filter differ in parameters it does not read (faults, load force) or, for calibration
            # states, in a few it does, never in the geometry: derive again only what changed.
            _derive_unless_same(params, i, j, p, d, GEOMETRY_COLS, True)
            _derive_unless_same(params, i, j, p, d, MACHINE_COLS, False)
        step_lanes(s, uu, p, d, dt, fl, m, substeps, scheme, leaks, effects)
        for j in range(m):
            for c in range(N_STATES):
                states[lo + j, c] = s[c, j]
            flags[lo + j] = fl[j]


@jit_inline
def _derive_unless_same(params, i, j, p, d, cols, geometry):
    """Lane j's constants of one part of :func:`derive` (``geometry``: derive_geometry's, else
    derive_machine's), copied from lane j - 1 where params row i equals row i - 1 in its ``cols``."""
    same = j > 0
    if same:
        for c in cols:
            if params[i, c] != params[i - 1, c]:
                same = False
                break
    if geometry:
        if same:
            for e in (D.cos_level, D.sin_level, D.cos_cog, D.sin_cog, D.x_end):
                d[e, j] = d[e, j - 1]
        else:
            derive_geometry(p, d, j)
    elif same:
        for e in (D.K_PA, D.K_AT, D.K_PB, D.K_BT, D.A_A, D.A_B, D.inv_J_tot, D.sigma_1_r):
            d[e, j] = d[e, j - 1]
    else:
        derive_machine(p, d, j)
