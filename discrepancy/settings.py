"""Every knob of the mismatch diagnosis, once: :class:`Settings`."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Settings:
    """How the diagnosis simulates, calibrates and decides. The defaults are what docs/mismatch.md
    measures; a caller changes one with ``dataclasses.replace``."""

    #: the model's step (sam.dynamics.step): Heun at 1 ms is the estimation default, its
    #: discretisation error below the sensor noise on rig recordings (docs/rig.md); Eq. (22)'s
    #: Euler at 1 ms errs as much as the effects the diagnosis looks for
    scheme: str = "heun"
    #: the longest model step [s]; recordings sampled slower are simulated in sub-steps
    max_step_s: float = 1e-3
    #: keep Eq. (7)'s R-dot term (docs/model.md, "Motion"): a real boom has it
    arm_rate_torque: bool = True
    #: least-squares evaluations of the calibration
    calibration_nfev: int = 60
    #: least-squares evaluations of a hypothesis fit (with the calibration parameters)
    hypothesis_nfev: int = 30
    #: reweighting rounds of every first-round fit, one residual variance per segment
    #: (fitting.fit_by_segment): a segment ringing from its start state must not steer the parameters.
    #: One feasible-GLS step, as the second round takes: a second step halves what is left of the
    #: held-out error on the sam-made air case (1.2 -> 0.6, nominal 5.7) for twice the fitting time
    segment_rounds: int = 1
    #: ...and the least-squares evaluations of each round (it starts at the previous optimum)
    segment_round_nfev: int = 15
    #: m/s: samples faster than this enter the force-balance start of the load and the level angle
    commissioning_min_speed: float = 0.01
    #: fewer moving samples than this: no force-balance start (the nominal values are the start)
    commissioning_min_samples: int = 300
    #: m: samples this close to an end stop are a known gap of the model's form (gap_mask)
    stop_band_m: float = 2e-3
    #: Pa: samples with a chamber below this pressure are one too (cavitation, transmitters clipped at 0)
    low_pressure_Pa: float = 0.2e6
    #: s: and so are the samples this long after either (the impact's ringing, the void closing)
    gap_hold_s: float = 0.05
    #: the step floor's finer step is the model's step over this (discrepancy.floor)
    floor_refine: int = 4
    #: an effect must remove more than this many times the step floor of the held-out error
    floor_margin: float = 2.0
    #: a segment counts as the effect's regime when its change of the prediction exceeds this over the
    #: segment's effective samples (in shares of its squared error): below, noise alone could move it
    noise_factor: float = 4.0
    #: s: the segment starts are moved by this either way to find the segments the start decides
    start_shift_s: float = 0.005
    #: ...and a segment whose squared error that changes by more than this share is not scored
    start_sensitive_share: float = 1.0
    #: decay times (1 / sigma, sigma the decay rate of the model's hydraulic mode, slowest over the
    #: stroke: simulation.hydraulic_decay_rate) over which every segment's start state (p_A, p_B, v, z)
    #: is estimated under the hypothesis being judged (SegmentSimulator.settled_states); 0: every
    #: segment starts from the smoothed measurement. After 3 decay times a start error's ringing is
    #: down to 5 %
    start_decay_times: float = 3.0
    #: a calibrated model whose held-out shortfall from 100 % fit is more than this many times the noise
    #: ceiling's (discrepancy.ceiling.excess) is not adequate even when no effect passed every test:
    #: 1.5 times the worst clean development recording's excess (docs/mismatch.md, Acceptance, rule 6)
    excess_limit: float = 11.0
    #: when the calibrated model is beyond ``excess_limit``, an effect that lowers the held-out error on
    #: at least this share of the segments where it changes the prediction (not all:
    #: floor.Specificity.mostly) is accepted if it brings the model back within the limit; the
    #: every-segment rule alone rejects true effects whose library form only approximates the machine's
    specific_share: float = 2.0 / 3.0

    def __post_init__(self):
        for name in ("max_step_s", "floor_margin", "noise_factor", "start_shift_s", "start_sensitive_share",
                     "stop_band_m", "low_pressure_Pa", "gap_hold_s", "commissioning_min_speed", "excess_limit"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"Settings.{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0.0 < self.specific_share <= 1.0:
            raise ValueError(f"Settings.specific_share must be within (0, 1], got {self.specific_share!r}")
        if not 0.0 <= self.start_decay_times <= 20.0:
            raise ValueError(f"Settings.start_decay_times must be within 0-20 decay times of the hydraulic mode, "
                             f"got {self.start_decay_times!r}")
