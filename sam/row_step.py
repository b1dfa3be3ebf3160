"""The one step over rows of states, and over the lane blocks a caller keeps: the process model
of the filter, whose sigma points are a few dozen rows that differ in a few parameters.

A caller that steps the same rows sample after sample (the UKF, :mod:`fdi.kernel`) keeps them
in the layout of :func:`sam.dynamics.step_lanes`: :func:`lane_blocks` lays its rows out once;
at each sample it writes each row's state, input and the parameters it changes into the row's
lane (:func:`block_lane`), and :func:`step_blocks` advances them in place, deriving again only
the constants those parameters feed (:func:`derived_parts`). Nothing is allocated, and nothing
but what the caller changes is copied, per step.

Row i is lane i % LANES of block i // LANES of the blocks: states ``s`` (nb, 7, LANES), inputs
``u`` (nb, LANES) [V], parameters ``p`` (nb, len(P), LANES), their :func:`sam.dynamics.derive`d
constants ``d`` (nb, len(D), LANES) and flags (nb, LANES) int64.

:func:`step_batch` (:func:`step_batch_inplace`) is the same step of rows (n, 7) handed in at
each call: they go into blocks and back.
"""

from __future__ import annotations

import numpy as np

from .dynamics import (
    DERIVE_INPUTS, GEOMETRY_INPUTS, LANES, N_DERIVED, N_PARAMS, N_STATES, derive_geometry, derive_machine, jit,
    jit_inline, jit_lanes, kernel_variant, step_lanes,
)
from .params import P
from .views import fixed

#: The columns of a parameter vector that derive() reads, in the order of P: the geometry's, the others'.
GEOMETRY_COLS = np.array(sorted(int(P[name]) for name in GEOMETRY_INPUTS), dtype=np.int64)
MACHINE_COLS = np.array(sorted(int(P[name]) for name in DERIVE_INPUTS - GEOMETRY_INPUTS), dtype=np.int64)


@jit_inline
def block_lane(i):
    """(block, lane) of row i in lane blocks."""
    return i // LANES, i % LANES


@jit_inline
def _block_width(n, b):
    """Rows of n in block b (LANES but in the last)."""
    return min(LANES, n - b * LANES)


@jit
def lane_blocks(params):
    """Lane blocks (s, u, p, d, flags) for the rows of ``params`` (n, len(P)): their parameters
    in p, the constants derived from them in d, states, inputs and flags 0."""
    n = params.shape[0]
    nb = (n + LANES - 1) // LANES
    s, u = np.zeros((nb, N_STATES, LANES)), np.zeros((nb, LANES))
    p, d = np.zeros((nb, N_PARAMS, LANES)), np.zeros((nb, N_DERIVED, LANES))
    flags = np.zeros((nb, LANES), dtype=np.int64)
    for i in range(n):
        b, j = block_lane(i)
        for c in range(N_PARAMS):
            p[b, c, j] = params[i, c]
    derive_blocks(p, d, n, True, True)
    return s, u, p, d, flags


@jit
def derived_parts(cols):
    """(geometry, machine): whether a parameter column of ``cols`` (k,) is read by
    :func:`sam.dynamics.derive_geometry` / by :func:`sam.dynamics.derive_machine`, i.e. which
    part of d a caller that changes those columns must have derived again (:func:`step_blocks`)."""
    geometry, machine = False, False
    for c in cols:
        for g in GEOMETRY_COLS:
            geometry |= c == g
        for m in MACHINE_COLS:
            machine |= c == m
    return geometry, machine


@jit
def derive_blocks(p, d, n, geometry, machine):
    """The constants d of rows 0..n-1 from their parameters p: derive_geometry's part if
    ``geometry``, derive_machine's if ``machine``."""
    for b in range((n + LANES - 1) // LANES):
        _derive_lanes(p[b], d[b], _block_width(n, b), geometry, machine)


@jit_lanes
def _derive_lanes(p, d, m, geometry, machine):
    """:func:`derive_blocks` of one block's lanes 0..m-1: a lane loop, which LLVM vectorises where
    the arithmetic allows (the filter derives the machine's part of every sigma point each sample)."""
    p, d = fixed(p, N_PARAMS, LANES), fixed(d, N_DERIVED, LANES)
    if geometry:
        for j in range(np.uint64(m)):  # unsigned: no wrap-around of negative indices to vectorise
            derive_geometry(p, d, j)
    if machine:
        for j in range(np.uint64(m)):
            derive_machine(p, d, j)


@jit
def blocks_variant(p, n):
    """(leaks, effects) of :func:`sam.dynamics.kernel_variant` over rows 0..n-1 of lane blocks."""
    leaks, effects = False, False
    for b in range((n + LANES - 1) // LANES):
        lk, ef = kernel_variant(p[b, :, :_block_width(n, b)].T)
        leaks |= lk
        effects |= ef
    return leaks, effects


@jit
def step_blocks(s, u, p, d, dt, flags, n, substeps=1, scheme=0, geometry=False, machine=False):
    """Advance rows 0..n-1 of lane blocks (s, u, p, d, flags) in place over ``dt`` [s]: the one
    step, :func:`sam.dynamics.step_lanes`, on each block (``substeps`` and ``scheme`` as there; the
    defaults are Eq. (22) at ``dt``), its variant chosen over the n rows, flags ORed. Each block's
    constants d are first derived again from p where the caller has changed parameters they read
    since: ``geometry`` and ``machine`` as :func:`derived_parts` gives them for those columns."""
    leaks, effects = blocks_variant(p, n)
    for b in range((n + LANES - 1) // LANES):
        m = _block_width(n, b)
        if geometry or machine:  # block by block: its arrays are still in the cache for its step
            _derive_lanes(p[b], d[b], m, geometry, machine)
        step_lanes(s[b], u[b], p[b], d[b], dt, flags[b], m, substeps, scheme, leaks, effects)


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
    """:func:`step_batch` in place: states (n, 7) advanced; flags (n,) written. The rows go into
    lane blocks (:func:`lane_blocks`) and back at each call: a caller that steps the same rows
    again and again keeps them in the blocks (:func:`step_blocks`)."""
    n = states.shape[0]
    s, uu, p, d, fl = lane_blocks(params)
    for i in range(n):
        b, j = block_lane(i)
        for c in range(N_STATES):
            s[b, c, j] = states[i, c]
        uu[b, j] = u[i]
    step_blocks(s, uu, p, d, dt, fl, n, substeps, scheme)
    for i in range(n):
        b, j = block_lane(i)
        for c in range(N_STATES):
            states[i, c] = s[b, c, j]
        flags[i] = fl[b, j]
