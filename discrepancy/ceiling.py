"""What the recording's own noise lets a model reach, and when a calibrated model falls far short.

A model that were exact up to the transmitters' and the encoder's noise would still miss each
measured sample by that noise. Its NRMSE fit on a signal y with noise sigma is

    fit_noise = 100 (1 - sqrt(n) sigma / ||y - mean(y)||)  [%],

the *noise ceiling* (:func:`noise_ceiling`). The calibrated model's own shortfall from 100 %,
over the ceiling's, is the *excess* (:func:`excess`): how many times the noise its error is.
Clean rig recordings have an excess above 1 (the step, the segment starts, the rig's continuous
physics), but bounded; an excess far above what clean recordings show means that something the
calibration cannot absorb is still in the recording, even when no single library effect passed
every acceptance test (:func:`short_of_ceiling`).

The noise sigma of each signal is read from the recording itself (:func:`sam.white_noise_std`:
the median absolute second difference, which a smooth signal sampled at 1 kHz barely moves).
"""

from __future__ import annotations

import math

import numpy as np

from sam import white_noise_std

from .simulation import SIGNALS, SegmentSimulator

def noise_ceiling(sim: SegmentSimulator, part: str = "held") -> dict[str, float]:
    """Per-signal fit % [%] that a model exact up to the noise would reach on ``part`` of ``sim``'s
    segments (the samples :func:`simulation.fits` scores), and their mean under "mean"."""
    segs = sim.segment_mask(part)
    out = {}
    for k in SIGNALS:
        y = sim.meas[k][segs][sim.mask[k][segs]]
        den = float(np.linalg.norm(y - y.mean())) if y.size else 0.0
        sd = white_noise_std(sim.data.y[k][sim.data.scored[k]])
        out[k] = 100.0 * (1.0 - math.sqrt(y.size) * sd / den) if den > 0 else float("nan")
    out["mean"] = float(np.nanmean([out[k] for k in SIGNALS]))
    return out


def excess(fit_mean: float, ceiling_mean: float) -> float:
    """How many times the noise's shortfall the model's is: (100 - fit) / (100 - ceiling) [1]."""
    return (100.0 - fit_mean) / max(100.0 - ceiling_mean, 1e-3)


def short_of_ceiling(fit_mean: float, ceiling_mean: float, limit: float) -> bool:
    """Whether a model's held-out fit ``fit_mean`` [%] errs more than ``limit`` times the noise
    ceiling's shortfall (``Settings.excess_limit``): something is still missing."""
    return excess(fit_mean, ceiling_mean) > limit


def closest_library_effect(cands, ceiling_mean: float, limit: float, bic_strong: float, min_gain: float,
                           min_points: float):
    """The first-round candidate (:class:`diagnose.Candidate`) that explains a calibrated model
    short of the noise ceiling, or None.

    Asked only when no effect passed every acceptance test and the calibrated model errs more than
    ``limit`` times the noise ceiling's shortfall. A candidate explains it when it is physical
    (``Candidate.physical``), carries strong evidence on both parts (BIC change below ``-bic_strong``
    on the fitting part and segment by segment held out), removes more than ``min_gain`` of the
    held-out error and raises the held-out fit by ``min_points`` [points], and brings the model
    back within ``limit`` of the ceiling: an effect that leaves the model as far from its noise as
    before has not found what is missing. The best such by its held-out BIC change."""
    ok = [c for c in cands if c.physical and c.delta_bic < -bic_strong and c.seg_bic_held < -bic_strong
          and c.gain_held > min_gain and c.fit_after.get("mean", 0.0) - c.fit_before.get("mean", 0.0) >= min_points
          and not short_of_ceiling(c.fit_after["mean"], ceiling_mean, limit)]
    return min(ok, key=lambda c: c.delta_bic_held) if ok else None


__all__ = ["closest_library_effect", "excess", "noise_ceiling", "short_of_ceiling"]
