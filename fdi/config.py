"""The filter's configuration: groups of settings in SI units, each checked once, when built.

``FilterConfig()`` is the shipped filter. A variant replaces a group or a few states' noise::

    cfg = FilterConfig(calibration=CalibrationStates(states=("m_L",)))
    cfg = FilterConfig().with_process_noise(K_int=0.3 * K_PER_LPM)

A setting that is not valid raises ``ValueError`` naming the group, the field and what a valid
value is; the numerics never check again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from sam import P, SCHEMES
from sam.errors import did_you_mean

from .states import (
    CALIBRATION_SCALE, K_PER_LPM, N_AUG, PARAM_COLS, SCALE, STATE_NAMES, THETA_PULSE, UNKNOWN_INPUT_SCALE,
)

#: Process noise of each base state: std of its random walk per sqrt(s), SI (it does not depend
#: on the sampling step). The model states' noise is the model's error; the parameters' is how
#: fast a fault or the load may change.
PROCESS_NOISE = {
    "p_A": 5e4, "p_B": 5e4,               # Pa/sqrt(s): flow model error
    "x_s": 1e-5, "dx_s": 1e-3,            # the spool follows u deterministically
    "x": 1e-5, "v": 5e-3,                 # m/sqrt(s), m/s/sqrt(s)
    "z": 1e-5,                            # m/sqrt(s): bristle deflection
    "K_int": 0.1 * K_PER_LPM, "K_extA": 0.1 * K_PER_LPM, "K_extB": 0.1 * K_PER_LPM,  # 0.1 L/min/sqrt(s)
    "offset": 0.001,                      # 0.1 % of spool travel per sqrt(s)
    "F_d": 1e4,                           # N/sqrt(s): an unknown, changing load
}
#: Initial std of each base state, SI.
INITIAL_SD = {
    "p_A": 2e5, "p_B": 2e5, "x_s": 1e-3, "dx_s": 1e-2, "x": 1e-3, "v": 1e-3, "z": 1e-4,
    "K_int": 0.3 * K_PER_LPM, "K_extA": 0.3 * K_PER_LPM, "K_extB": 0.3 * K_PER_LPM, "offset": 0.01, "F_d": 2e4,
}
PROJECTIONS = ("joint", "leak")


def _number(value, low: float = 0.0, high: float = math.inf, open_low: bool = False) -> bool:
    """A real number (not a bool) in [low, high] (or (low, high] with open_low)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        return False
    return (low < value if open_low else low <= value) and value <= high


def _require(ok: bool, where: str, value, what: str) -> None:
    if not ok:
        raise ValueError(f"FilterConfig.{where} = {value!r}: {what}")


def _known(name, known, where: str, what: str) -> None:
    if name not in known:
        raise ValueError(f"FilterConfig.{where}: {name!r} is not {what}{did_you_mean(str(name), known)}")


@dataclass(frozen=True)
class SigmaPoints:
    """Merwe's scaled sigma points, as filterpy's ``MerweScaledSigmaPoints`` draws them."""

    alpha: float = 1.0  #: spread of the points around the mean
    beta: float = 2.0  #: prior knowledge of the distribution (2: Gaussian)
    kappa: float = 0.0  #: secondary scaling

    def __post_init__(self):
        _require(_number(self.alpha, 0.0, 1e3, open_low=True), "sigma_points.alpha", self.alpha, "must be > 0")
        _require(_number(self.beta, -1e3, 1e3), "sigma_points.beta", self.beta, "must be a finite number")
        _require(_number(self.kappa, -1e3, 1e3), "sigma_points.kappa", self.kappa, "must be a finite number")


