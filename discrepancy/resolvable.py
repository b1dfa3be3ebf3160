"""Whether a fitted effect acts where the recording can show it: a term whose whole action lies below
what the sampling resolves, or inside the model's known gaps, is not named however much it gains."""

from __future__ import annotations

from sam import P
from sam.hydraulics import effective_bulk_modulus

from .fitting import FitResult
from .library import Hypothesis
from .settings import Settings
from .simulation import MEAS_PARAMS

#: 1: entrained air must soften the oil by more than this share at the edge of the model's low-pressure
#: gap (Settings.low_pressure_Pa): the calibration's own 5 % significance (B_eff is calibrated)
AIR_SOFTENING_MIN = 0.05


def resolvable(hyps: list[Hypothesis], res: FitResult, dt: float, settings: Settings) -> bool:
    """A sensor lag or delay must be at least one sample interval ``dt`` [s]: shorter ones are not
    resolvable from the sampling itself (which instant a sample stands for, an encoder read within its
    pulse interval, the smoothing of the segment starts all shift signals by a fraction of a sample).
    Entrained air must soften the oil by AIR_SOFTENING_MIN at ``settings.low_pressure_Pa``: a smaller
    fraction acts only near vacuum, where sam clamps a cavitating chamber and a machine opens a void
    (discrepancy.data.gap_mask), so its gain is that gap's, not air's."""
    names = {f.name for h in hyps for f in h.params}
    if any(res.values[n] < dt for n in names & set(MEAS_PARAMS)):
        return False
    if "air_fraction" in names:
        B_eff = res.params[P.B_eff]
        B = effective_bulk_modulus(settings.low_pressure_Pa, B_eff, res.values["air_fraction"])
        return bool(B <= (1.0 - AIR_SOFTENING_MIN) * B_eff)
    return True
