"""Unscented-Kalman-filter fault detection and isolation (see docs/fdi.md).

* :mod:`fdi.filter`: the batched augmented-state UKF over ``sam.step_batch``, configured by
  :class:`fdi.config.FilterConfig`;
* :mod:`fdi.detect`: residuals, CUSUM alarms, diagnosis;
* :mod:`fdi.isolate`: isolation and size by likelihood (a bank of constrained filters);
* :mod:`fdi.replay`: offline replay of a recording (``samfdi fdi replay``);
* :mod:`fdi.signatures`, :mod:`fdi.tune`: signature tables, Monte Carlo thresholds;
* :mod:`fdi.rates`: a Monte Carlo's rates with exact intervals, and the verdict on a target rate.
"""

from .config import CalibrationStates, Constraints, FilterConfig, Guards, Sensors, SigmaPoints, StopRules, UnknownInputStates
from .detect import Diagnosis, Thresholds
from .filter import FilterInput, FilterOutput, run_filter
from .states import K_PER_LPM, POS_THETA, POS_X, STATE_NAMES, leak_lpm


def replay_recording(rec, plant, out_dir, **kw) -> Diagnosis:
    """Replay a recording (only its measured columns) and write the outputs into out_dir."""
    from .replay import replay_recording as _replay

    return _replay(rec, plant, out_dir, **kw)


__all__ = ["CalibrationStates", "Constraints", "Diagnosis", "FilterConfig", "FilterInput", "FilterOutput", "Guards",
           "K_PER_LPM", "POS_THETA", "POS_X", "STATE_NAMES", "Sensors", "SigmaPoints", "StopRules", "Thresholds",
           "UnknownInputStates", "leak_lpm", "replay_recording", "run_filter"]
