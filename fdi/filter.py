"""The augmented-state Unscented Kalman Filter over ``sam``'s own step function.

:func:`run_filter` runs B filters at once over the measured data of :class:`FilterInput` and
returns :class:`FilterOutput`. The first seven states are advanced by sam's one step
(:func:`sam.step_blocks`, Eq. (22)), the sigma points kept in its lanes; the parameter states
are random walks written into each sigma point's parameters (:mod:`fdi.states`). There is no
second copy of the physics here. Sigma points and weights follow filterpy's ``MerweScaledSigmaPoints`` exactly
(tests/test_fdi_ukf.py checks the whole filter against filterpy's ``UnscentedKalmanFilter``).

Robustness: leak sigma points are clipped at 0 and the leak means projected onto K >= 0
(:class:`fdi.config.Constraints`); P is symmetrised after every update; a failed Cholesky
factorisation is retried with growing jitter, and as a last resort P is reset; a diverging
filter (weighted NIS, a mean out of range) is reset (:class:`fdi.config.Guards`); a missing
measurement is predicted through; on an end stop the gain and the random walks follow
:class:`fdi.config.StopRules`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numba
import numpy as np

from sam import SCHEMES, P, S, stroke_ends
from sam.geometry import piston_position

from .config import FilterConfig
from .form_noise import form_gates
from .kernel import KernelArgs, KernelOutputs, run
from .sigma import merwe_weights, robust_sqrt
from .states import (
    FAULT_STATES, MEAS_SCALE_P, MEAS_SCALE_THETA, MEAS_SCALE_X, N_AUG, N_MODEL, PARAM_COLS, POS_X,
)
from .strokes import directions, long_strokes

#: s: the largest Euler step of the model the filter takes (stable for the SAM up to here:
#: sam.dynamics.euler_step). A coarser recording is propagated with :func:`model_substeps`
#: steps per sample, its input held over the sample.
MAX_MODEL_DT = 1e-3
#: relative slack of :func:`model_substeps`: a logger clock 1 % off its nominal rate (the jitter
#: the recording format allows) keeps the nominal number of steps
SUBSTEP_SLACK = 0.01


@dataclass(frozen=True)
class FilterInput:
    """Measured data of B runs, all of the same length and sampling step."""

    dt: float  #: s, sampling step
    u: np.ndarray  #: (B, T) valve input [V]
    pA: np.ndarray  #: (B, T) Pa, NaN = missing
    pB: np.ndarray  #: (B, T) Pa, NaN = missing
    pos: np.ndarray  #: (B, T) piston position x [m] or joint angle theta [rad], NaN = missing
    pos_kind: int  #: POS_X or POS_THETA (fdi.states)
    params: np.ndarray  #: (B, len(sam.P)) nominal plant vectors (healthy faults)
    pS: np.ndarray | None = None  #: (B, T) measured supply pressure [Pa], or None
    #: where an x came from: "linear" (a transducer) or "encoder" (computed from the encoder's
    #: quantised angle); None: linear for x, encoder for theta
    position_sensor: str | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(B, T)."""
        return self.u.shape

    @property
    def linear_position(self) -> bool:
        """The position reading is a linear transducer's x (continuous, not an encoder's pulses)."""
        return self.pos_kind == POS_X and self.position_sensor != "encoder"

    def decimated(self, k: int) -> "FilterInput":
        """Every k-th sample (what a logger sampling k times more slowly records)."""
        if k == 1:
            return self
        every = lambda a: None if a is None else np.ascontiguousarray(a[:, ::k])  # noqa: E731
        return replace(self, dt=self.dt * k, u=every(self.u), pA=every(self.pA), pB=every(self.pB),
                       pos=every(self.pos), pS=every(self.pS))


