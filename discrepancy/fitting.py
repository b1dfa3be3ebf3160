"""Fitting free parameters on simulation error (scipy.optimize.least_squares).

The Jacobian is a forward difference evaluated as one batch of simulations
(one candidate per free parameter), which the compiled simulator runs in
parallel: a whole Jacobian costs about as much as two serial simulations.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from sam import P

from .library import Free
from .simulation import MEAS_PARAMS, SIGNALS, SegmentSimulator

FD_STEP = 1e-3  # forward-difference step in the scaled (log10 or fraction-of-span) parameter space


@dataclass
class FitResult:
    free: tuple[Free, ...]
    values: dict[str, float]
    params: np.ndarray  # full plant vector (len(P),)
    meas: np.ndarray  # (2,) tau, delay
    rss_fit: float
    rss_held: float
    n_fit: int
    n_held: int = 0
    at_bounds: list[str] = field(default_factory=list)
    nfev: int = 0


class Model:
    """Maps scaled free parameters to plant vectors and measurement settings."""

    def __init__(self, base: np.ndarray, free: tuple[Free, ...], base_meas=(0.0, 0.0), tv=None):
        self.tv = tv  # optional callable (thetas, simulator) -> {name: (m, n_samples)} disturbance inputs
        self.base = np.asarray(base, float)
        self.free = tuple(free)
        self.base_meas = np.asarray(base_meas, float)

    def build(self, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        thetas = np.atleast_2d(thetas)
        m = thetas.shape[0]
        params = np.tile(self.base, (m, 1))
        meas = np.tile(self.base_meas, (m, 1))
        for j, f in enumerate(self.free):
            vals = np.array([f.to_value(t) for t in thetas[:, j]])
            if f.name in MEAS_PARAMS:
                meas[:, MEAS_PARAMS.index(f.name)] = vals
            elif f.name.startswith("c_"):  # a coefficient of the generic route's disturbance term
                continue
            elif f.apply is not None:
                f.apply(params, vals)
            else:
                params[:, P[f.name]] = vals
        return params, meas

    def theta_of(self, values: dict[str, float]) -> np.ndarray:
        out = []
        for f in self.free:
            if f.name in values:
                v = values[f.name]
            elif f.name in MEAS_PARAMS:
                v = self.base_meas[MEAS_PARAMS.index(f.name)]
            elif f.name.startswith("c_") or f.apply is not None:
                v = 0.0  # a term's coefficient, an increment: none at the base
            else:
                v = self.base[P[f.name]]
            out.append(f.to_theta(v))
        return np.array(out)

    def values_of(self, theta: np.ndarray) -> dict[str, float]:
        return {f.name: float(f.to_value(t)) for f, t in zip(self.free, theta)}


class Split:
    """The fitting part and the held-out part: segments of one recording, or a second recording.

    ``seg_sigma`` (optional): part -> (n_segments_of_part,) residual scale of each segment. The
    residuals of a segment are divided by it (a heteroscedastic noise model: every 1 s segment has
    its own residual variance), see :func:`segment_scales`. ``settle``: 0, or the decay times over
    which every segment's start state is estimated under each model evaluated
    (:meth:`SegmentSimulator.settled_states`; ``Settings.start_decay_times``).
    """

    def __init__(self, fit_sim: SegmentSimulator, held_sim: SegmentSimulator | None = None,
                 seg_sigma: dict[str, np.ndarray] | None = None, settle: float = 0.0):
        self.fit_sim = fit_sim
        self.held_sim = held_sim or fit_sim
        self.seg_sigma = seg_sigma
        self.settle = settle

    def sim_for(self, part: str) -> SegmentSimulator:
        return self.fit_sim if part == "fit" else self.held_sim

    def weighted(self, seg_sigma: dict[str, np.ndarray]) -> "Split":
        """The same split with per-segment residual scales (the simulators are shared)."""
        return Split(self.fit_sim, self.held_sim, seg_sigma, self.settle)

    def settled(self, decay_times: float) -> "Split":
        """The same split, every segment started from the state consistent with the model evaluated."""
        return Split(self.fit_sim, self.held_sim, self.seg_sigma, decay_times)

    def n_segments(self, part: str) -> int:
        return int(np.sum(self.sim_for(part).segment_mask(part)))


def evaluate(split: Split, model: Model, thetas: np.ndarray, part: str = "fit") -> np.ndarray:
    """Weighted residuals (m, n) of a batch of scaled parameter vectors."""
    sim = split.sim_for(part)
    params, meas = model.build(thetas)
    use_meas = meas if np.any(meas != 0) else None
    tv = model.tv(np.atleast_2d(thetas), sim) if model.tv is not None else None
    out = sim.simulate(params, use_meas, time_varying=tv, settle=split.settle)
    r = sim.residuals(out, part)
    if split.seg_sigma is not None:
        r = r / _per_sample(split.seg_sigma[part], r.shape[1])[None, :]
    return np.nan_to_num(r, nan=1e3, posinf=1e3, neginf=-1e3)


def _per_sample(seg_values: np.ndarray, n_res: int) -> np.ndarray:
    """(n_res,) per-residual values from (n_seg,) per-segment values; residuals are laid out as
    signal-major blocks of (n_seg, n_eval) (see :meth:`SegmentSimulator.residuals`)."""
    n_seg = len(seg_values)
    n_eval = n_res // (len(SIGNALS) * n_seg)
    return np.tile(np.repeat(seg_values, n_eval), len(SIGNALS))


def segment_rss(r: np.ndarray, n_seg: int) -> np.ndarray:
    """(n_seg,) squared error of each segment from one residual vector (n_res,)."""
    return np.sum(r.reshape(len(SIGNALS), n_seg, -1) ** 2, axis=(0, 2))


def segment_delta_bic(rss_new: np.ndarray, rss_ref: np.ndarray, n_seg_eff: float, k: int) -> float:
    """BIC change of a model over a reference with one residual variance per segment (profiled out).

    -2 log-likelihood ratio of a Gaussian whose variance differs between segments and is estimated in
    each: n_seg_eff sum_s log(RSS_s(new) / RSS_s(ref)); plus k log(n_seg_eff n_seg) for k extra parameters.

    Args:
        rss_new, rss_ref: (n_seg,) squared error of each segment under the model and the reference.
        n_seg_eff: effective (independent) samples in one segment.
        k: number of extra free parameters.
    """
    ratio = np.maximum(rss_new, 1e-300) / np.maximum(rss_ref, 1e-300)
    n = max(n_seg_eff * len(rss_new), 10.0)
    return float(n_seg_eff * np.sum(np.log(ratio)) + k * np.log(n))


#: Floor of a segment's residual scale, as a multiple of the median segment's: a segment is never
#: weighted above a typical one (a segment that happens to fit well carries no more information than a
#: typical one, its small residual is partly luck), only segments whose residual is larger than typical
#: are down-weighted (their variance is larger: start-up transients, stroke ends, stick-slip).
SEGMENT_SIGMA_FLOOR = 1.0


def segment_scales(split: Split, model: Model, theta: np.ndarray) -> dict[str, np.ndarray]:
    """Per-segment residual scales (RMS of the weighted residual) of a reference fit, part -> (n_seg,).

    A feasible generalised-least-squares step: the variance of each segment is estimated once from the
    reference model, then candidate models are compared under it. The scale is floored at
    :data:`SEGMENT_SIGMA_FLOOR` times the median over the part's segments.
    """
    out = {}
    for part in ("fit", "held"):
        r = evaluate(split, model, theta[None, :], part)[0]
        n_seg = split.n_segments(part)
        rms = np.sqrt(segment_rss(r, n_seg) / (r.size / n_seg))
        out[part] = np.maximum(rms, SEGMENT_SIGMA_FLOOR * np.median(rms))
    return out


def fit(sim: Split, model: Model, starts: list[np.ndarray], max_nfev: int = 40,
        families: list[list[int]] | None = None) -> FitResult:
    """Least-squares fit from the best of several starts (evaluated as one batch).

    ``families`` (optional): the starts' indices grouped into families (forms of the effect between
    which one optimiser run cannot move); the best start of each is optimised and the lowest squared
    error wins. None: one family, one optimiser run."""
    lo = np.array([f.theta_bounds[0] for f in model.free])
    hi = np.array([f.theta_bounds[1] for f in model.free])
    starts = np.clip(np.atleast_2d(np.array(starts)), lo, hi)
    r0 = evaluate(sim, model, starts)
    costs = np.sum(r0 ** 2, axis=1)
    if not starts.shape[1]:
        return at(sim, model, starts[0], 1)
    cache: dict = {}

    def fun(th):
        r = evaluate(sim, model, th[None, :])[0]
        cache["r"] = (th.copy(), r)
        return r

    def jac(th):
        k = len(th)
        steps = np.where(th + FD_STEP <= hi, FD_STEP, -FD_STEP)
        cands = np.repeat(th[None, :], k + 1, axis=0)
        cands[1:][np.arange(k), np.arange(k)] += steps
        if "r" in cache and np.array_equal(cache["r"][0], th):
            r = evaluate(sim, model, cands[1:])
            r_base = cache["r"][1]
        else:
            rr = evaluate(sim, model, cands)
            r_base, r = rr[0], rr[1:]
        return ((r - r_base[None, :]) / steps[:, None]).T

    best, nfev = None, 0
    for family in families or [range(len(starts))]:
        x0 = starts[min(family, key=lambda i: costs[i])]
        # trf takes the SVD of J (about 10^4 x 10) at each step: threaded BLAS splits so thin a matrix
        # badly (measured 4.9 ms on one thread, 91 ms on two with the cores busy, same result). A
        # parameter without gradient (a pump the valve cannot outdraw) makes trf's trust-region sub-problem
        # overflow or divide by zero, which its iteration guards against: the warnings would only alarm the user
        with threadpool_limits(limits=1, user_api="blas"), np.errstate(all="ignore"):
            res = least_squares(fun, x0, jac=jac, bounds=(lo, hi), method="trf", max_nfev=max_nfev,
                                x_scale=1.0, diff_step=None)
        nfev += res.nfev
        if best is None or res.cost < best.cost:
            best = res
    return at(sim, model, best.x, nfev)


def at(split: Split, model: Model, theta: np.ndarray, nfev: int = 0) -> FitResult:
    """The model at one scaled parameter vector ``theta``, as a :class:`FitResult` (no fitting)."""
    lo = np.array([f.theta_bounds[0] for f in model.free])
    hi = np.array([f.theta_bounds[1] for f in model.free])
    params, meas = model.build(theta[None, :])
    both = evaluate(split, model, theta[None, :], "fit")[0], evaluate(split, model, theta[None, :], "held")[0]
    span = hi - lo
    at_bounds = [f.name for f, t, a, b, s in zip(model.free, theta, lo, hi, span)
                 if (t - a) < 0.005 * s or (b - t) < 0.005 * s]
    return FitResult(model.free, model.values_of(theta), params[0], meas[0], float(np.sum(both[0] ** 2)),
                     float(np.sum(both[1] ** 2)), both[0].size, both[1].size, at_bounds, nfev)


def unweighted(split: Split, res: FitResult) -> FitResult:
    """``res`` with its squared errors on ``split`` without per-segment scales, comparable with
    every other fit's."""
    plain = Split(split.fit_sim, split.held_sim, settle=split.settle)
    model = Model(res.params, (), res.meas)
    none = np.zeros((1, 0))
    rss = [float(np.sum(evaluate(plain, model, none, part)[0] ** 2)) for part in ("fit", "held")]
    return replace(res, rss_fit=rss[0], rss_held=rss[1])


