"""The change tests: residuals of the filter's fault estimates and their CUSUM statistics.

Per fault parameter p, the change residual d_p = (estimate - healthy baseline) / spread, the
spread sqrt((w sd_filter)^2 + sigma_regime^2) (:func:`change_spread`); the baseline is the
recording's own estimate over its baseline window (:func:`own_baseline`) or a healthy reference's.
Per hypothesis a one-sided CUSUM in continuous time, ``g <- max(0, g exp(-dt / memory) + (r -
drift) dt)``, held in regimes where the residual does not vote and where its parameter cannot show
(:mod:`fdi.conditions`); the notch-flow trigger is a sixth test (:func:`notch_jump`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numba
import numpy as np

from .conditions import (
    WANDERING, baseline_window, before_motion, held, long_stroke_mask, regimes,
)
from .faults import HYPOTHESES, NOTCH_STATES, NOTCH_TRIGGER, PARAMS
from .filter import FilterOutput, sample_step
from .states import N_AUG
from .strokes import after_long_segment
from .thresholds import Thresholds

RESIDUAL_NAMES = ("nu_pA", "nu_pB", "nu_pos") + tuple(f"r_{h}" for h in HYPOTHESES)
#: the parameters whose baselines are re-learnt after a withdrawn alarm (:func:`restarted`):
#: those whose estimates wander with the operating point. An external leak's excursion the bank could not confirm is
#: either gone soon or too small to show in its window; a re-learnt baseline would hide it for good.
REBASE_PARAMS = WANDERING


@dataclass(frozen=True)
class Statistics(Mapping):
    """The change tests' statistics of B runs: test -> (B, T), the CUSUM of each hypothesis
    [sigma s] and, when it runs, the notch-flow trigger's jump [sigma]. A test alarms where its
    statistic exceeds its threshold h."""

    g: dict  #: test name -> (B, T)
    start: np.ndarray  #: (B,) the sample each run's tests started from (the warm-up, or a restart)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.g[name]

    def __iter__(self):
        return iter(self.g)

    def __len__(self) -> int:
        return len(self.g)


def own_baseline(out: FilterOutput, th: Thresholds, hidden: np.ndarray | None = None):
    """The recording's own healthy baseline: (B, 4) the mean of each fault estimate over its
    baseline window (fdi.conditions.baseline_window: not where it is ``hidden`` (B, 4, T), nor
    before the first motion), and the samples at which its test is armed (B, 4, T)."""
    hidden = held(out, th) if hidden is None else hidden
    w, ready = baseline_window(out.t, hidden | before_motion(out, th)[:, None, :], th)
    est = np.stack([out.mean[:, :, j] for j in PARAMS.values()], axis=1)
    return np.where(w, est, 0.0).sum(axis=2) / np.maximum(w.sum(axis=2), 1), ready


def baseline_values(out: FilterOutput, th: Thresholds, hidden: np.ndarray | None = None) -> np.ndarray:
    """(B, 4) the baseline of :func:`own_baseline`."""
    return own_baseline(out, th, hidden)[0]


def change_spread(sd_filter: np.ndarray, sigma: np.ndarray, w: float) -> np.ndarray:
    """The spread a change residual is counted in, sqrt((w sd_filter)^2 + sigma^2): the filter's
    std of the estimate weighted by w and the regime's healthy spread sigma (same units)."""
    return np.maximum(np.sqrt((w * sd_filter) ** 2 + sigma**2), 1e-300)


def masks(out: FilterOutput, th: Thresholds, baseline=None):
    """(regime (B, T), held (B, 4, T), baseline (B, 4), armed (B, 4, T)) of the change tests;
    ``baseline`` (B, 4) or None (the recording's own)."""
    dt = sample_step(out.t)
    r = th.regimes
    reg = (regimes(out.u, dt, r.band_V, r.transient_s) if out.u is not None
           else np.full(out.mean.shape[:2], 2, np.int8))
    hidden = held(out, th)
    if baseline is None:
        base, ready = own_baseline(out, th, hidden)
    else:
        base = np.broadcast_to(np.atleast_2d(baseline), (out.mean.shape[0], 4))
        ready = np.broadcast_to(out.t >= th.window.warmup_s, hidden.shape)
    return reg, hidden, base, ready


