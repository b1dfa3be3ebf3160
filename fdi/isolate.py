"""Isolation and sizing by likelihood: a bank of constrained filters after an alarm.

The detection filter and its CUSUM alarms (:mod:`fdi.detect`) say *that* a fault parameter
changed; this stage says *which* one, the multiple-model / GLR idea. For a run that alarmed
at sample k_a:

1. **onset estimate** k0: one past the last zero of the first alarming CUSUM statistic
   before k_a (its change-time estimate), ``ONSET_LEAD_S`` earlier, never before the end of
   the healthy baseline window;
2. **healthy reference**: the ``calibrated`` filter (:data:`REFERENCE`, whatever filter
   detected) run over [0, k0] with every fault parameter held at its healthy nominal value
   (0 leak, the plant's offset; no process noise, a tiny prior). Its calibration states
   (load mass, B_eff, notch flows) then learn the nuisance without being able to trade it
   against a fault state. (Measured: seeding
   the bank from the *detection* filter's own state at k0 holds its pre-onset offset error,
   +0.4 % on the nominal plant, in every leak hypothesis, and a 1 L/min K_int is taken for
   offset- by thousands of nats; docs/fdi.md, "Session 6".)
3. **bank**: one filter per hypothesis H of :data:`BANK`, started at k0 from the reference's
   mean and variances, the reference's calibration values written into the parameter
   vector, in which ONLY the parameter of H is free (a constant with the prior
   :data:`PRIOR_SD`), the other faults stay at their healthy values. All hypotheses of all
   runs go through ONE :func:`fdi.ukf.run_filter` call (B = runs x hypotheses).
4. **decision**: with L_H(k) = sum_{i=k0..k} log N(nu_H,i; 0, S_H,i), the innovation
   log-likelihood of filter H, the fault is isolated as H at the first k >= k_a at which
   L_H(k) exceeds every other fault hypothesis by ``margin`` nats (causal: data up to k).
   Otherwise "not isolable", with the hypotheses within the margin of the best.
5. **size**: the free parameter of the isolated hypothesis' filter at the end of its window
   (the estimate of a constant from all the window's data), minus its healthy value.

The margin is not fitted: with equal prior probabilities, the posterior probability of the
best of n hypotheses is at least 1 / (1 + (n - 1) e^-margin); :func:`margin_for` gives the
margin of a stated false-isolation level (``FALSE_ISOLATION_LEVEL``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .ukf import (
    I_KEXTA, I_KEXTB, I_KINT, I_OFFSET, K_PER_LPM, N_AUG, N_MODEL, PRESETS, SCALE, FilterConfig,
    FilterOutput, param_layout, run_filter, state_scale,
)

#: The filter whose calibration states learn the nuisance before the onset (docs/fdi.md,
#: session 4: load mass, B_eff and the four notch flows); its fault states are held.
REFERENCE = PRESETS["calibrated"]
#: Hypotheses of the bank: name -> the state left free (None: the healthy hypothesis).
BANK = {"none": None, "K_int": I_KINT, "K_extA": I_KEXTA, "K_extB": I_KEXTB, "offset": I_OFFSET}
FAULTS = tuple(h for h, j in BANK.items() if j is not None)
FAULT_IDX = (I_KINT, I_KEXTA, I_KEXTB, I_OFFSET)
#: Prior std of the free fault parameter (SI): the largest leak of the issue's grid (1 L/min)
#: and the offset that changes the pressures as much (2 %). Measured: scaling both by 0.1 or
#: 0.3 changes no decision (the likelihood gaps are tens to thousands of nats).
PRIOR_SD = {I_KINT: 1.0 * K_PER_LPM, I_KEXTA: 1.0 * K_PER_LPM, I_KEXTB: 1.0 * K_PER_LPM, I_OFFSET: 0.02}
#: Relative prior std of a held fault state in the reference filter (x its detection p0):
#: small enough that it does not move, large enough for a well-conditioned covariance.
HELD_P0_FACTOR = 1e-6
#: Variance of a held state in the bank (scaled units), as in the detection filter's freeze.
FROZEN_VAR = 1e-12
#: s: the bank starts this long before the CUSUM change-time estimate: the change residual
#: needs a few tenths of a second to leave 0 after a step (the filter's response), and an
#: early start only adds healthy samples, the same for every hypothesis.
ONSET_LEAD_S = 0.25
#: s: the bank runs at most this long after the alarm (replay): the isolation target counts
#: 1 s, the size is read over the last SIZE_WINDOW_S of it, and on a long recording a bank run
#: to the end would cost 5 filters for the rest of the record.
DECISION_WINDOW_S = 1.0
#: Stated false-isolation level: the probability, under the model, that the isolated
#: hypothesis is not the one that produced the data.
FALSE_ISOLATION_LEVEL = 0.01


def margin_for(level: float = FALSE_ISOLATION_LEVEL, n_hypotheses: int = len(FAULTS)) -> float:
    """Log-likelihood margin [nats] such that, with equal priors, the best hypothesis has
    posterior >= 1 - level when it beats each of the other n - 1 by the margin:
    1 / (1 + (n - 1) e^-margin) >= 1 - level  <=>  margin = ln((n - 1) (1 - level) / level)."""
    return math.log((n_hypotheses - 1) * (1.0 - level) / level)


def reference_config(base: FilterConfig = REFERENCE) -> FilterConfig:
    """The healthy reference: ``base`` with every fault parameter held at its healthy value
    (no process noise, prior std x HELD_P0_FACTOR)."""
    q, p0 = list(base.q), list(base.p0)
    for j in FAULT_IDX:
        q[j] = 0.0
        p0[j] *= HELD_P0_FACTOR
    return base.with_(q=tuple(q), p0=tuple(p0))


def bank_config(detect: FilterConfig = REFERENCE) -> FilterConfig:
    """The constrained filters: the reference filter's measurement model and model-state
    noise, no calibration states (their reference values are written into the parameter
    vector), fault parameters constant (q = 0; the free one gets a prior), no divergence
    resets (a wrong hypothesis must keep its large innovations)."""
    q = list(detect.q[:N_AUG])
    for j in FAULT_IDX:
        q[j] = 0.0
    return replace(PRESETS["shipped"], q=tuple(q), p0=detect.p0[:N_AUG], pressure_noise=detect.pressure_noise,
                   x_noise=detect.x_noise, theta_pulse=detect.theta_pulse,
                   theta_noise_floor=detect.theta_noise_floor, alpha=detect.alpha, beta=detect.beta,
                   kappa=detect.kappa, calibrate=(), disturb=(), freeze_calib_s=None,
                   constraint="project", clip_leaks=True, nis_factor=0.0)


def onset_index(g: np.ndarray, k_alarm: int, k_ready: int, dt: float) -> int:
    """Change-time estimate of a CUSUM g (T,) that alarmed at k_alarm: one past its last
    zero before the alarm, minus ONSET_LEAD_S, not before k_ready (the end of the healthy
    baseline) and never after the alarm."""
    zeros = np.flatnonzero(g[:k_alarm + 1] <= 0.0)
    k = zeros[-1] + 1 if len(zeros) else 0
    return int(min(k_alarm, max(k_ready, k - int(round(ONSET_LEAD_S / dt)))))


def _rows(inp, rows: np.ndarray, k0: int, k1: np.ndarray, L: int):
    """The input of runs ``rows`` over [k0, k1) padded to L samples (input held, nothing
    measured after k1): a FilterInput-like dict of arrays (len(rows), L)."""
    n = len(rows)
    out = {}
    for name in ("u", "pA", "pB", "pos", "pS"):
        src = getattr(inp, name)
        if src is None:
            out[name] = None
            continue
        a = np.full((n, L), np.nan)
        for i, (b, ka, kb) in enumerate(zip(rows, k0, k1)):
            a[i, :kb - ka] = src[b, ka:kb]
            if name == "u":
                a[i, kb - ka:] = src[b, kb - 1]
        out[name] = a
    return out


def run_reference(out: FilterOutput, rows: np.ndarray, k_end: np.ndarray) -> FilterOutput:
    """The healthy reference filter of runs ``rows`` over [0, max k_end) (one batched call)."""
    inp = out.inp
    L = int(max(1, np.max(k_end)))
    seg = _rows(inp, rows, np.zeros(len(rows), dtype=np.int64), np.minimum(k_end, inp.u.shape[1]), L)
    sub = replace(inp, params=inp.params[rows], **seg)
    return run_filter(sub, reference_config(), n_steps=np.minimum(k_end, inp.u.shape[1]))


@dataclass
class BankResult:
    """Per run of the bank (n runs, hypotheses in BANK order, L samples from k0)."""

    k0: np.ndarray  #: (n,) start index of each run's bank in the recording
    loglik: np.ndarray  #: (n, H, L) cumulative innovation log-likelihood from k0 (scaled units)
    free: np.ndarray  #: (n, H, L) estimate of each hypothesis' free parameter (SI; NaN for "none")
    free_sd: np.ndarray  #: (n, H, L)
    healthy: np.ndarray  #: (n, H) healthy value of each hypothesis' free parameter (SI)
    n_valid: np.ndarray  #: (n,) samples inside each run's window
    names: tuple = tuple(BANK)  #: the hypotheses, in the order of axis 1


def run_bank(out: FilterOutput, ref: FilterOutput, rows: np.ndarray, k0: np.ndarray, k1: np.ndarray,
             hypotheses: tuple = tuple(BANK), ref_rows: np.ndarray | None = None) -> BankResult:
    """The hypothesis bank of runs ``rows`` of the detection output ``out``, run i over
    samples [k0[i], k1[i]), seeded from row ``ref_rows[i]`` (default i) of the reference
    ``ref`` at k0[i]; ONE run_filter call for all runs and ``hypotheses`` (names of BANK)."""
    inp, det = out.inp, ref.config
    rows, k0, k1 = (np.asarray(a, dtype=np.int64) for a in (rows, k0, k1))
    ref_rows = np.arange(len(rows)) if ref_rows is None else np.asarray(ref_rows)
    n, H = len(rows), len(hypotheses)
    frees = [BANK[name] for name in hypotheses]
    L = int(max(1, (k1 - k0).max()))
    cols, rel = param_layout(det)
    sc = state_scale(det)[:N_AUG]
    seg = _rows(inp, rows, k0, k1, L)
    params = np.empty((n, inp.params.shape[1]))
    z0 = np.empty((n, N_AUG))
    var = np.empty((n, N_AUG))
    for i, (b, ka) in enumerate(zip(rows, k0)):
        mean = ref.mean[ref_rows[i], ka]
        params[i] = inp.params[b]
        for a in range(len(cols)):  # calibration states -> the parameter vector
            if rel[a]:
                params[i, cols[a]] = inp.params[b, cols[a]] * (1.0 + max(mean[N_MODEL + a], -0.95))
        z0[i] = mean[:N_AUG] / sc
        var[i] = (ref.std[ref_rows[i], ka, :N_AUG] / sc) ** 2
    P0 = np.zeros((n, H, N_AUG, N_AUG))
    for h, free in enumerate(frees):
        d = var.copy()
        d[:, list(FAULT_IDX)] = FROZEN_VAR
        if free is not None:
            d[:, free] += (PRIOR_SD[free] / SCALE[free]) ** 2
        P0[:, h] = np.einsum("bi,ij->bij", d, np.eye(N_AUG))
    rep = lambda a: None if a is None else np.repeat(a, H, axis=0)  # noqa: E731  run-major, hypothesis-minor
    bank_inp = replace(inp, **{k: rep(v) for k, v in seg.items()}, params=rep(params))
    res = run_filter(bank_inp, bank_config(det), z0=rep(z0), P0=P0.reshape(n * H, N_AUG, N_AUG),
                     n_steps=rep(k1 - k0))  # each run only over its own window
    loglik = np.cumsum(np.nan_to_num(res.ll), axis=1).reshape(n, H, L)
    mean = res.mean.reshape(n, H, L, -1)
    std = res.std.reshape(n, H, L, -1)
    free_est = np.full((n, H, L), np.nan)
    free_sd = np.full((n, H, L), np.nan)
    healthy = np.full((n, H), np.nan)
    for h, j in enumerate(frees):
        if j is not None:
            free_est[:, h], free_sd[:, h] = mean[:, h, :, j], std[:, h, :, j]
            healthy[:, h] = z0[:, j] * sc[j]
    return BankResult(k0=k0, loglik=loglik, free=free_est, free_sd=free_sd, healthy=healthy, n_valid=k1 - k0,
                      names=tuple(hypotheses))


@dataclass
class Decision:
    """The bank's decision for one run."""

    hypothesis: str | None  #: isolated fault parameter (a FAULTS name) or None (not isolable)
    index: int  #: recording sample of the decision (-1: none)
    candidates: list  #: fault hypotheses within the margin of the best at the decision (or last) sample
    llr: dict  #: hypothesis -> its log-likelihood minus the best one's at that sample [nats]
    llr_none: float  #: best fault hypothesis minus the healthy hypothesis at that sample [nats]
    k0: int  #: first sample of the bank
    size: float = float("nan")  #: change of the isolated (or best) parameter, SI
    size_sd: float = float("nan")


