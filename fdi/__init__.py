"""Fault detection and isolation with an augmented-state Unscented Kalman Filter (docs/fdi.md).

One pipeline, one direction, each stage a module returning an immutable, typed result:

* the recording, checked (:mod:`fdi.recording`) -> :class:`FilterInput`;
* the filter (:mod:`fdi.filter`; :class:`FilterConfig`) -> :class:`FilterOutput`;
* the change tests (:mod:`fdi.statistics`) -> :class:`Statistics`;
* the alarms (:mod:`fdi.alarms`);
* isolation and sizing by the likelihood bank (:mod:`fdi.bank`, :mod:`fdi.isolation`;
  :class:`BankDesign`);
* the diagnosis, which drives the stages (:mod:`fdi.diagnosis`) -> :class:`Diagnosis`.

:func:`replay` runs them on one recording (:mod:`fdi.offline`); :func:`run_tune` evaluates the detector on Monte
Carlo runs and :func:`analyse` turns those into rates with intervals; :mod:`fdi.study` derives
:class:`Thresholds` from the sensitivity studies.
"""

import sam.jitcache  # noqa: F401  (numba's cache keyed by the project's sources: sam/jitcache.py)
from .bank import BankDesign
from .config import (
    CalibrationStates, Constraints, FilterConfig, FormNoise, Guards, Sensors, SigmaPoints, StopRules,
    UnknownInputStates,
)
from .diagnosis import Diagnosis, diagnose, judge
from .filter import FilterInput, FilterOutput, run_filter
from .metrics import analyse
from .offline import Replay, replay, replay_recording
from .states import K_PER_LPM, POS_THETA, POS_X, STATE_NAMES, leak_lpm
from .statistics import Statistics
from .thresholds import Thresholds
from .tune import run_tune

__all__ = [
    "BankDesign", "CalibrationStates", "Constraints", "Diagnosis", "FilterConfig", "FilterInput", "FilterOutput",
    "FormNoise", "Guards", "K_PER_LPM", "POS_THETA", "POS_X", "Replay", "STATE_NAMES", "Sensors", "SigmaPoints",
    "Statistics", "StopRules", "Thresholds", "UnknownInputStates", "analyse", "diagnose", "judge", "leak_lpm",
    "replay", "replay_recording", "run_filter", "run_tune",
]
