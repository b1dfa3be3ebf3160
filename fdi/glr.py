"""A likelihood (GLR) detector: banks of constrained filters restarted on a schedule.

Session 6 measured that, after a 0.25 L/min leak, the bank's best fault hypothesis leads the
healthy one by tens to thousands of nats long before the CUSUM on the estimate change alarms.
This detector uses that directly, causally and at bounded cost:

* windows [k_j, k_j + W) with k_j = k_ready + j R (``WINDOW_S`` = ``RESTART_S``: each sample
  is in exactly one window, so the cost is the bank's five 12-state filters once over the
  monitored part of the record);
* every window starts from the DETECTION filter at k_j (model states, variances, the
  calibration values written into the parameter vector, the fault parameters at its current
  estimates: "none" = no change since k_j; optionally at a healthy ``baseline`` instead, which
  measured the same healthy tail on 20 development runs), and runs
  the bank of :mod:`fdi.isolate` (none, K_int, K_extA, K_extB, offset; faults constant, the
  free one with its prior); all windows of all runs are ONE :func:`fdi.ukf.run_filter` call;
* statistic g(k) = max(0, max_H L_H(k) - L_none(k)), the log-likelihood ratio of the best
  fault against "no change" accumulated from the start of k's window [nats]; an alarm when
  g(k) > h_glr. The onset estimate for the isolation stage is the alarming window's start
  (the last zero of g before the alarm, as for a CUSUM).

Measured limitation (docs/fdi-history.md, session 7): a fault that starts before a window's start is
partly absorbed by the seed (the detection filter follows it), so the detector mostly sees a
change inside the window it starts in. The tune's onset (1.5 s) coincides with the first window's
start, its best case; with the first window 0.25-0.5 s after the onset (``Thresholds.glr_start_s``)
detection within 1 s collapses. An option, not the default.

The threshold is NOT a chi-square level (healthy windows reach tens of nats from model error):
:func:`glr_threshold` takes it from the healthy runs of the nuisance GSA of
:mod:`fdi.thresholds` (the same design and seed as the CUSUM thresholds), as the
(1 - alpha) quantile of the per-run maxima (the CUSUM rule, :func:`fdi.thresholds.level_threshold`),
alpha the stated false-alarm level per healthy run of ``Thresholds.run_length_s`` (one statistic,
so no Bonferroni split).
"""

from __future__ import annotations

import numpy as np

from .isolate import BANK, FAULT_IDX, FAULTS, _run_hypotheses, bank_config, seed_from
from .ukf import N_AUG, FilterOutput, sample_step, state_scale

#: s: window length = restart period. 0.5 s: two windows fit in the 1 s detection target, so a
#: step is followed by at least one whole faulty window within 1 s; the cost is the bank once
#: over the record (overlapping windows, e.g. 1 s every 0.5 s, would double it).
WINDOW_S = 0.5
RESTART_S = 0.5


def window_starts(T: int, k_ready: int, dt: float, restart_s: float = RESTART_S) -> np.ndarray:
    """Start samples of the windows: k_ready, k_ready + R, ... < T."""
    return np.arange(k_ready, T, max(1, int(round(restart_s / dt))), dtype=np.int64)


def glr_statistics(out: FilterOutput, baseline: np.ndarray | None, k_ready: int, window_s: float = WINDOW_S,
                   restart_s: float = RESTART_S) -> dict:
    """Fault name -> g_H (B, T) [nats] of the detection output ``out`` (its ``inp`` is needed):
    per window (:func:`window_starts`), max(0, L_H - L_none) from the window's start; 0 before
    k_ready. ``baseline`` (B, 4) or None: healthy values of K_int, K_extA, K_extB, offset (SI)
    held in every window (None: the detection filter's estimates at the window's start). One
    batched bank call for all windows of all runs."""
    B, T = out.mean.shape[:2]
    dt = sample_step(out.t)
    starts = window_starts(T, k_ready, dt, restart_s)
    g = {h: np.zeros((B, T)) for h in FAULTS}
    if not len(starts):
        return g
    W = max(1, int(round(window_s / dt)))
    rows = np.repeat(np.arange(B), len(starts))
    k0 = np.tile(starts, B)
    k1 = np.minimum(k0 + W, T)
    params, z0, var = seed_from(out, out.inp, rows, k0, rows)
    sc = state_scale(out.config)[:N_AUG]
    if baseline is not None:
        z0[:, list(FAULT_IDX)] = np.asarray(baseline)[rows] / sc[list(FAULT_IDX)]
    names = [tuple(BANK)] * len(rows)
    res = _run_hypotheses(out.inp, bank_config(out.config), rows, k0, k1, params, z0, var, names, False)
    ll = res.loglik  # (n, 5, W)
    none = ll[:, list(BANK).index("none")]
    for h in FAULTS:
        lead = np.maximum(ll[:, list(BANK).index(h)] - none, 0.0)
        for i, (b, a, e) in enumerate(zip(rows, k0, k1)):
            g[h][b, a:e] = np.maximum(g[h][b, a:e], lead[i, :e - a])  # overlapping windows: the larger
    return g


def first_alarm(g: np.ndarray, h: float) -> np.ndarray:
    """(B,) first sample with g > h (-1: none)."""
    above = g > h
    return np.where(above.any(axis=1), np.argmax(above, axis=1), -1)


def glr_threshold(maxima: np.ndarray, level: float) -> float:
    """h_glr for a stated false-alarm ``level`` per run: the (1 - level) quantile of the healthy
    per-run maxima by the CUSUM rule (:func:`fdi.thresholds.level_threshold`; until session 10
    also never below 1.05 x their largest value, the rule of the shipped thresholds_glr.toml)."""
    from .thresholds import level_threshold

    return level_threshold(maxima, 1.0 - level)
