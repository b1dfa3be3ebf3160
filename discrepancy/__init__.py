"""Mismatch diagnosis between simulation and recordings.

``diagnose(rec, plant, out_dir, validate=None, settings=Settings()) -> Report``: compare the
plant model with a recording; calibrate what commissioning fixes (the GSA-ranked nominal
parameters and the plant file's [uncertain] ones); locate where the residual concentrates; rank
a library of candidate effects (switched on through :class:`sam.params.Effects`, never a fork of
the model) by signature, BIC and held-out validation against the model's own error
(discrepancy.floor); run a generic unknown-input route for what the library lacks; say how sure,
and design the test that would settle a look-alike; write report.md / report.json / figures.
"""

import sam.jitcache  # noqa: F401  (numba's cache keyed by the project's sources: sam/jitcache.py)
from .diagnose import Report, diagnose
from .library import Hypothesis, library
from .settings import Settings

__all__ = ["diagnose", "Report", "Hypothesis", "library", "Settings"]
