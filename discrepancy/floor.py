"""The misfit no physics explains, and the test an effect must pass against it.

The calibrated model never fits a real recording exactly, even with nothing missing: its step
errs (the integration scheme), the transmitters quantise, the segment starts are smoothed
estimates. A free parameter of any effect soaks up part of that error, and on 20,000 correlated
samples a BIC calls that significant. Two measures keep an effect from claiming it:

* **The step floor.** The calibrated model simulated at the estimation step and at a
  ``Settings.floor_refine``-times finer one: their difference is (for Heun, 15/16 of) the
  discretisation error. Its squared size over each held-out segment's calibrated squared error is
  the share of that segment's error that the model's own step accounts for (:func:`step_floor`).
* **Segments the start decides.** Each segment starts from the smoothed measurement; where the
  valve is near null and the oil is trapped, a start error of a few kPa never decays, and the
  segment's error is the start's, not the model's. Shifting every start by
  ``Settings.start_shift_s`` either way measures it (:func:`start_sensitive`); a segment whose
  squared error that shift changes by more than ``Settings.start_sensitive_share`` judges nothing
  and is not scored.
* **Specificity, segment by segment.** An effect changes the prediction mostly in its regime
  (air when the pressure is low, a lag at the fast transients). On every held-out segment where
  its change of the prediction is larger than the floor and than what noise could produce, it must
  lower the error; and over the held-out part it must remove more than ``Settings.floor_margin``
  times the floor (:func:`specific`). A term that moves the prediction where it does not help is
  fitting the model's error, not physics. An effect whose library form only approximates the
  machine's may fail one active segment: ``Specificity.mostly`` (it helps on at least
  ``Settings.specific_share`` of them) is then enough when the calibrated model is far short of the
  fit clean recordings reach over their noise and the effect brings it back within that limit
  (``discrepancy.ceiling``; the diagnosis decides that).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .fitting import FitResult, Model, Split, evaluate, segment_rss
from .settings import Settings
from .simulation import SegmentSimulator


@dataclass(frozen=True)
class Floor:
    """The share of the calibrated model's squared error that its own step accounts for."""

    held: np.ndarray  #: (n_held_segments,) per held-out segment
    pooled: float  #: over the held-out part
    pooled_fit: float  #: over the fitting part
    refine: int  #: the finer step is the estimation step over this

    def as_dict(self) -> dict:
        return {"pooled_held": self.pooled, "pooled_fit": self.pooled_fit, "per_held_segment": self.held.tolist(),
                "refine": self.refine}


def _finer(sim: SegmentSimulator, refine: int) -> SegmentSimulator:
    """The same segments of the same recording, simulated at a ``refine``-times finer step."""
    fine = SegmentSimulator.__new__(SegmentSimulator)
    fine.__dict__.update(sim.__dict__)
    fine.data = dataclasses.replace(sim.data, n_sub=sim.data.n_sub * refine)
    fine.u_seg = np.repeat(sim.u_seg, refine, axis=1)
    fine.record_at = sim.record_at * refine
    return fine


def _shifted(sim: SegmentSimulator, shift: int) -> SegmentSimulator:
    """The same segments started from the smoothed measurement ``shift`` samples later (earlier if < 0)."""
    moved = SegmentSimulator.__new__(SegmentSimulator)
    moved.__dict__.update(sim.__dict__)
    n = sim.data.n
    idx = np.clip(np.arange(n) + shift, 0, n - 1)
    moved.data = dataclasses.replace(sim.data, smooth={k: v[idx] for k, v in sim.data.smooth.items()})
    return moved


