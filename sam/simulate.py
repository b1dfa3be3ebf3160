"""The batch simulator: many parameter sets, one compiled loop over time.

The runs go in blocks of :data:`sam.dynamics.LANES`, each advanced through time by the one step,
:func:`sam.dynamics.step_lanes` (Eq. (22) by default), which takes the lanes of a block in one
vectorised loop; the blocks are spread over the CPU cores with numba's ``prange``. Only the
instants asked for are kept, so a batch of 90,000 runs of 4 s at 1 ms fits in memory.

Time convention: the state at ``t_k = k dt`` is ``x(k)``; the control ``u[k]``
and the time-varying parameters of step k act on ``[t_k, t_{k+1})``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .dynamics import (
    DERIVE_INPUTS, FLAG_CAVITATION, LANES, N_DERIVED, N_PARAMS, N_STATES, SCHEMES, S, areas, derive_geometry,
    derive_machine, kernel_variant, step_lanes,
)
from .constants import P_CAVITATION
from .geometry import external_force
from .params import P

#: The float types the step runs in, by name.
PRECISIONS = {"float64": np.float64, "float32": np.float32}

# nogil: a caller's other threads (e.g. the GSA runner writing finished chunks) run meanwhile
@numba.njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def _simulate_kernel(x0, params, u, tv_cols, tv_vals, rederive, dt, n_steps, record_at, channels, out, flags,
                     substeps, scheme, leaks, effects, ftype):
    """x0 (n,7); params (n,np); u (1|n, n_steps); tv_vals (1|n, m, n_steps);
    record_at (n_rec,) sorted step indices in [0, n_steps]; out (n, n_chan, n_rec).
    Blocks of LANES runs, each advanced in time together; ftype the float type of the step."""
    n = x0.shape[0]
    n_rec = record_at.shape[0]
    for b in numba.prange((n + LANES - 1) // LANES):
        lo = b * LANES
        m = min(LANES, n - lo)
        s = np.empty((N_STATES, LANES), ftype)
        p = np.empty((N_PARAMS, LANES), ftype)
        d = np.empty((N_DERIVED, LANES), ftype)
        uu = np.empty(LANES, ftype)
        fl = np.zeros(LANES, np.int64)
        for j in range(m):
            for c in range(N_STATES):
                s[c, j] = x0[lo + j, c]
            for c in range(N_PARAMS):
                p[c, j] = params[lo + j, c]
            derive_geometry(p, d, j)
            derive_machine(p, d, j)
        # a shared (1, n_steps) input serves every run; int64 keeps numba from promoting to float
        iu = np.int64(u.shape[0] - 1)
        itv = np.int64(tv_vals.shape[0] - 1)
        r = 0
        for k in range(n_steps + 1):
            while r < n_rec and record_at[r] == k:
                for c in range(channels.shape[0]):
                    for j in range(m):
                        out[lo + j, c, r] = s[channels[c], j]
                r += 1
            if k == n_steps:
                break
            for i in range(tv_cols.shape[0]):
                for j in range(m):
                    p[tv_cols[i], j] = tv_vals[min(lo + j, itv), i, k]
            if rederive:
                for j in range(m):
                    derive_geometry(p, d, j)
                    derive_machine(p, d, j)
            for j in range(m):
                uu[j] = u[min(lo + j, iu), k]
            step_lanes(s, uu, p, d, dt, fl, m, substeps, scheme, leaks, effects)
        for j in range(m):
            flags[lo + j] |= fl[j]


@dataclass(frozen=True)
class BatchResult:
    """States of a batch of runs at the recorded instants.

    Attributes:
        t: (n_rec,) recorded instants [s].
        states: dict state name -> (n_runs, n_rec) array, for the channels recorded
            (``p_A``, ``p_B`` [Pa], ``x_s`` [1], ``dx_s`` [1/s], ``x`` [m], ``v`` [m/s], ``z`` [m]).
        cavitated: (n_runs,) bool, True where a chamber pressure hit the cavitation floor.
    """

    t: np.ndarray
    states: dict[str, np.ndarray]
    cavitated: np.ndarray

    def __getitem__(self, name: str) -> np.ndarray:
        return self.states[name]


def simulate_batch(
    params: np.ndarray,
    u: np.ndarray,
    dt: float,
    *,
    x0: np.ndarray | None = None,
    time_varying: dict[str, np.ndarray] | None = None,
    record_every: int = 1,
    record_at: np.ndarray | None = None,
    channels: tuple[str, ...] = tuple(S.__members__),
    substeps: int = 1,
    scheme: str = "euler",
    precision: str = "float64",
    out: np.ndarray | None = None,
) -> BatchResult:
    """Simulate a batch of runs from their parameter vectors.

    Args:
        params: (n_runs, len(P)) parameter vectors (see :meth:`sam.params.Plant.vector`).
        u: control signal [V], (n_steps,) shared by all runs or (n_runs, n_steps).
        dt: the model's step [s]: the input and the time-varying parameters are held over it.
        x0: initial states (n_runs, 7) or (7,); default :func:`initial_state` of each run.
        time_varying: parameter name -> values per step, (n_steps,) shared or
            (n_runs, n_steps); overrides that column of ``params`` at each step
            (fault profiles, a changing load mass, a disturbance force).
        record_every: keep every k-th instant, including t = 0 and the end.
        record_at: explicit step indices in [0, n_steps] to keep instead.
        channels: names of the states to keep (fewer channels, less memory).
        substeps: sub-steps of ``dt / substeps`` per step (:func:`sam.dynamics.step`).
        scheme: ``"euler"`` (Eq. (22)), ``"semi_implicit"``, ``"heun"`` or ``"rk4"``
            (:class:`sam.dynamics.Scheme`). The defaults are Eq. (22) at ``dt``.
        precision: ``"float64"``, or ``"float32"``: the step's arithmetic in single precision,
            about 1.4x faster (for the GSA, whose indices tolerate it: docs/benchmarks.md). The
            states returned are in the arithmetic's precision (float32 arrays: half the memory to
            write, and float64 would carry no more digits), unless ``out`` says otherwise.
        out: where to record, a C-contiguous float64 (or, for ``precision="float32"``, float32)
            array (n_runs, len(channels), >= n_rec) whose first n_rec columns receive the recorded
            instants (a caller's layout with room for more, e.g. the GSA's steady-state column,
            without a copy); the returned states are views of it. Default: a new array of the
            arithmetic's precision.
    """
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {sorted(SCHEMES)}, got {scheme!r}")
    if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps must be a whole number >= 1, got {substeps!r}")
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
    params = np.ascontiguousarray(np.atleast_2d(params), dtype=np.float64)
    n_runs = params.shape[0]
    u2 = np.ascontiguousarray(np.atleast_2d(u), dtype=np.float64)
    n_steps = u2.shape[1]
    if x0 is None:
        x0 = initial_state(params)
    x0 = np.ascontiguousarray(np.broadcast_to(x0, (n_runs, N_STATES)), dtype=np.float64)
    tv_cols, tv_vals = _pack_time_varying(time_varying or {}, n_steps)
    if record_at is None:
        record_at = np.unique(np.r_[np.arange(0, n_steps + 1, record_every), n_steps])
    record_at = np.ascontiguousarray(record_at, dtype=np.int64)
    chan_idx = np.array([S[c] for c in channels], dtype=np.int64)
    out = _record_buffer(out, (n_runs, len(chan_idx), len(record_at)), precision)
    flags = np.zeros(n_runs, dtype=np.int64)
    rederive = bool(DERIVE_INPUTS.intersection(time_varying or {}))
    leaks, effects = _variant(params, tv_cols, tv_vals)
    _simulate_kernel(x0, params, u2, tv_cols, tv_vals, rederive, float(dt), n_steps, record_at, chan_idx, out, flags,
                     int(substeps), int(SCHEMES[scheme]), leaks, effects, PRECISIONS[precision])
    states = {c: out[:, j, : len(record_at)] for j, c in enumerate(channels)}
    return BatchResult(record_at * dt, states, (flags & FLAG_CAVITATION) != 0)


def _record_buffer(out: np.ndarray | None, shape: tuple[int, int, int], precision: str) -> np.ndarray:
    """``out`` checked against the recording's ``shape`` (or a new array of it in ``precision``)."""
    if out is None:
        return np.empty(shape, dtype=np.dtype(precision))
    allowed = (np.float64, np.float32) if precision == "float32" else (np.float64,)
    if (not isinstance(out, np.ndarray) or out.dtype not in allowed or not out.flags.c_contiguous
            or out.shape[:2] != shape[:2] or out.ndim != 3 or out.shape[2] < shape[2]):
        raise ValueError(f"out must be a C-contiguous {' or '.join(np.dtype(t).name for t in allowed)} array "
                         f"({shape[0]}, {shape[1]}, >= {shape[2]}), got {getattr(out, 'dtype', type(out))} "
                         f"{getattr(out, 'shape', '')}")
    return out