@dataclass(frozen=True)
class Sensors:
    """The measurement noise the filter assumes."""

    pressure_noise: float = 20e3  #: Pa, std of each pressure sensor
    x_noise: float = 1e-5  #: m, std of a linear position sensor
    theta_pulse: float = THETA_PULSE  #: rad, the encoder's quantum (std pulse / sqrt(12))
    #: rad, added in quadrature to the quantisation: that error is constant while the arm is slow
    #: or held, not white, so pulse^2 / 12 alone overstates what the position tells at 1 kHz
    theta_noise_floor: float = 3e-5

    def __post_init__(self):
        for name in ("pressure_noise", "x_noise", "theta_pulse", "theta_noise_floor"):
            v = getattr(self, name)
            _require(_number(v, 0.0, 1e12), f"sensors.{name}", v, "must be a finite std >= 0 (SI)")
        _require(self.pressure_noise > 0, "sensors.pressure_noise", self.pressure_noise, "must be > 0")
        _require(self.x_noise > 0, "sensors.x_noise", self.x_noise, "must be > 0")
        _require(self.theta_pulse > 0 or self.theta_noise_floor > 0, "sensors.theta_noise_floor",
                 self.theta_noise_floor, "must be > 0 when theta_pulse is 0")


@dataclass(frozen=True)
class CalibrationStates:
    """Parameters of :data:`sam.P` whose relative error c the filter estimates along with the
    faults, as random walks written into the model as nominal * (1 + c): the load mass, the bulk
    modulus and the four valve notch flows, the nuisance the sensitivity studies rank first."""

    #: the parameters estimated, in state order after the base states
    states: tuple = ("m_L", "B_eff", "Q_N_PA", "Q_N_AT", "Q_N_PB", "Q_N_BT")
    initial_sd: float = 0.02  #: relative initial std of a state not in ``noise``
    walk: float = 0.002  #: relative random-walk std per sqrt(s) of a state not in ``noise``
    #: parameter -> (initial std, walk per sqrt(s)), relative, of those states that differ from the
    #: defaults above (an entry for a parameter not in ``states`` is not used). The load is unknown
    #: (0-800 kg around 494 kg); B_eff has Table 1's +-10 % as its prior.
    noise: dict = field(default_factory=lambda: {"m_L": (0.25, 0.05), "B_eff": (0.1, 0.005)})
    #: s: inside a long stroke of the input, from this long into it until this long into the rest
    #: after it (fdi.strokes.long_strokes), the walk stops (None: never): a steady stroke fixes
    #: none of these states and they would drift along what it leaves unseen
    hold_after_s: float | None = 2.0

    def __post_init__(self):
        object.__setattr__(self, "states", tuple(self.states))
        object.__setattr__(self, "noise", {k: tuple(v) for k, v in dict(self.noise).items()})
        for name in self.states:
            _known(name, P.__members__, "calibration.states", "a parameter of sam.P")
        _require(len(set(self.states)) == len(self.states), "calibration.states", self.states,
                 "names a parameter twice")
        _require(_number(self.initial_sd, 0.0, 1e3, open_low=True), "calibration.initial_sd", self.initial_sd,
                 "must be a relative std > 0")
        _require(_number(self.walk, 0.0, 1e3), "calibration.walk", self.walk, "must be a relative std >= 0")
        for name, value in self.noise.items():
            _known(name, P.__members__, "calibration.noise", "a parameter of sam.P")
            _require(len(value) == 2 and _number(value[0], 0.0, 1e3, open_low=True) and _number(value[1], 0.0, 1e3),
                     f"calibration.noise[{name!r}]", value, "must be (initial std > 0, walk >= 0), relative")
        _require(self.hold_after_s is None or _number(self.hold_after_s, 0.0, 1e9, open_low=True),
                 "calibration.hold_after_s", self.hold_after_s, "must be a duration > 0 s, or None")

    def prior(self, name: str) -> tuple[float, float]:
        """(initial std, walk per sqrt(s)) of calibration state ``name``, relative."""
        return self.noise.get(name, (self.initial_sd, self.walk))


