"""Mismatch diagnosis between simulation and recordings.

``diagnose(rec, plant, out_dir, validate=None) -> Report``: compare the plant
model with a recording, calibrate the GSA-ranked nominal parameters, locate
where the residual concentrates, rank a library of candidate effects (switched
on through :class:`sam.params.Effects`, never a fork of the model) by signature,
BIC and held-out validation, run a generic unknown-input route for what the
library lacks, and write report.md / report.json / figures.
"""

from .diagnose import Report, diagnose
from .library import Hypothesis, library

__all__ = ["diagnose", "Report", "Hypothesis", "library"]