@dataclass(frozen=True)
class FilterOutput:
    """The filters' posteriors, per run b and sample k, in SI units."""

    t: np.ndarray  #: (T,) s, from 0
    mean: np.ndarray  #: (B, T, n) posterior means (n = config.n_states)
    std: np.ndarray  #: (B, T, n) posterior stds
    nu: np.ndarray  #: (B, T, 3) normalised innovations [pA, pB, position] (NaN: not measured)
    nis: np.ndarray  #: (B, T) exponentially weighted normalised innovation squared
    n_nan: np.ndarray  #: (B,) samples with at least one channel missing
    n_jitter: np.ndarray  #: (B,) covariances factorised only with jitter
    n_cov_reset: np.ndarray  #: (B,) covariance resets (divergence, or no factor)
    n_state_reset: np.ndarray  #: (B,) means restored to their last sane value
    config: FilterConfig = field(default_factory=FilterConfig)  #: the filter that ran
    u: np.ndarray | None = None  #: (B, T) the input the filter was driven with
    #: (B, T) innovation log-likelihood log N(nu; 0, S) per sample (internal units; 0 where nothing
    #: was measured); summed over a window it compares hypotheses (fdi.bank)
    ll: np.ndarray | None = None
    inp: FilterInput | None = None  #: the measured data the filter ran on

    @property
    def names(self) -> tuple[str, ...]:
        """The state names of axis 2 of mean and std."""
        return self.config.state_names

    def estimate(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(mean, std) (B, T) of the state ``name``."""
        j = self.names.index(name)
        return self.mean[:, :, j], self.std[:, :, j]


def sample_step(t: np.ndarray) -> float:
    """s, the sampling step of the sample times ``t`` (T,) of a filter output (1 ms for one sample)."""
    return float(t[1] - t[0]) if len(t) > 1 else 1e-3


def model_substeps(dt: float) -> int:
    """Model steps per sample of ``dt`` [s]: the fewest that keep each step <= MAX_MODEL_DT
    (1 + SUBSTEP_SLACK): 2 for a 500 Hz recording whose clock runs 0.4 % slow, 1 at 1 kHz."""
    return max(1, math.ceil(dt / (MAX_MODEL_DT * (1.0 + SUBSTEP_SLACK))))


def measurement_variances(cfg: FilterConfig, pos_kind: int) -> np.ndarray:
    """Scaled measurement variances [pA, pB, position] (the encoder: its quantum's pulse^2 / 12
    and the noise floor in quadrature)."""
    s = cfg.sensors
    rp = (s.pressure_noise / MEAS_SCALE_P) ** 2
    if pos_kind == POS_X:
        rx = (s.x_noise / MEAS_SCALE_X) ** 2
    else:
        rx = (s.theta_pulse**2 / 12.0 + s.theta_noise_floor**2) / MEAS_SCALE_THETA**2
    return np.array([rp, rp, rx])


def scaled_measurements(inp: FilterInput) -> np.ndarray:
    """(B, T, 3) the measurements [pA, pB, position] in the filter's internal units."""
    pos_scale = MEAS_SCALE_X if inp.pos_kind == POS_X else MEAS_SCALE_THETA
    return np.ascontiguousarray(np.stack(
        [inp.pA / MEAS_SCALE_P, inp.pB / MEAS_SCALE_P, inp.pos / pos_scale], axis=-1))


def initial_mean(inp: FilterInput, cfg: FilterConfig | None = None) -> np.ndarray:
    """(B, n) scaled initial means from the first finite measurements: the filter starts at the
    measured pressures and position, at rest, with the plant's fault parameters, zero
    calibration errors and the unknown inputs at their plant values."""
    cfg = FilterConfig() if cfg is None else cfg
    B = inp.u.shape[0]
    n = cfg.n_states
    scale = cfg.state_scale()
    z0 = np.zeros((B, n))
    for b in range(B):
        pa = _first_finite(inp.pA[b])
        pb = _first_finite(inp.pB[b])
        pos = _first_finite(inp.pos[b])
        p = inp.params[b]
        x = pos if inp.pos_kind == POS_X else float(piston_position(pos, p[P.L_1], p[P.L_2], p[P.L_3]))
        x = max(x, 0.0)
        full = np.zeros(n)
        full[S.p_A], full[S.p_B], full[S.x] = pa, pb, x
        full[N_MODEL:N_AUG] = p[PARAM_COLS]
        for i, name in enumerate(cfg.unknown_inputs.states):
            full[N_AUG + len(cfg.calibration.states) + i] = p[P[name]]
        z0[b] = full / scale
    return z0


def _first_finite(a: np.ndarray) -> float:
    idx = np.flatnonzero(np.isfinite(a))
    return float(a[idx[0]]) if len(idx) else 0.0


def run_filter(inp: FilterInput, cfg: FilterConfig | None = None, z0: np.ndarray | None = None,
               P0: np.ndarray | None = None, n_steps: np.ndarray | None = None,
               held: np.ndarray | None = None) -> FilterOutput:
    """Run the filter ``cfg`` (default: the shipped one) over the B runs of ``inp`` at once.

    ``z0`` (B, n) scaled initial means (default :func:`initial_mean`); ``P0`` (B, n, n) scaled
    initial covariances (default: diagonal, the configuration's initial stds), refused (ValueError)
    unless finite, symmetric, positive semi-definite and factorisable over the free states.
    ``n_steps`` (B,): run b only over its first n_steps[b] samples (NaN after): runs of different
    lengths share a batch without paying for the padding. ``held`` (B, n) bool: states of filter
    b that are known constants (at z0): its unscented transform runs over the others only (2
    n_free + 1 sigma points), what a bank of constrained filters costs. Only parameter states
    (index >= N_MODEL) may be held, with no prior covariance with the free ones."""
    cfg = FilterConfig() if cfg is None else cfg
    B, T = inp.u.shape
    n = cfg.n_states
    scale = cfg.state_scale()
    cols, rel = cfg.param_layout()
    q, p0 = cfg.noise_vectors()
    held = np.zeros((B, n), dtype=np.bool_) if held is None else np.asarray(held, dtype=np.bool_)
    if held.shape != (B, n):
        raise ValueError(f"run_filter: held has shape {held.shape}, expected {(B, n)}")
    if held[:, :N_MODEL].any():
        raise ValueError("run_filter: only parameter states (index >= N_MODEL) can be held")
    n_act = n - held.sum(axis=1)
    act = np.array([np.concatenate([np.flatnonzero(~h), np.flatnonzero(h)]) for h in held], dtype=np.int64)
    sp = cfg.sigma_points
    Wm, Wc, lam = np.zeros((B, 2 * n + 1)), np.zeros((B, 2 * n + 1)), np.empty(B)
    for na in np.unique(n_act):
        wm, wc, la = merwe_weights(int(na), sp.alpha, sp.beta, sp.kappa)
        Wm[n_act == na, :2 * na + 1], Wc[n_act == na, :2 * na + 1], lam[n_act == na] = wm, wc, la
    z0 = initial_mean(inp, cfg) if z0 is None else z0
    if P0 is None:
        P0 = np.broadcast_to(np.diag((p0 / scale) ** 2), (B, n, n)).copy()
    z0 = np.broadcast_to(z0, (B, n))
    P0 = np.broadcast_to(P0, (B, n, n))
    if held.any() and np.any((P0 != 0.0) & held[:, :, None] & ~held[:, None, :]):
        raise ValueError("run_filter: a held state has prior covariance with a free one (P0)")
    check_p0(P0, act, n_act, n_act + lam, cfg.guards.jitter)
    steps = np.full(B, T, dtype=np.int64) if n_steps is None else np.minimum(np.asarray(n_steps, np.int64), T)
    # the kernel needs the active runs first: order the runs by decreasing length (and back)
    order = slice(None) if n_steps is None else np.argsort(-steps, kind="stable")
    if not isinstance(order, slice) and np.array_equal(order, np.arange(B)):
        order = slice(None)  # already in order (e.g. a bank's hypotheses of one run): no copies
    c = np.ascontiguousarray
    pS = np.full((B, T), np.nan) if inp.pS is None else inp.pS
    q_gate, gate_group = random_walk_gates(inp, cfg)
    stop_gate, stop_learn = stop_gain_gate(inp, cfg)
    g, con = cfg.guards, cfg.constraints
    args = KernelArgs(
        z0=c(z0[order], dtype=float), P0=c(P0[order], dtype=float),
        Qd=np.diag((q * math.sqrt(inp.dt) / scale) ** 2), Rd=measurement_variances(cfg, inp.pos_kind),
        u=c(inp.u[order], dtype=float), y=c(scaled_measurements(inp)[order]), pS=c(pS[order], dtype=float),
        params=c(cfg.stops.model_params(inp.params)[order], dtype=float), scale=scale, param_cols=cols, param_rel=rel,
        pos_kind=int(inp.pos_kind), Wm=Wm[order], Wc=Wc[order], lam=lam[order], act=act[order],
        n_act=n_act[order], n_steps=steps[order], slot=np.arange(B, dtype=np.int64)[order],
        q_gate=q_gate[order], gate_group=gate_group, stop_gate=stop_gate[order], stop_learn=stop_learn,
        clip_leaks=bool(con.clip_leaks), project_mean=bool(con.project_mean),
        project_internal=bool(con.project_internal), joint=con.projection == "joint",
        symmetrise=bool(con.symmetrise), nis_alpha=float(min(1.0, inp.dt / g.nis_tau_s) if g.nis_tau_s > 0 else 1.0),
        nis_limit=float(g.nis_factor * 3 if g.nis_factor > 0 else np.inf), jitter=float(g.jitter),
        max_state=float(g.max_scaled_state), dt=float(inp.dt), n_sub=model_substeps(inp.dt),
        scheme=int(SCHEMES[cfg.model_scheme]))
    # every sample is written by the kernel (NaN after a run's n_steps): no fill here
    res = KernelOutputs(mean=np.empty((B, T, n)), sd=np.empty((B, T, n)), nu=np.empty((B, T, 3)),
                        nis=np.empty((B, T)), ll=np.empty((B, T)), counts=np.zeros((B, 4), dtype=np.int64))
    run(args, res)
    counts = res.counts if isinstance(order, slice) else res.counts[np.argsort(order)]  # in the caller's order
    mean, std = res.mean, res.sd
    mean *= scale  # SI units, in place: these arrays are the filter's own
    std *= scale
    return FilterOutput(t=np.arange(T) * inp.dt, mean=mean, std=std, nu=res.nu, nis=res.nis, n_nan=counts[:, 0],
                        n_jitter=counts[:, 1], n_cov_reset=counts[:, 2], n_state_reset=counts[:, 3], config=cfg,
                        u=inp.u, ll=res.ll, inp=inp)


def check_p0(P0: np.ndarray, act: np.ndarray, n_act: np.ndarray, c: np.ndarray, jitter: float) -> None:
    """Refuse (ValueError, one line) initial covariances P0 (B, n, n) that are not finite, not
    symmetric, not positive semi-definite, or that the filter cannot factorise as c[b] P0[b] over
    its free states act[b, :n_act[b]] even with its growing diagonal jitter (all zeros)."""
    if not np.all(np.isfinite(P0)):
        b, i, j = np.argwhere(~np.isfinite(P0))[0]
        raise ValueError(f"run_filter: P0[{b}, {i}, {j}] = {P0[b, i, j]}: the initial covariance must be finite")
    asym = np.abs(P0 - np.swapaxes(P0, 1, 2))
    size = np.maximum(np.abs(P0).max(axis=(1, 2)), 1e-300)
    if np.any(asym.max(axis=(1, 2)) > 1e-9 * size):
        b, i, j = np.unravel_index(np.argmax(asym / size[:, None, None]), asym.shape)
        raise ValueError(f"run_filter: P0 is not symmetric: P0[{b}, {i}, {j}] = {P0[b, i, j]:.6g} but "
                         f"P0[{b}, {j}, {i}] = {P0[b, j, i]:.6g}")
    low = np.linalg.eigvalsh(P0)[:, 0]
    if np.any(low < -1e-9 * size):
        b = int(np.argmin(low / size))
        raise ValueError(f"run_filter: P0[{b}] is not positive semi-definite (smallest eigenvalue {low[b]:.3g})")
    ok = _factorisable(np.ascontiguousarray(P0, dtype=float), act, n_act, np.asarray(c, dtype=float), jitter)
    if not ok.all():
        b = int(np.flatnonzero(~ok)[0])
        raise ValueError(f"run_filter: P0[{b}] cannot be factorised (its Cholesky factor does not exist even "
                         "with diagonal jitter: every variance of the free states is zero)")


@numba.njit(cache=True)
def _factorisable(P0, act, n_act, c, jitter):
    """(B,) whether :func:`fdi.sigma.robust_sqrt` factorises c[b] P0[b] over act[b, :n_act[b]]."""
    B, n = P0.shape[0], P0.shape[1]
    L = np.empty((n, n))
    A = np.empty((n, n))
    ok = np.empty(B, dtype=np.bool_)
    for b in range(B):
        ok[b] = robust_sqrt(P0[b].copy(), c[b], jitter, L, A, act[b], n_act[b]) >= 0
    return ok


# ---------------------------------------------------------------- stop rules and holds


def calibration_hold(inp: FilterInput, cfg: FilterConfig) -> np.ndarray:
    """(B, T) factor on the calibration states' random walk: 0 in the long strokes of the input
    (:attr:`fdi.config.CalibrationStates.hold_after_s`, fdi.strokes.long_strokes), 1 elsewhere."""
    B, T = inp.u.shape
    if cfg.calibration.hold_after_s is None or not cfg.calibration.states:
        return np.ones((B, T))
    held = long_strokes(inp.u, inp.dt, cfg.hold_band_V, cfg.calibration.hold_after_s)
    return np.ascontiguousarray(np.where(held, 0.0, 1.0))


def random_walk_gates(inp: FilterInput, cfg: FilterConfig) -> tuple[np.ndarray, np.ndarray]:
    """The random-walk gates of the kernel: (B, T, 2) factors, [..., 0] the calibration states'
    (0 in long strokes, :func:`calibration_hold`, and pressed on a stop), [..., 1] the fault
    states' (0 pressed on a stop, :func:`pressed_on_stop`), with ``cfg.form_noise`` [..., 2:4] those
    of p_A and p_B (above 1 where the model's form errs, :func:`fdi.form_noise.form_gates`), and (n,)
    each state's gate (-1: none, its walk always runs)."""
    n = cfg.n_states
    q_cal = calibration_hold(inp, cfg)
    group = np.full(n, -1, dtype=np.int64)
    calib = slice(N_AUG, N_AUG + len(cfg.calibration.states))
    if cfg.calibration.hold_after_s is not None:
        group[calib] = 0
    q_fault = np.ones_like(q_cal)
    if cfg.stops.hold_s is not None:
        group[list(FAULT_STATES)] = 1
        group[calib] = 0
        q_fault = np.where(pressed_on_stop(inp, cfg), 0.0, 1.0)
        q_cal = q_cal * q_fault
    gates = [q_cal, q_fault]
    if cfg.form_noise.active:  # where the model's form errs
        group[[S.p_A, S.p_B]] = [2, 3]
        wide = form_gates(inp, cfg.form_noise, cfg.process_noise["p_A"], cfg.process_noise["p_B"])
        gates += [wide[..., 0], wide[..., 1]]
    return np.ascontiguousarray(np.stack(gates, axis=-1)), group


def pressed_on_stop(inp: FilterInput, cfg: FilterConfig) -> np.ndarray:
    """(B, T) bool: where the input has been in the hold band and the measured piston (x, or theta
    mapped to x) within ``cfg.stops.hold_margin_m`` of an end stop, both without a break, for
    ``cfg.stops.hold_s`` or longer: where :func:`random_walk_gates` stops the random walks.
    Causal; a missing position is not on a stop."""
    d, _ = directions(inp.u, inp.dt, cfg.hold_band_V)
    pressed = d == 0
    b, k = np.nonzero(pressed)  # the position is looked at only at rest (a tune's batch rests little)
    p = inp.params[b]
    x = inp.pos[b, k]
    if inp.pos_kind != POS_X:
        x = piston_position(x, p[:, P.L_1], p[:, P.L_2], p[:, P.L_3])
    pressed[b, k] = near_end_stop(x[:, None], p, cfg.stops.hold_margin_m)[:, 0]
    steps = np.arange(pressed.shape[1])[None, :]
    last_off = np.maximum.accumulate(np.where(pressed, -1, steps), axis=1)
    return pressed & ((steps - last_off - 1) * inp.dt >= cfg.stops.hold_s - 1e-9)


def stop_gain_gate(inp: FilterInput, cfg: FilterConfig) -> tuple[np.ndarray, np.ndarray]:
    """The gate of :attr:`fdi.config.StopRules.learners`: (B, T) bool, a linear sensor's reading
    within ``cfg.stops.margin_m`` of an end stop (False everywhere for the encoder, theta or x
    computed from it, and where the reading is missing), and the (n,) states that learn from the
    position there."""
    B, T = inp.u.shape
    n = cfg.n_states
    learners = cfg.stops.learners
    if learners is None or not inp.linear_position:
        return np.zeros((B, T), dtype=np.bool_), np.ones(n, dtype=np.bool_)
    learn = np.array([i < N_MODEL or name in learners for i, name in enumerate(cfg.state_names)])
    return np.ascontiguousarray(near_end_stop(inp.pos, inp.params, cfg.stops.margin_m)), learn


def near_end_stop(x: np.ndarray, params: np.ndarray, margin_m: float) -> np.ndarray:
    """(B, T) bool: piston positions x (B, T) [m] within ``margin_m`` of an end stop of their
    plant vectors params (B, len(P)): 0, or the extension stop (the stroke or the joint limit
    theta_max, whichever comes first, :func:`sam.stroke_ends`). NaN is not near a stop."""
    x_end = stroke_ends(params)[:, None]
    with np.errstate(invalid="ignore"):
        return (x <= margin_m) | (x >= x_end - margin_m)