def change_residuals(out: FilterOutput, th: Thresholds, baseline=None) -> tuple[dict, np.ndarray, np.ndarray]:
    """Change residuals d_<param> name -> (B, T) (0 before the test is armed), the regime (B, T)
    and where each test is held (B, 4, T)."""
    reg, hidden, base, ready = masks(out, th, baseline)
    return _changes(out, th, reg, base, ready), reg, hidden


def _changes(out: FilterOutput, th: Thresholds, reg, base, ready) -> dict:
    t = th.test
    res = {}
    for i, (name, j) in enumerate(PARAMS.items()):
        sd = change_spread(out.std[:, :, j], np.asarray(t.sigma[name], dtype=float)[reg], t.sd_weight(name))
        res[name] = np.where(ready[:, i], (out.mean[:, :, j] - base[:, i:i + 1]) / sd, 0.0)
    return res


def tested_seconds(out: FilterOutput, th: Thresholds, baseline=None) -> np.ndarray:
    """(B, 4) seconds in which each parameter's change test ran: armed, voting in the regime, not
    held. A parameter tested for less than Window.min_tested_s was not looked at."""
    dt = sample_step(out.t)
    reg, hidden, _, ready = masks(out, th, baseline)
    votes = np.stack([np.asarray(th.test.votes[p], dtype=bool)[reg] for p in PARAMS], axis=1)
    warm = out.t >= th.window.warmup_s
    return (ready & ~hidden & votes & warm).sum(axis=2) * dt


def residuals(out: FilterOutput, th: Thresholds | None = None, baseline=None) -> dict[str, np.ndarray]:
    """All residuals, name -> (B, T): the normalised innovations nu_*, each fault estimate against
    0 in units of sqrt(sd^2 + nuisance_sd^2), r_<hypothesis>, and with thresholds the change
    residuals d_<param>, the regime, the held samples and the long-stroke samples (0 / 1)."""
    res = {"nu_pA": out.nu[:, :, 0], "nu_pB": out.nu[:, :, 1], "nu_pos": out.nu[:, :, 2]}
    for name, (j, sign) in HYPOTHESES.items():
        extra = 0.0 if th is None else th.test.nuisance_sd.get(name.rstrip("+-"), 0.0)
        sd = np.maximum(np.sqrt(out.std[:, :, j] ** 2 + extra**2), 1e-300)
        res[f"r_{name}"] = sign * out.mean[:, :, j] / sd  # healthy value is 0 for every fault
    if th is not None:
        chg, reg, hidden = change_residuals(out, th, baseline)
        for name, r in chg.items():
            res[f"d_{name}"] = r
        res["regime"] = reg.astype(float)
        res["pinned"] = hidden.any(axis=1).astype(float)
        res["long_stroke"] = long_stroke_mask(out, th).astype(float)
    return res


def cusum(r: np.ndarray, drift: float | np.ndarray, dt: float, warmup: int | np.ndarray = 0,
          active: np.ndarray | None = None, memory_s: float | None = None) -> np.ndarray:
    """Continuous-time one-sided CUSUM of r (B, T) [sigma s] with memory ``memory_s`` [s] (None:
    none forgotten), held where ``active`` is False: g_k = max(0, a g_(k-1) + (r_k - drift_k) dt),
    a = exp(-dt / memory_s), for k >= warmup (a sample, or one per run (B,)), g = 0 before. A
    constant r > drift brings g to (r - drift) memory_s."""
    excess = r - drift
    # a NaN residual (a gap) counts as r = 0: the statistic decays, it does not jump
    inc = np.ascontiguousarray(np.where(np.isnan(excess), -np.broadcast_to(drift, excess.shape), excess) * dt,
                               dtype=float)
    act = np.ones(inc.shape, dtype=bool) if active is None else np.ascontiguousarray(np.broadcast_to(active, inc.shape))
    keep = 1.0 if memory_s is None else math.exp(-dt / memory_s)
    start = np.ascontiguousarray(np.broadcast_to(np.asarray(warmup, dtype=np.int64), inc.shape[:1]))
    return _cusum_recursion(inc, act, keep, start)


