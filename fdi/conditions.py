"""The operating conditions of every sample, and which change tests they hold.

From the valve input and the filter's posterior: the regime (hold, extension, retraction;
transient or steady), pressures pinned to supply and tank, the piston on an end stop, balanced
chamber pressures, long strokes, the first motion, and the healthy baseline window each test
learns from. A test is *held* where its parameter cannot show in the measurements.
"""

from __future__ import annotations

import numpy as np

from sam import P, S

from .faults import PARAMS
from .filter import FilterOutput, near_end_stop, sample_step
from .states import I_X
from .strokes import directions, first_motion, long_strokes
from .thresholds import Thresholds

#: Which change tests are held while the pressures are pinned (:func:`pinned`), per parameter:
#: (A at supply and B at tank, B at supply and A at tank). With no flow, an offset changes
#: nothing the sensors see, nor does a leak out of the chamber at tank pressure; the fed
#: chamber's leak and the internal one still show through the notch that feeds them.
UNOBSERVABLE_PINNED = {"K_int": (False, False), "K_extA": (False, True), "K_extB": (True, False),
                       "offset": (True, True)}
#: the tests held while the piston rests on an end stop with the valve at null: the stop
#: truncates the filter's velocity sigma points, and the bias of the predicted pressures sets the
#: null-leakage balance that K_int and the offset would absorb
HELD_ON_STOP = ("K_int", "offset")
#: the parameters whose baselines are re-learnt after a withdrawn alarm: a leak across the piston
#: and a spool offset bias a steady stroke's flow balance alike (which tests still hold their
#: long-stroke excursions is Thresholds.long_stroke_params)
WANDERING = ("K_int", "offset")


def regimes(u: np.ndarray, dt: float, band: float = 0.3, transient_s: float = 0.3) -> np.ndarray:
    """(B, T) regime index (fdi.faults.REGIMES) of each sample of the input u (B, T) [V]."""
    d, since = directions(u, dt, band)
    out = np.zeros(d.shape, dtype=np.int8)
    trans = since < transient_s
    out[d == 1] = np.where(trans[d == 1], 1, 2)
    out[d == 2] = np.where(trans[d == 2], 3, 4)
    return out


def pinned(out: FilterOutput, th: Thresholds) -> np.ndarray:
    """(B, T, 2) bool: the chamber pressures pinned to the rails, [..., 0] A within
    ``pin_margin_Pa`` of the supply and B within it of the tank pressure, [..., 1] the other way
    round: stalled against the load or held on an end stop with the valve open, no oil flowing
    but the leaks. Pressures: the filter's posterior means; the supply: the measured p_S where
    the recording has it, else the plant's. False everywhere without measured data (``out.inp``)."""
    B, T = out.mean.shape[:2]
    if out.inp is None:
        return np.zeros((B, T, 2), dtype=bool)
    margin = th.regimes.pin_margin_Pa
    p_S = out.inp.params[:, P.p_S][:, None]
    if out.inp.pS is not None:  # measured; in its gaps the plant's, as the filter does
        p_S = np.where(np.isnan(out.inp.pS), p_S, out.inp.pS)
    p_T = out.inp.params[:, P.p_T][:, None]
    hi = out.mean[:, :, :2] >= (p_S - margin)[..., None]
    lo = out.mean[:, :, :2] <= (p_T + margin)[..., None]
    return np.stack([hi[..., 0] & lo[..., 1], hi[..., 1] & lo[..., 0]], axis=2)


def on_end_stop(out: FilterOutput) -> np.ndarray:
    """(B, T) bool: the piston (the filter's posterior mean) within the filter's stop margin
    (fdi.config.StopRules.margin_m) of an end stop. False without measured data (``out.inp``)."""
    B, T = out.mean.shape[:2]
    if out.inp is None:
        return np.zeros((B, T), dtype=bool)
    return near_end_stop(out.mean[:, :, I_X], out.inp.params, out.config.stops.margin_m)


def resting_on_stop(out: FilterOutput, th: Thresholds) -> np.ndarray:
    """(B, T) bool: the piston on an end stop (:func:`on_end_stop`) with the valve input in the
    hold band: blocked, the spool at null, the offset only shifting the null leakage's balance."""
    if out.u is None:
        return np.zeros(out.mean.shape[:2], dtype=bool)
    return on_end_stop(out) & (np.abs(out.u) < th.regimes.band_V)