def start_sensitive(sim: SegmentSimulator, params: np.ndarray, settings: Settings) -> np.ndarray:
    """(n_seg,) bool: segments whose squared error (under ``params``) changes by more than
    ``settings.start_sensitive_share`` when every start moves by ``settings.start_shift_s`` either way.
    At most a third of the segments, the most sensitive ones, are flagged."""
    shift = max(1, int(round(settings.start_shift_s / sim.data.dt)))
    n_seg = len(sim.seg.starts)

    def rss(s: SegmentSimulator) -> np.ndarray:
        return segment_rss(s.residuals(s.simulate(params[None, :]), "all")[0], n_seg)

    base = np.maximum(rss(sim), 1e-300)
    change = np.max([np.abs(rss(_shifted(sim, k)) - base) / base for k in (-shift, shift)], axis=0)
    flagged = change > settings.start_sensitive_share
    worst = np.argsort(-change)[: n_seg // 3]
    keep = np.zeros(n_seg, bool)
    keep[worst] = True
    return flagged & keep


def _residual(sim: SegmentSimulator, res: FitResult, part: str, settle: float) -> np.ndarray:
    meas = res.meas[None, :] if np.any(res.meas) else None
    return sim.residuals(sim.simulate(res.params[None, :], meas, settle=settle), part)[0]


def step_floor(split: Split, cal: FitResult, settings: Settings) -> Floor:
    """The step floor of the calibrated fit ``cal`` on ``split`` (unweighted; every segment started
    from the state consistent with ``cal``, as the effects are judged)."""
    shares = {}
    for part in ("fit", "held"):
        sim = split.sim_for(part)
        r = _residual(sim, cal, part, settings.start_decay_times)
        r_fine = _residual(_finer(sim, settings.floor_refine), cal, part, settings.start_decay_times)
        n_seg = split.n_segments(part)
        e = segment_rss(r - r_fine, n_seg)
        rss = np.maximum(segment_rss(r, n_seg), 1e-300)
        shares[part] = (e / rss, float(np.sum(e) / np.sum(rss)))
    return Floor(shares["held"][0], shares["held"][1], shares["fit"][1], settings.floor_refine)


@dataclass(frozen=True)
class Specificity:
    """How an effect's held-out gain is spread over the held-out segments."""

    gain: np.ndarray  #: (n_held_segments,) 1 - RSS(effect) / RSS(reference) per segment
    change: np.ndarray  #: (n_held_segments,) squared change of the prediction / RSS(reference)
    active: np.ndarray  #: (n_held_segments,) bool, segments where the change is above floor and noise
    pooled_gain: float
    passed: bool  #: it lowers the error on every active segment, and the pooled error beyond the floor
    mostly: bool = False  #: on at least ``Settings.specific_share`` of the active segments, and the pooled one

    def as_dict(self) -> dict:
        return {"segment_gain": self.gain.tolist(), "segment_change": self.change.tolist(),
                "active": self.active.tolist(), "pooled_gain": self.pooled_gain, "passed": self.passed,
                "mostly": self.mostly}


def specific(split: Split, res: FitResult, reference: FitResult, floor: Floor, n_seg_eff: float,
             settings: Settings) -> Specificity:
    """Whether ``res`` beats the floor over ``reference`` specifically, on every held-out segment
    where it changes the prediction (see the module's docstring). ``n_seg_eff``: the effective
    (independent) samples of one segment; a change of the prediction below ``noise_factor /
    n_seg_eff`` of a segment's squared error is within what noise alone lets a term move."""
    none = np.zeros((1, 0))
    n_seg = split.n_segments("held")
    r_new = evaluate(split, Model(res.params, (), res.meas), none, "held")[0]
    r_ref = evaluate(split, Model(reference.params, (), reference.meas), none, "held")[0]
    scored = segment_rss(r_ref, n_seg) > 0.0  # an unscored segment (start_sensitive) neither gains nor changes
    rss_ref = np.maximum(segment_rss(r_ref, n_seg), 1e-300)
    gain = np.where(scored, 1.0 - segment_rss(r_new, n_seg) / rss_ref, 0.0)
    change = np.where(scored, segment_rss(r_new - r_ref, n_seg) / rss_ref, 0.0)
    floor_s = floor.held if len(floor.held) == n_seg else np.full(n_seg, floor.pooled)
    active = change > np.maximum(floor_s, settings.noise_factor / max(n_seg_eff, 1.0))
    pooled = 1.0 - float(np.sum(r_new ** 2) / max(np.sum(r_ref ** 2), 1e-300))
    beyond = bool(active.any() and pooled > settings.floor_margin * floor.pooled)
    helped = float(np.mean(gain[active] > 0.0)) if active.any() else 0.0
    return Specificity(gain, change, active, pooled, beyond and helped == 1.0, beyond and helped >= settings.specific_share)


__all__ = ["Floor", "Specificity", "specific", "start_sensitive", "step_floor"]