@numba.njit(cache=True)
def _cusum_recursion(inc, active, keep, start):
    """g[b, k] = max(0, keep g[b, k-1] + inc[b, k]) where active, g[b, k-1] where not, from
    k = start[b] on (0 before)."""
    B, T = inc.shape
    g = np.zeros((B, T))
    for b in range(B):
        acc = 0.0
        for k in range(max(0, start[b]), T):
            if active[b, k]:
                acc = max(0.0, keep * acc + inc[b, k])
            g[b, k] = acc
    return g


def cusum_drift(param: str, long_stroke: np.ndarray, th: Thresholds) -> float | np.ndarray:
    """The CUSUM drift [sigma] of ``param``'s test: ``long_stroke_drift`` on the long-stroke
    samples (B, T) if the parameter still wanders there (``long_stroke_params``), else ``drift``."""
    t = th.test
    if param not in t.long_stroke_params or not long_stroke.any():
        return t.drift
    return np.where(long_stroke, t.long_stroke_drift, t.drift)


def statistics(out: FilterOutput, th: Thresholds, baseline=None, start: np.ndarray | None = None) -> Statistics:
    """The change tests of the filter output ``out``: a CUSUM per hypothesis on its change
    residual and, with its threshold and the notch-flow states, the notch-flow trigger.
    ``baseline`` (B, 4): healthy values of the fault parameters (None: the recording's own);
    ``start`` (B,): samples at which each run's tests restart from 0 (never before the warm-up)."""
    dt = sample_step(out.t)
    warm = int(round(th.window.warmup_s / dt))
    if start is not None:
        warm = np.maximum(warm, np.asarray(start, dtype=np.int64))
    reg, hidden, base, ready = masks(out, th, baseline)
    chg = _changes(out, th, reg, base, ready)
    long_stroke = long_stroke_mask(out, th)
    g = {}
    for h, (j, sign) in HYPOTHESES.items():
        param = h.rstrip("+-")
        active = np.asarray(th.test.votes[param], dtype=bool)[reg] & ~hidden[:, list(PARAMS).index(param)]
        g[h] = cusum(sign * chg[param], cusum_drift(param, long_stroke, th), dt, warm, active, th.test.memory_s)
    if uses_notch_trigger(out, th):
        g[NOTCH_TRIGGER] = notch_jump(out, th, notch_armed(out, th, ready), warm)
    return Statistics(g, np.broadcast_to(np.asarray(warm, dtype=np.int64), out.mean.shape[:1]).copy())


def restarted(out: FilterOutput, th: Thresholds, start: np.ndarray, baseline=None) -> Statistics:
    """The statistics with each run b whose start[b] > 0 restarted there (after a withdrawn
    alarm), the baselines of :data:`REBASE_PARAMS` re-learnt as its mean estimates over the
    ``rebase_s`` before the restart: the bank has just judged that excursion healthy. The other
    baselines: ``baseline`` (B, 4), or the recording's own. Every run over the whole record: the
    definition; :func:`restart` computes the restarted runs alone, from their restarts on."""
    dt = sample_step(out.t)
    n = max(1, int(round(th.test.rebase_s / dt)))
    B = out.mean.shape[0]
    base = np.array(baseline_values(out, th) if baseline is None else np.broadcast_to(np.atleast_2d(baseline), (B, 4)),
                    dtype=float)
    cols = list(PARAMS.values())
    relearn = [i for i, p in enumerate(PARAMS) if p in REBASE_PARAMS]
    for b in np.flatnonzero(start > 0):
        base[b, relearn] = out.mean[b, max(0, start[b] - n):start[b]][:, cols].mean(axis=0)[relearn]
    return statistics(out, th, base, start)


