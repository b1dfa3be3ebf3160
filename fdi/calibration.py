"""Calibration from a healthy reference recording of the same machine.

The filter's calibration states (:attr:`fdi.config.CalibrationStates.states`) learn the relative
error of the valve's notch flows and of the bulk modulus on every recording, starting from
their priors (2 % and 10 %). A healthy reference recording of the same machine learns them
before any fault can hide in them: :func:`learn` reads them at the reference's last sample,
:func:`apply` writes them into the nominal plant of another recording and narrows the priors
to what the reference left uncertain. A 0.25 L/min leak is about 1 % of the valve's flow, so a
notch flow known to +-2 % can absorb it while the cylinder moves; known to +-0.5 % it cannot
(docs/fdi-design.md, "Calibration from a reference").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sam import P

from .config import FilterConfig
from .filter import FilterInput, FilterOutput

#: Calibration states carried over: properties of the machine, not of the run. The load mass
#: is not one: another recording may lift another load.
MACHINE_STATES = ("Q_N_PA", "Q_N_AT", "Q_N_PB", "Q_N_BT", "B_eff")
#: Floor of a carried-over prior std (relative): about what the calibration random walk
#: (0.2 %/sqrt(s)) leaves of a notch flow after a few seconds of healthy data.
MIN_PRIOR_SD = 0.003
#: The carried prior std is this many posterior stds: the posterior is optimistic, most of all
#: after PRBS inputs (docs/fdi-design.md, "Calibration from a reference").
SD_INFLATION = 2.0


@dataclass(frozen=True)
class Calibration:
    """What healthy reference recordings taught about their machines, one per run."""

    factor: dict  #: parameter name -> (B,) multiplier of its nominal value (1 + learnt relative error)
    sd: dict  #: parameter name -> (B,) relative std of that error at the reference's end

    def to_json(self, b: int = 0) -> dict:
        """Run b's factors and stds, parameter name -> {"factor", "relative_sd"}."""
        return {name: {"factor": float(self.factor[name][b]), "relative_sd": float(self.sd[name][b])}
                for name in self.factor}


def learn(out: FilterOutput, cfg: FilterConfig) -> Calibration:
    """The machine states of :data:`MACHINE_STATES` that ``cfg`` estimates, read from every run
    of ``out`` (a filter run of ``cfg`` over healthy recordings) at its last sample."""
    names = [n for n in cfg.calibration.states if n in MACHINE_STATES]
    j = {n: cfg.state_names.index(f"c_{n}") for n in names}
    return Calibration(factor={n: 1.0 + out.mean[:, -1, j[n]] for n in names},
                       sd={n: out.std[:, -1, j[n]].copy() for n in names})


def apply(inp: FilterInput, cfg: FilterConfig, cal: Calibration) -> tuple[FilterInput, FilterConfig]:
    """``inp`` with each calibrated parameter's nominal value multiplied by its run's factor,
    and ``cfg`` with that calibration state's prior std set to SD_INFLATION times the
    reference's (the median over the runs: one configuration serves the batch), at least
    MIN_PRIOR_SD and at most the prior ``cfg`` had; its random walk is unchanged."""
    params = inp.params.copy()
    for name, f in cal.factor.items():
        params[:, P[name]] *= f
    noise = dict(cfg.calibration.noise)
    for name, sd in cal.sd.items():
        p0, q = cfg.calibration.prior(name)
        # a reference that taught little (stalled, short) leaves the prior as it was
        noise[name] = (min(max(SD_INFLATION * float(np.median(sd)), MIN_PRIOR_SD), p0), q)
    return replace(inp, params=params), cfg.with_(calibration=replace(cfg.calibration, noise=noise))


__all__ = ["Calibration", "MACHINE_STATES", "MIN_PRIOR_SD", "SD_INFLATION", "apply", "learn"]