@dataclass(frozen=True)
class UnknownInputStates:
    """Parameters of :data:`sam.P` whose absolute value the filter estimates as a random walk
    around the plant's: the disturbance flows into the chambers of the mismatch diagnosis."""

    #: the unknown inputs estimated (UNKNOWN_INPUT_SCALE names), after the calibration states
    states: tuple = ()
    #: input -> (initial std, walk per sqrt(s)), SI: 1 L/min and 2 L/min per sqrt(s)
    noise: dict = field(default_factory=lambda: {"Q_dA": (1e-3 / 60, 2e-3 / 60), "Q_dB": (1e-3 / 60, 2e-3 / 60)})

    def __post_init__(self):
        object.__setattr__(self, "states", tuple(self.states))
        object.__setattr__(self, "noise", {k: tuple(v) for k, v in dict(self.noise).items()})
        for name in self.states:
            _known(name, UNKNOWN_INPUT_SCALE, "unknown_inputs.states", "an unknown input")
            _known(name, self.noise, "unknown_inputs.states", "in unknown_inputs.noise")
        for name, value in self.noise.items():
            _known(name, UNKNOWN_INPUT_SCALE, "unknown_inputs.noise", "an unknown input")
            _require(len(value) == 2 and _number(value[0], 0.0, 1e3, open_low=True) and _number(value[1], 0.0, 1e3),
                     f"unknown_inputs.noise[{name!r}]", value, "must be (initial std > 0, walk >= 0), SI")


@dataclass(frozen=True)
class Constraints:
    """How the leak coefficients are kept non-negative."""

    clip_leaks: bool = True  #: leak sigma points are clipped at 0 where they enter the model
    project_mean: bool = True  #: the reported leak means are projected onto K >= 0
    #: the filter's own posterior is projected too (with ``project_mean``)
    project_internal: bool = True
    #: "joint": a negative leak mean is set to 0 and the other states move along their regression
    #: on it (the minimum P^-1-distance projection); "leak": only the leak mean is set to 0
    projection: str = "joint"
    symmetrise: bool = True  #: P is symmetrised after every update

    def __post_init__(self):
        for name in ("clip_leaks", "project_mean", "project_internal", "symmetrise"):
            _require(isinstance(getattr(self, name), bool), f"constraints.{name}", getattr(self, name),
                     "must be true or false")
        _require(self.projection in PROJECTIONS, "constraints.projection", self.projection,
                 f"must be one of {', '.join(PROJECTIONS)}")


@dataclass(frozen=True)
class Guards:
    """What the filter does when it diverges: reset its covariance, restore its state."""

    nis_tau_s: float = 0.5  #: s, time constant of the exponentially weighted NIS
    #: the covariance is reset to P0 when the weighted NIS exceeds this many times its mean (3
    #: channels); 0: never
    nis_factor: float = 8.0
    jitter: float = 1e-9  #: first relative jitter added to P's diagonal when its Cholesky fails
    #: largest |state| in its internal unit (1e6 MPa, 10 km/s, 1e6 L/min): beyond it the mean has
    #: diverged and its last sane value is restored with P0, as for a non-finite one
    max_scaled_state: float = 1e6

    def __post_init__(self):
        _require(_number(self.nis_tau_s, 0.0, 1e6), "guards.nis_tau_s", self.nis_tau_s, "must be a time >= 0 s")
        _require(_number(self.nis_factor, 0.0, 1e12), "guards.nis_factor", self.nis_factor, "must be >= 0")
        _require(_number(self.jitter, 0.0, 1.0, open_low=True), "guards.jitter", self.jitter, "must be in (0, 1]")
        _require(_number(self.max_scaled_state, 0.0, 1e300, open_low=True), "guards.max_scaled_state",
                 self.max_scaled_state, "must be > 0")