@dataclass(frozen=True)
class RestartBasis:
    """What every restart of the change tests of one filter output (B runs, T samples) shares:
    the parts of :func:`restarted` that depend neither on where a test restarts nor on its
    baselines, computed once (:func:`restart_basis`) and sliced at each restart (:func:`restart`)."""

    mean: np.ndarray  #: (B, T, n) the filter's posterior means (SI)
    spread: dict  #: parameter -> (B, T) its change residual's spread (:func:`change_spread`, SI)
    active: dict  #: hypothesis -> (B, T) bool, where its CUSUM runs (votes in the regime, not held)
    drift: dict  #: parameter -> its CUSUM drift [sigma]: a number, or (B, T)
    armed: np.ndarray  #: (T,) bool, where a restarted change test is armed: from the warm-up on
    base: np.ndarray  #: (B, 4) the baselines a restart keeps (PARAMS order, SI)
    notch: np.ndarray | None  #: (B, T) the notch-flow trigger from sample 0 [sigma] (None: not run)
    notch_window: int  #: samples of the trigger's jump window
    warm: int  #: samples of the warm-up, before which no test runs
    rebase: int  #: samples a re-learnt baseline is averaged over (``rebase_s``)
    dt: float  #: s, the sample step
    memory_s: float | None  #: s, the CUSUM's memory


def restart_basis(out: FilterOutput, th: Thresholds, baseline=None) -> RestartBasis:
    """The :class:`RestartBasis` of ``out`` under ``th``; ``baseline`` (B, 4) as given to
    :func:`restarted` (None: the recording's own)."""
    dt = sample_step(out.t)
    t = th.test
    reg, hidden, base, _ = masks(out, th, baseline)
    armed = out.t >= th.window.warmup_s  # a restart's baselines are given: armed after the warm-up
    long_stroke = long_stroke_mask(out, th)
    spread = {p: change_spread(out.std[:, :, j], np.asarray(t.sigma[p], dtype=float)[reg], t.sd_weight(p))
              for p, j in PARAMS.items()}
    active = {h: np.asarray(t.votes[h.rstrip("+-")], dtype=bool)[reg] & ~hidden[:, list(PARAMS).index(h.rstrip("+-"))]
              for h in HYPOTHESES}
    notch = None
    if uses_notch_trigger(out, th):
        notch = notch_jump(out, th, notch_armed(out, th, np.broadcast_to(armed, hidden.shape)))
    return RestartBasis(out.mean, spread, active, {p: cusum_drift(p, long_stroke, th) for p in PARAMS}, armed,
                        np.array(base, dtype=float), notch, max(1, int(round(t.notch_jump_window_s / dt))),
                        int(round(th.window.warmup_s / dt)), max(1, int(round(t.rebase_s / dt))), dt, t.memory_s)