def fit_by_segment(split: Split, model: Model, starts: list[np.ndarray], max_nfev: int, rounds: int,
                   round_nfev: int, families: list[list[int]] | None = None) -> FitResult:
    """Least squares with one residual variance per segment, by iterative reweighting.

    A pooled least-squares fit is steered by the segments with the largest error, and a segment's
    error is often not the parameters' doing: a lightly damped hydraulic mode rings from an
    imperfect start state (the recording's first sample, a start in stick-slip) for most of a
    segment. The commissioning parameters can partly fit such ringing, which then moves them away
    from the values that predict the other segments (the held-out fit falls). Each round
    re-estimates every segment's residual scale from the current fit (:func:`segment_scales`, the
    noise model the acceptance judges with) and fits again from there, ``round_nfev`` evaluations at
    most. An already weighted ``split`` (the second round's) is fitted as given. The squared errors
    of the result are unweighted. ``families``: as for :func:`fit` (the first fit only; the rounds
    refine its winner).
    """
    res = fit(split, model, starts, max_nfev=max_nfev, families=families)
    if split.seg_sigma is not None or not len(model.free):
        return res
    for _ in range(rounds):
        th = model.theta_of(res.values)
        res = fit(split.weighted(segment_scales(split, model, th)), model, [th], max_nfev=round_nfev)
    return unweighted(split, res)


def correlation_time(r: np.ndarray, n_blocks: int, max_lag: int = 200) -> float:
    """Integrated autocorrelation time [samples] of residuals laid out as (n_blocks) rows."""
    r = r.reshape(n_blocks, -1)
    r = r - r.mean(axis=1, keepdims=True)
    var = np.mean(r * r)
    if var == 0:
        return 1.0
    tau = 1.0
    for k in range(1, min(max_lag, r.shape[1] - 1)):
        rho = np.mean(r[:, k:] * r[:, :-k]) / var
        if rho < 0.05:
            break
        tau += 2 * rho
    return float(max(tau, 1.0))