def decide(bank: BankResult, i: int, k_alarm: int, margin: float) -> Decision:
    """First sample k >= k_alarm at which the best fault hypothesis of bank run i beats every
    other fault hypothesis by ``margin`` nats (causal: L_H(k) uses samples up to k)."""
    names = list(bank.names)
    fi = [names.index(h) for h in FAULTS]
    nv = int(bank.n_valid[i])
    ll = bank.loglik[i][fi, :nv]  # (F, nv)
    start = min(max(0, k_alarm - int(bank.k0[i])), nv - 1)
    srt = np.sort(ll, axis=0)
    ok = np.flatnonzero(srt[-1, start:] - srt[-2, start:] >= margin)
    at = start + int(ok[0]) if len(ok) else nv - 1
    best = int(np.argmax(ll[:, at]))
    llr = {h: float(ll[q, at] - ll[best, at]) for q, h in enumerate(FAULTS)}
    llr_none = float(ll[best, at] - bank.loglik[i, names.index("none"), at])
    # size: the best filter's estimate of its constant parameter from all the window's data
    # (its last sample), minus the healthy value
    hb = fi[best]
    size = float(bank.free[i, hb, nv - 1] - bank.healthy[i, hb])
    size_sd = float(bank.free_sd[i, hb, nv - 1])
    if len(ok):
        return Decision(FAULTS[best], int(bank.k0[i]) + at, [FAULTS[best]], llr, llr_none, int(bank.k0[i]), size, size_sd)
    cands = [h for h in FAULTS if llr[h] > -margin]
    return Decision(None, -1, cands, llr, llr_none, int(bank.k0[i]), size, size_sd)