@dataclass(frozen=True)
class StopRules:
    """What the filter learns with the piston on an end stop."""

    #: where a linear sensor reads the piston within ``margin_m`` of a stop, only these states (and
    #: the model states) learn from the position; the others from the pressures alone. The
    #: inelastic stop truncates the sigma points, and the position's one-sided innovation there is
    #: no evidence about the leaks or the valve. None: every state learns from every reading.
    learners: tuple | None = ("F_d", "c_m_L")
    margin_m: float = 1e-3  #: m: "on an end stop", for ``learners`` and the detector's stop rules
    #: s: once the input has rested in the hold band with the measured piston within
    #: ``hold_margin_m`` of a stop this long without a break, the random walks of the fault and
    #: calibration states stop until either ends (None: never); pressed on a stop with the spool at
    #: null they show only through the null leakage, and would wander along its balance
    hold_s: float | None = 2.0
    #: m: "pressed on an end stop" for ``hold_s``: 3 encoder pulses at the retracted stop (not
    #: ``margin_m``: a light boom creeping off the stop shows the offset by that creep)
    hold_margin_m: float = 1e-4
    #: N/m: the filter's model draws the end stops as a spring-damper contact of this stiffness at
    #: the piston (sam.EndStops, Eq. (C1)) where the plant's are rigid, and takes the readings
    #: beyond a stop as they are; 0: rigid and inelastic (readings beyond a stop read as the stop).
    #: 4e9: a sink of 5 um per 20 kN, under the encoder's quantum
    contact_stiffness_N_per_m: float = 4e9
    #: 1, that contact's damping ratio at the reduced mass: restitution 0.21 (sam.contact.restitution),
    #: between a machine's (0.3-0.8) and sam's own rigid stop's (0); the filter's 1 ms Euler step is
    #: stable on it while 1 ms x sqrt(k / m) < 2 x this (0.70 with no load at the retracted stop)
    contact_damping_ratio: float = 0.7

    def __post_init__(self):
        if self.learners is not None:
            object.__setattr__(self, "learners", tuple(self.learners))
        _require(_number(self.margin_m, 0.0, 1.0), "stops.margin_m", self.margin_m, "must be a distance >= 0 m")
        _require(_number(self.hold_margin_m, 0.0, 1.0), "stops.hold_margin_m", self.hold_margin_m,
                 "must be a distance >= 0 m")
        _require(self.hold_s is None or _number(self.hold_s, 0.0, 1e9), "stops.hold_s", self.hold_s,
                 "must be a duration >= 0 s, or None")
        _require(_number(self.contact_stiffness_N_per_m, 0.0, 1e13), "stops.contact_stiffness_N_per_m",
                 self.contact_stiffness_N_per_m, "must be a stiffness >= 0 N/m (0: rigid stops)")
        _require(_number(self.contact_damping_ratio, 0.0, 1.0) and self.contact_damping_ratio < 1.0,
                 "stops.contact_damping_ratio", self.contact_damping_ratio, "must be a damping ratio in [0, 1)")

    @classmethod
    def rigid(cls) -> StopRules:
        """No contact of the filter's own: the plant's stops as its file has them (rigid and
        inelastic unless it says otherwise), as the recordings sam makes have them."""
        return cls(contact_stiffness_N_per_m=0.0)

    def model_params(self, params: np.ndarray) -> np.ndarray:
        """The plant vectors ``params`` (B, len(P)) as the filter's model steps them: rows whose
        plant has rigid stops (k_stop = 0) get this contact (a plant's own contact is kept)."""
        if self.contact_stiffness_N_per_m == 0.0:
            return params
        out = np.array(params, dtype=float)
        rigid = out[:, P.k_stop] == 0.0
        out[rigid, P.k_stop] = self.contact_stiffness_N_per_m
        out[rigid, P.zeta_stop] = self.contact_damping_ratio
        return out