def rebased(basis: RestartBasis, rows: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(n, 4) the baselines of runs ``rows`` (n,) restarted at samples ``start`` (n,): those of
    :data:`REBASE_PARAMS` their mean estimates over the ``rebase_s`` before the restart (where
    start > 0), the others kept."""
    base = basis.base[rows].copy()
    cols = list(PARAMS.values())
    relearn = [i for i, p in enumerate(PARAMS) if p in REBASE_PARAMS]
    for q, (b, s) in enumerate(zip(rows, start)):
        if s > 0:
            base[q, relearn] = basis.mean[b, max(0, s - basis.rebase):s][:, cols].mean(axis=0)[relearn]
    return base


def restart(basis: RestartBasis, rows, start) -> Statistics:
    """:func:`restarted` for runs ``rows`` (n,) restarted at samples ``start`` (n,), computed for
    those runs alone and from the earliest restart on (the CUSUM is causal and starts from 0):
    test -> (B, T), 0 in the other runs and before each run's restart (never before the warm-up)."""
    rows, start = np.asarray(rows, dtype=np.int64), np.asarray(start, dtype=np.int64)
    B, T = basis.mean.shape[:2]
    warm = np.maximum(basis.warm, start)
    s0 = int(warm.min()) if len(rows) else T
    base = rebased(basis, rows, start)
    chg = {p: np.where(basis.armed[s0:], (basis.mean[rows, s0:, j] - base[:, i:i + 1]) / basis.spread[p][rows, s0:], 0.0)
           for i, (p, j) in enumerate(PARAMS.items())}
    part = {}
    for h, (_, sign) in HYPOTHESES.items():
        p = h.rstrip("+-")
        drift = basis.drift[p] if np.ndim(basis.drift[p]) == 0 else basis.drift[p][rows, s0:]
        part[h] = cusum(sign * chg[p], drift, basis.dt, warm - s0, basis.active[h][rows, s0:], basis.memory_s)
    if basis.notch is not None:
        after = np.arange(s0, T)[None, :] >= (warm + basis.notch_window)[:, None]
        part[NOTCH_TRIGGER] = np.where(after, basis.notch[rows, s0:], 0.0)
    g = {}
    for h, gh in part.items():
        g[h] = np.zeros((B, T))
        g[h][rows, s0:] = gh
    runs_start = np.full(B, basis.warm, dtype=np.int64)
    runs_start[rows] = warm
    return Statistics(g, runs_start)


def notch_armed(out: FilterOutput, th: Thresholds, ready: np.ndarray) -> np.ndarray:
    """(B, T) where the notch-flow trigger is armed: every change test armed (``ready`` (B, 4, T))
    and not within ``transient_s`` of a stroke after a rest or a stroke the other way of at least
    ``notch_rest_s`` (everywhere without the input)."""
    armed = ready.all(axis=1)
    if out.u is None:
        return armed
    r = th.regimes
    return armed & ~after_long_segment(out.u, sample_step(out.t), r.band_V, th.test.notch_rest_s, r.transient_s)


def uses_notch_trigger(out: FilterOutput, th: Thresholds) -> bool:
    """Whether the notch-flow trigger runs: the thresholds have its h and the filter has notch-flow states."""
    return NOTCH_TRIGGER in th.test.h and has_notch_states(out)


def has_notch_states(out: FilterOutput) -> bool:
    """Whether the filter that made ``out`` estimates the notch flows (fdi.faults.NOTCH_STATES)."""
    return all(n in out.config.calibration.states for n in NOTCH_STATES)


def notch_jump(out: FilterOutput, th: Thresholds, armed: np.ndarray, start=0) -> np.ndarray:
    """The notch-flow trigger's statistic (B, T) [sigma]: the largest jump of a notch-flow state
    over the last ``notch_jump_window_s``, in its posterior std at the window's start, less
    ``drift`` (0 below); 0 where not ``armed`` and before ``start`` + the window. A fault that
    begins in a steady stroke changes the flow balance as a notch-flow error does, and the filter
    often puts the change on the notch states first; a healthy machine's notch states only learn,
    by about their std. The trigger says only *when*: the bank names the fault, or withdraws it."""
    dt = sample_step(out.t)
    w = max(1, int(round(th.test.notch_jump_window_s / dt)))
    cols = [N_AUG + out.config.calibration.states.index(n) for n in NOTCH_STATES]
    z, sd = out.mean[:, :, cols], out.std[:, :, cols]
    jump = np.zeros(out.mean.shape[:2])
    if out.mean.shape[1] > w:
        jump[:, w:] = (np.abs(z[:, w:] - z[:, :-w]) / np.maximum(sd[:, :-w], 1e-300)).max(axis=2)
    k = np.arange(jump.shape[1])
    after = k[None, :] >= np.reshape(np.asarray(start, dtype=np.int64), (-1, 1)) + w
    return np.where(armed & after, np.maximum(jump - th.test.drift, 0.0), 0.0)