def _variant(params: np.ndarray, tv_cols: np.ndarray, tv_vals: np.ndarray) -> tuple[bool, bool]:
    """(leaks, effects) of :func:`sam.dynamics.kernel_variant` over the parameters and the values
    the time-varying columns take (each of its tests is decided by a column's least and greatest)."""
    rows = [params]
    for j, col in enumerate(tv_cols):
        ends = np.repeat(params[:1], 2, axis=0)
        ends[:, col] = tv_vals[:, j, :].min(), tv_vals[:, j, :].max()
        rows.append(ends)
    leaks, effects = kernel_variant(np.concatenate(rows))
    return bool(leaks), bool(effects)


def _pack_time_varying(time_varying: dict[str, np.ndarray], n_steps: int):
    cols = np.array([P[name] for name in time_varying], dtype=np.int64)
    if not time_varying:
        return cols, np.zeros((1, 0, n_steps))
    arrays = [np.atleast_2d(np.asarray(v, dtype=np.float64)) for v in time_varying.values()]
    n_lead = max(a.shape[0] for a in arrays)
    vals = np.stack([np.broadcast_to(a, (n_lead, n_steps)) for a in arrays], axis=1)
    return cols, np.ascontiguousarray(vals)


def initial_state(params: np.ndarray, x: float | np.ndarray = 0.0) -> np.ndarray:
    """A state at rest, valve centred, piston at ``x`` [m] (a float, or (n_runs,) one per run):
    shape (n_runs, 7) or (7,).

    The rod-side pressure is the one the laminar null leakage settles to,
    Eq. (14) with zero flow: the valve has been centred for a long time. On the
    retracted end stop (x = 0) chamber A settles the same way (Eq. (13)), and the
    stop carries whatever load the pressures do not. Away from the stop chamber A
    instead holds the load: ``p_A A_A = p_B A_B + F_ext``. A load that pulls the
    piston out harder than that rod-side pressure can resist (a boom past vertical)
    would need p_A below the cavitation floor; there chamber A sits at the floor
    and chamber B carries the load: ``p_B A_B = P_CAVITATION A_A - F_ext``.
    """
    p = np.atleast_2d(params)
    x = np.broadcast_to(np.asarray(x, dtype=float), (p.shape[0],))
    p_A = _leak_divider(p, "PA", "AT")
    p_B = _leak_divider(p, "PB", "BT")
    A_A, A_B = areas(p[:, P.D_piston], p[:, P.D_rod])
    F_ext = external_force(
        x, p[:, P.L_1], p[:, P.L_2], p[:, P.L_3], p[:, P.theta_level], p[:, P.cog_angle], p[:, P.m_B],
        p[:, P.r_B], p[:, P.m_L], p[:, P.m_R], p[:, P.L],
    ) + p[:, P.F_d]
    p_A = np.where(x > 0.0, (p_B * A_B + F_ext) / A_A, p_A)
    pulled = p_A < P_CAVITATION  # only away from the stop: the null-leak divider is above the floor
    p_B = np.where(pulled, (P_CAVITATION * A_A - F_ext) / A_B, p_B)
    p_A = np.where(pulled, P_CAVITATION, p_A)
    s = np.zeros((p.shape[0], N_STATES))
    s[:, S.p_A], s[:, S.p_B], s[:, S.x] = p_A, p_B, x
    return s if np.ndim(params) == 2 else s[0]


def _leak_divider(p: np.ndarray, into: str, out_of: str) -> np.ndarray:
    """Pressure where the null leakages in and out of a chamber balance; p_T if there are none."""
    k_in, k_out = p[:, P[f"K_leak_{into}"]], p[:, P[f"K_leak_{out_of}"]]
    total = k_in + k_out
    safe = np.where(total > 0, total, 1.0)
    return np.where(total > 0, (k_in * p[:, P.p_S] + k_out * p[:, P.p_T]) / safe, p[:, P.p_T])


__all__ = ["BatchResult", "simulate_batch", "initial_state"]