@dataclass(frozen=True)
class FormNoise:
    """Process noise where the model's form is known to be uncertain (:mod:`fdi.form_noise`): on
    the chamber pressures, at the null-leakage band's edge, where Eqs. (13)-(14) step the leakage
    off (a real valve's fades over an unknown width, and a position loop parks the spool there),
    near cavitation, where Eqs. (8)-(9) keep a constant bulk modulus, at an end stop, whose
    contact the model draws inelastic, and where a reading comes back from the transmitter's
    floor (a cavitating chamber's void may have absorbed the flow through it)."""

    #: 1, fraction of leak_band: "at the edge" is | |x_s + offset| - leak_band | <= margin leak_band
    #: (a position loop parks the spool within a few tenths of it; the fade's width is unknown)
    band_margin: float = 0.2
    #: 1, the std of each chamber's flow at the edge as a fraction of its null-leakage paths' flow
    #: (1: either path may or may not flow); 0: Eqs. (13)-(14) taken as exact
    band_share: float = 1.0
    #: Pa (gauge): below it a chamber's oil releases air and its bulk modulus is unknown (near
    #: atmospheric; at 1 MPa it would also blur a healthy meter-out chamber: K_extA read as K_extB)
    low_pressure: float = 0.2e6
    #: 1, the std of the chamber's pressure-driving flow there as a fraction of its displacement
    #: flow A |v| (1: the pressure may not follow it at all); 0: Eqs. (8)-(9) taken as exact
    low_share: float = 1.0
    #: s: the window over which the piston's rate is taken from the measured position
    velocity_window_s: float = 0.02
    #: m: within this of an end stop (the measured piston) the piston may be in contact: a real
    #: stop gives and rebounds (the rig's: 0.3-0.5 mm, at half the impact speed), the model's
    #: stops it dead; and the encoder's frame puts a stop up to mm off the model's
    stop_margin_m: float = 2e-3
    #: 1, the std of the chamber's displacement flow near a stop as a fraction of A |v| (1: the
    #: piston may rebound as fast as it came); 0: the inelastic stop taken as exact
    stop_share: float = 1.0
    #: 1, where a chamber's reading comes back from the transmitter's floor (it may have
    #: cavitated): the std of its pressure as a fraction of the pressure the flow through it
    #: while at the floor would build (a void of unknown size may have absorbed it all); 0: none
    floor_share: float = 1.0

    def __post_init__(self):
        for name in ("band_margin", "band_share", "low_share", "stop_share", "floor_share"):
            _require(_number(getattr(self, name), 0.0, 1e3), f"form_noise.{name}", getattr(self, name),
                     "must be a fraction >= 0")
        _require(_number(self.low_pressure, -1e5, 1e9), "form_noise.low_pressure", self.low_pressure,
                 "must be a gauge pressure >= -1e5 Pa")
        _require(_number(self.velocity_window_s, 0.0, 10.0, open_low=True), "form_noise.velocity_window_s",
                 self.velocity_window_s, "must be a duration > 0 s")
        _require(_number(self.stop_margin_m, 0.0, 1.0), "form_noise.stop_margin_m", self.stop_margin_m,
                 "must be a distance >= 0 m")

    @classmethod
    def exact(cls) -> FormNoise:
        """Every term off: the model's form taken as exact everywhere."""
        return cls(band_share=0.0, low_share=0.0, stop_share=0.0, floor_share=0.0)

    @property
    def active(self) -> bool:
        """Whether any term adds noise (else the filter is the model's own, bit for bit)."""
        return self.band_share > 0.0 or self.low_share > 0.0 or self.stop_share > 0.0 or self.floor_share > 0.0


