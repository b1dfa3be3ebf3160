"""Strokes of the valve input: which way it drives the cylinder and for how long.

The detector's long-stroke rule (the thresholds' ``long_stroke_s``, :mod:`fdi.thresholds`) and the filter's
hold of its calibration states in long strokes (:attr:`fdi.config.CalibrationStates.hold_after_s`)
read the same strokes from the input alone.
"""

from __future__ import annotations

import numpy as np


def directions(u: np.ndarray, dt: float, band: float) -> tuple[np.ndarray, np.ndarray]:
    """Direction of the input u (B, T) [V] per sample (0 hold |u| <= band, 1 extension, 2
    retraction) and the time [s] since that direction was entered, both (B, T)."""
    u = np.atleast_2d(np.nan_to_num(u))
    d = np.where(u > band, 1, np.where(u < -band, 2, 0))
    B, T = u.shape
    change = np.ones((B, T), dtype=bool)
    change[:, 1:] = d[:, 1:] != d[:, :-1]
    idx = np.where(change, np.arange(T)[None, :], 0)
    np.maximum.accumulate(idx, axis=1, out=idx)
    return d, (np.arange(T)[None, :] - idx) * dt


def first_motion(u: np.ndarray, band: float) -> np.ndarray:
    """(B,) index of the first sample at which the input u (B, T) [V] leaves the hold band
    (|u| > band); T where it never does."""
    moving = np.abs(np.nan_to_num(np.atleast_2d(u))) > band
    return np.where(moving.any(axis=1), moving.argmax(axis=1), moving.shape[1])


def long_strokes(u: np.ndarray, dt: float, band: float, after_s: float) -> np.ndarray:
    """(B, T) bool: the samples from ``after_s`` into an extension or a retraction (the input
    beyond +-band in one direction) until ``after_s`` into the rest that follows it. The rest
    after a stroke is included, not the next stroke: with back-to-back strokes the first
    ``after_s`` of each stroke stay out, so that a machine reversing in long strokes is never
    covered for the whole recording. Causal: sample k depends on u up to k."""
    d, since = directions(u, dt, band)
    inside = (d != 0) & (since > after_s)
    k = np.arange(d.shape[1])[None, :]
    last = np.where(inside, k, np.iinfo(np.int64).min // 2)
    np.maximum.accumulate(last, axis=1, out=last)
    return inside | ((d == 0) & ((k - last) * dt <= after_s))


def after_long_segment(u: np.ndarray, dt: float, band: float, long_s: float, transient_s: float) -> np.ndarray:
    """(B, T) bool: the first ``transient_s`` of each stroke (the input beyond +-band) that follows
    a segment of at least ``long_s`` in another direction: a rest (the input within the band; the
    record's start counts as rest) or a stroke the other way (a reversal). Causal."""
    d, since = directions(u, dt, band)
    B, T = d.shape
    k = np.broadcast_to(np.arange(T)[None, :], (B, T))
    start = np.zeros((B, T), dtype=bool)
    start[:, 1:] = (d[:, 1:] != 0) & (d[:, 1:] != d[:, :-1])
    after_long = np.zeros((B, T), dtype=bool)
    after_long[:, 1:] = start[:, 1:] & (since[:, :-1] >= long_s)
    last_start = np.maximum.accumulate(np.where(start, k, -1), axis=1)
    last_long = np.maximum.accumulate(np.where(after_long, k, -1), axis=1)
    return (d != 0) & (last_start >= 0) & (last_long == last_start) & ((k - last_start) * dt <= transient_s)