def first_alarms(stats: dict, h: dict) -> tuple[np.ndarray, list]:
    """(B,) first alarm sample of any hypothesis (-1: none) and, per run, the name of the
    hypothesis that alarmed first (None: none), from CUSUM statistics name -> (B, T)."""
    names = list(stats)
    g = np.stack([stats[k] / h[k] for k in names])  # (H, B, T)
    above = g > 1.0
    first = np.where(above.any(axis=2), np.argmax(above, axis=2), np.iinfo(np.int64).max)  # (H, B)
    k = first.min(axis=0)
    who = [names[int(np.argmin(first[:, b]))] if k[b] < np.iinfo(np.int64).max else None for b in range(len(k))]
    return np.where(k < np.iinfo(np.int64).max, k, -1), who


def isolate(out: FilterOutput, stats: dict, h: dict, k_ready: int, margin: float,
            horizon_s: float | None = None, rows=None, k_stop: int | None = None, size: bool = True) -> dict:
    """Run the reference and the bank for every run (of ``rows``) that alarmed, batched;
    returns run -> Decision. A run's window is [k0, end of the record) or, with ``horizon_s``,
    [k0, alarm + horizon_s], never beyond ``k_stop``. In stages, so that the five filters run
    only as long as a decision needs them: (1) the bank up to the alarm, decided there; (2) for
    runs not yet decided, the bank over the whole window; (3) with ``size``, the decided
    hypothesis' filter alone over the whole window, whose last estimate is the size."""
    dt = float(out.t[1] - out.t[0])
    T = out.mean.shape[1]
    k_alarm, who = first_alarms(stats, h)
    rows = np.arange(len(k_alarm)) if rows is None else np.asarray(rows)
    rows = np.array([b for b in rows if k_alarm[b] >= 0], dtype=np.int64)
    if not len(rows):
        return {}
    ka = k_alarm[rows]
    k0 = np.array([onset_index(stats[who[b]][b], int(k_alarm[b]), k_ready, dt) for b in rows], dtype=np.int64)
    k1 = np.full(len(rows), T, dtype=np.int64)
    if horizon_s is not None:
        k1 = np.minimum(T, ka + int(round(horizon_s / dt)) + 1)
    if k_stop is not None:
        k1 = np.minimum(k1, k_stop)
    k1 = np.maximum(k1, k0 + 1)
    ref = run_reference(out, rows, k0 + 1)
    k_a1 = np.minimum(ka + 1, k1)  # stage 1: up to and including the alarm
    bank = run_bank(out, ref, rows, k0, k_a1)
    decs = [decide(bank, i, int(ka[i]), margin) for i in range(len(rows))]
    late = np.array([i for i, d in enumerate(decs) if d.hypothesis is None and k1[i] > k_a1[i]], dtype=np.int64)
    if len(late):  # stage 2: the undecided runs over their whole window
        bank2 = run_bank(out, ref, rows[late], k0[late], k1[late], ref_rows=late)
        for q, i in enumerate(late):
            decs[i] = decide(bank2, q, int(ka[i]), margin)
    if size:  # stage 3: the decided hypothesis alone over the whole window
        for name in FAULTS:
            sel = np.array([i for i, d in enumerate(decs) if d.hypothesis == name and k1[i] > k_a1[i]], dtype=np.int64)
            if len(sel):
                one = run_bank(out, ref, rows[sel], k0[sel], k1[sel], hypotheses=(name,), ref_rows=sel)
                for q, i in enumerate(sel):
                    nv = int(one.n_valid[q])
                    decs[i].size = float(one.free[q, 0, nv - 1] - one.healthy[q, 0])
                    decs[i].size_sd = float(one.free_sd[q, 0, nv - 1])
    return {int(b): decs[i] for i, b in enumerate(rows)}


def hypothesis_name(param: str, change: float) -> str:
    """The detect.HYPOTHESES name of a bank parameter: the offset side from the sign of its change."""
    if param != "offset":
        return param
    return "offset+" if change >= 0 else "offset-"