@dataclass(frozen=True)
class FilterConfig:
    """The augmented-state UKF's settings (:func:`fdi.filter.run_filter`); the defaults are the
    shipped filter."""

    #: state name -> random-walk std per sqrt(s), SI, for the 12 base states (:data:`PROCESS_NOISE`)
    process_noise: dict = field(default_factory=lambda: dict(PROCESS_NOISE))
    #: state name -> initial std, SI, for the 12 base states (:data:`INITIAL_SD`)
    initial_sd: dict = field(default_factory=lambda: dict(INITIAL_SD))
    sigma_points: SigmaPoints = field(default_factory=SigmaPoints)  #: the unscented transform's spread
    sensors: Sensors = field(default_factory=Sensors)  #: the measurement noise
    calibration: CalibrationStates = field(default_factory=CalibrationStates)  #: relative parameter errors learnt
    unknown_inputs: UnknownInputStates = field(default_factory=UnknownInputStates)  #: absolute inputs learnt
    constraints: Constraints = field(default_factory=Constraints)  #: how estimates are kept physical
    guards: Guards = field(default_factory=Guards)  #: when a diverging filter is reset
    stops: StopRules = field(default_factory=StopRules)  #: what the filter learns on and near the end stops
    form_noise: FormNoise = field(default_factory=FormNoise)  #: the pressures' noise where the model's form errs
    #: V: the input's hold band, |u| at most this: the valve at rest (calibration and stop holds)
    hold_band_V: float = 0.3
    #: the model's integration scheme in the prediction (sam.SCHEMES), one step per ms: "euler" is
    #: Eq. (22), which the shipped thresholds were derived with; "heun" the converged estimation
    #: default of docs/rig.md (1.92x the step's cost; its effect on rig data: docs/fdi.md)
    model_scheme: str = "euler"

    def __post_init__(self):
        _known(self.model_scheme, tuple(SCHEMES), "model_scheme", "an integration scheme")
        for name in ("process_noise", "initial_sd"):
            table = dict(getattr(self, name))
            object.__setattr__(self, name, table)
            for key, value in table.items():
                _known(key, STATE_NAMES, name, "a base state")
                low_ok = _number(value, 0.0, 1e12, open_low=(name == "initial_sd"))
                _require(low_ok, f"{name}[{key!r}]", value,
                         "must be a finite std " + ("> 0" if name == "initial_sd" else ">= 0") + " (SI)")
            missing = [s for s in STATE_NAMES if s not in table]
            if missing:
                raise ValueError(f"FilterConfig.{name}: no value for {', '.join(map(repr, missing))}")
        for name, kind in (("sigma_points", SigmaPoints), ("sensors", Sensors), ("calibration", CalibrationStates),
                           ("unknown_inputs", UnknownInputStates), ("constraints", Constraints), ("guards", Guards),
                           ("stops", StopRules), ("form_noise", FormNoise)):
            _require(isinstance(getattr(self, name), kind), name, getattr(self, name), f"must be a {kind.__name__}")
        clash = set(self.calibration.states) & set(self.unknown_inputs.states)
        _require(not clash, "unknown_inputs.states", self.unknown_inputs.states,
                 f"{sorted(clash)} are calibration states too")
        possible = STATE_NAMES + tuple(f"c_{p}" for p in P.__members__) + tuple(UNKNOWN_INPUT_SCALE)
        for name in self.stops.learners or ():  # a state this filter may lack (c_m_L without the load state)
            _known(name, possible, "stops.learners", "a filter state")
        _require(_number(self.hold_band_V, 0.0, 1e3), "hold_band_V", self.hold_band_V, "must be an input band >= 0 V")

    # ------------------------------------------------------------------ variants

    def with_(self, **groups) -> "FilterConfig":
        """This configuration with some groups or fields replaced."""
        return replace(self, **groups)

    def with_process_noise(self, **stds) -> "FilterConfig":
        """This configuration with the random walk of the named base states replaced (SI per sqrt(s))."""
        return replace(self, process_noise={**self.process_noise, **stds})

    def with_initial_sd(self, **stds) -> "FilterConfig":
        """This configuration with the initial std of the named base states replaced (SI)."""
        return replace(self, initial_sd={**self.initial_sd, **stds})

    # ------------------------------------------------------------------ the state layout

    @property
    def n_states(self) -> int:
        """Number of filter states: the 12 base states, the calibration states, the unknown inputs."""
        return N_AUG + len(self.calibration.states) + len(self.unknown_inputs.states)

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the filter states: the base states, ``c_<param>`` per calibration state, then
        the unknown inputs under their parameter names."""
        return (STATE_NAMES + tuple(f"c_{name}" for name in self.calibration.states)
                + tuple(self.unknown_inputs.states))

    def state_scale(self) -> np.ndarray:
        """(n_states,) internal unit of every state (SI per unit)."""
        unknown = [UNKNOWN_INPUT_SCALE[name] for name in self.unknown_inputs.states]
        return np.concatenate([SCALE, np.full(len(self.calibration.states), CALIBRATION_SCALE),
                               np.asarray(unknown, float)])

    def param_layout(self) -> tuple[np.ndarray, np.ndarray]:
        """(parameter column of sam.P, relative flag) of every augmented state (index >= N_MODEL)."""
        extra = self.calibration.states + self.unknown_inputs.states
        cols = np.concatenate([PARAM_COLS, np.array([int(P[n]) for n in extra], dtype=np.int64)])
        rel = np.concatenate([np.zeros(len(PARAM_COLS)), np.ones(len(self.calibration.states)),
                              np.zeros(len(self.unknown_inputs.states))])
        return cols.astype(np.int64), rel

    def noise_vectors(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, p0) (n_states,): random-walk std per sqrt(s) and initial std of every state, SI
        (relative for the calibration states)."""
        cal = [self.calibration.prior(name) for name in self.calibration.states]
        unk = [self.unknown_inputs.noise[name] for name in self.unknown_inputs.states]
        q = np.array([self.process_noise[s] for s in STATE_NAMES] + [c[1] for c in cal] + [u[1] for u in unk], float)
        p0 = np.array([self.initial_sd[s] for s in STATE_NAMES] + [c[0] for c in cal] + [u[0] for u in unk], float)
        return q, p0