def balanced(out: FilterOutput, th: Thresholds) -> np.ndarray:
    """(B, T) bool: the chamber pressures (posterior means) within ``balance_margin_Pa`` of each
    other, where a leak across the piston carries almost no flow."""
    return np.abs(out.mean[:, :, S.p_A] - out.mean[:, :, S.p_B]) < th.regimes.balance_margin_Pa


def held(out: FilterOutput, th: Thresholds) -> np.ndarray:
    """(B, 4, T) bool, PARAMS order: where each change test is held: its parameter unobservable
    with the pressures pinned (:data:`UNOBSERVABLE_PINNED`), the tests of :data:`HELD_ON_STOP`
    resting on an end stop, and K_int's where the pressures balance."""
    pin = pinned(out, th)
    hidden = np.stack([(pin[..., 0] & a) | (pin[..., 1] & b) for a, b in UNOBSERVABLE_PINNED.values()], axis=1)
    rest = resting_on_stop(out, th)
    for p in HELD_ON_STOP:
        hidden[:, list(PARAMS).index(p)] |= rest
    hidden[:, list(PARAMS).index("K_int")] |= balanced(out, th)
    return hidden


def held_on_stop(out: FilterOutput, th: Thresholds) -> np.ndarray:
    """(B, 4, T) bool, PARAMS order: the tests held (:func:`held`) while the piston is on an end
    stop. There the inelastic stop biases the predicted pressures, and a free fault parameter
    that cannot act fits that bias: the likelihood bank names no fault there."""
    return held(out, th) & on_end_stop(out)[:, None, :]


def long_stroke_mask(out: FilterOutput, th: Thresholds) -> np.ndarray:
    """(B, T) bool: the samples under the long-stroke rule (Regimes.long_stroke_s; all False
    without it or without the input)."""
    r = th.regimes
    if r.long_stroke_s is None or out.u is None or len(out.t) < 2:
        return np.zeros(out.mean.shape[:2], dtype=bool)
    return long_strokes(out.u, sample_step(out.t), r.band_V, r.long_stroke_s)


def before_motion(out: FilterOutput, th: Thresholds) -> np.ndarray:
    """(B, T) bool: the samples before the valve input first leaves the hold band and the warm-up
    after that (all False without the input; all True if it never leaves). At rest the load mass
    and the unknown force trade freely and the friction builds: a baseline learnt there is far
    from the estimates of the first motion."""
    if out.u is None:
        return np.zeros(out.mean.shape[:2], dtype=bool)
    dt = sample_step(out.t)
    k_move = first_motion(out.u, th.regimes.band_V)
    return np.arange(out.u.shape[1])[None, :] < (k_move + int(round(th.window.warmup_s / dt)))[:, None]


def first_motion_s(out: FilterOutput, th: Thresholds, b: int) -> float | None:
    """Time [s] of run b's first motion (fdi.strokes.first_motion); 0 without the input, None if
    the input never leaves the hold band."""
    if out.u is None:
        return 0.0
    k = int(first_motion(out.u[b:b + 1], th.regimes.band_V)[0])
    return float(out.t[k]) if k < len(out.t) else None


def baseline_window(t: np.ndarray, hidden: np.ndarray, th: Thresholds) -> tuple[np.ndarray, np.ndarray]:
    """Per run and parameter, the samples of its healthy baseline and those at which its test is
    armed, both (B, P, T) bool, given where it is hidden (B, P, T). The baseline is the samples of
    [warmup, warmup + baseline_s] that do not hide it; with fewer than ``min_baseline_s`` of them
    there (pinned from the start) it is the parameter's first ``baseline_s`` of such samples after
    the warm-up instead, armed after them (never, if there are not that many)."""
    w_ = th.window
    dt = t[1] - t[0] if len(t) > 1 else 1e-3
    after = t >= w_.warmup_s
    window = after & (t < w_.warmup_s + w_.baseline_s)
    if not window.any():  # a record shorter than the warm-up: its first quarter
        window = np.zeros_like(t, dtype=bool)
        window[: max(1, len(t) // 4)] = True
    seen = ~hidden
    w = window & seen
    ready = np.broadcast_to(t >= w_.warmup_s + w_.baseline_s, hidden.shape).copy()
    slide = w.sum(axis=2) * dt < w_.min_baseline_s  # (B, P)
    if slide.any():
        n_base = max(1, int(round(w_.baseline_s / dt)))
        count = np.cumsum(after & seen[slide], axis=1)
        w[slide] = after & seen[slide] & (count <= n_base)
        full = count >= n_base  # from the last baseline sample on; armed from the sample after it
        ready[slide] = np.concatenate([np.zeros((len(full), 1), dtype=bool), full[:, :-1]], axis=1)
    return w, ready
