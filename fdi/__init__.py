"""Unscented-Kalman-filter fault detection and isolation (see docs/fdi.md).

* :mod:`fdi.ukf`: the batched augmented-state UKF over ``sam.step_batch``;
* :mod:`fdi.detect`: residuals, CUSUM alarms, diagnosis;
* :mod:`fdi.strokes`: strokes of the valve input (the long-stroke rules of the filter and the detector);
* :mod:`fdi.isolate`: isolation and size by likelihood (a bank of constrained filters);
* :mod:`fdi.replay`: offline replay of a recording (``samfdi fdi replay``);
* :mod:`fdi.signatures`, :mod:`fdi.tune`: signature tables, Monte Carlo thresholds;
* :mod:`fdi.rates`: a Monte Carlo's rates with exact intervals, and the verdict on a target rate.
"""

from .detect import Diagnosis, Thresholds


def replay_recording(rec, plant, out_dir, **kw) -> Diagnosis:
    """Replay a recording (only its measured columns) and write the outputs into out_dir."""
    from .replay import replay_recording as _replay

    return _replay(rec, plant, out_dir, **kw)


__all__ = ["Diagnosis", "Thresholds", "replay_recording"]
