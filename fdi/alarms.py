"""Alarms: where each change test first crosses its threshold, and the model-fit alarm.

An alarm is a trigger, not a verdict: the likelihood bank (:mod:`fdi.isolation`) confirms it
and names the fault, or withdraws it. The model-fit alarm (the filter's weighted NIS held high)
flags what no fault parameter explains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .filter import FilterOutput, sample_step
from .statistics import Statistics
from .thresholds import Thresholds


@dataclass(frozen=True)
class Alarms:
    """The first alarms of B runs (recording samples; -1: none)."""

    first: np.ndarray  #: (B,) first alarm of any test
    who: tuple  #: per run the test that alarmed first (None: none)
    per_test: dict  #: test -> (B,) its first alarm
    model_fit: np.ndarray  #: (B,) the first model-fit (NIS) alarm


def first_alarm(g: np.ndarray, h: float) -> np.ndarray:
    """(B,) index of the first sample with g > h per row of g (B, T) (-1: none)."""
    above = g > h
    return np.where(above.any(axis=1), np.argmax(above, axis=1), -1)


def first_alarms(stats: Statistics, h: dict) -> tuple[np.ndarray, tuple]:
    """(B,) first alarm sample of any test (-1: none) and, per run, the test that alarmed first
    (None: none; the first of ``stats``' order on a tie)."""
    names = list(stats)
    g = np.stack([stats[k] / h[k] for k in names])  # (H, B, T)
    above = g > 1.0
    first = np.where(above.any(axis=2), np.argmax(above, axis=2), np.iinfo(np.int64).max)  # (H, B)
    k = first.min(axis=0)
    who = tuple(names[int(np.argmin(first[:, b]))] if k[b] < np.iinfo(np.int64).max else None for b in range(len(k)))
    return np.where(k < np.iinfo(np.int64).max, k, -1), who


def nis_alarm(out: FilterOutput, th: Thresholds) -> np.ndarray:
    """(B,) the first sample at which the weighted NIS has been above ``nis_limit`` for
    ``nis_hold_s`` after the warm-up (-1: none)."""
    dt = sample_step(out.t)
    hold = max(1, int(round(th.fit.nis_hold_s / dt)))
    warm = int(round(th.window.warmup_s / dt))
    hi = out.nis > th.fit.nis_limit
    hi[:, :warm] = False
    # run length of consecutive high samples: k minus the last low sample at or before k
    k = np.arange(hi.shape[1])
    last_low = np.maximum.accumulate(np.where(hi, -1, k[None, :]), axis=1)
    long_run = (k[None, :] - last_low) >= hold
    return np.where(long_run.any(axis=1), np.argmax(long_run, axis=1), -1)


def alarms(out: FilterOutput, stats: Statistics, th: Thresholds) -> Alarms:
    """The alarms of the statistics ``stats`` of ``out`` under the thresholds ``th``."""
    first, who = first_alarms(stats, th.test.h)
    return Alarms(first, who, {name: first_alarm(g, th.test.h[name]) for name, g in stats.items()},
                  nis_alarm(out, th))
