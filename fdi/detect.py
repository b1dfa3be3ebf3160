"""Residuals, CUSUM alarms and the diagnosis (healthy / one fault / several / not isolable).

Residuals (per sample):

* ``nu_pA``, ``nu_pB``, ``nu_pos``: the filter's normalised innovations, N(0, 1)
  when the model fits;
* ``r_<hypothesis>``: each fault estimate against 0 in units of sqrt(sd^2 + nuisance^2)
  (absolute; written, not used for alarms);
* ``d_<param>``: the change residual, (estimate - healthy baseline) in units of
  sqrt(sd^2 + sigma[regime]^2): the baseline is the recording's own estimate over
  [warmup, warmup + baseline_s] or a healthy reference recording's.

Alarms: a one-sided CUSUM per hypothesis on its change residual in continuous time,
``g <- max(0, g exp(-dt / memory) + (r - drift) dt)``, held in regimes where the residual does
not vote, alarm when ``g > h`` [sigma s]. The memory bounds what a healthy run's lasting
offset of the change residual can add up to (``Thresholds.memory_s``); in long steady strokes
the K_int and offset tests count only large excursions (``Thresholds.long_stroke_s``,
``long_stroke_drift``: there those estimates wander by a few sigma); the false-alarm level
is stated per healthy run of ``Thresholds.run_length_s`` (a longer recording has more
chances). A sixth alarm source, the notch-flow trigger (:func:`notch_jump`, session 25), alarms
when a notch-flow calibration state of the filter jumps by several of its own std: a fault that
begins in a steady stroke often moves those states before its own. sigma, the votes, the
confusable pairs and h come from the sensitivity studies of
:mod:`fdi.thresholds` (docs/fdi.md). A model-fit alarm on the weighted NIS flags faults that no
parameter explains.

Isolation and size: ``Thresholds.isolation = "likelihood"`` (the default) hands an alarm to the
bank of constrained filters of :mod:`fdi.isolate`; "signature" keeps the first-alarm rule with
the confusable pairs of the thresholds file.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numba
import numpy as np

from sam import P, S
from sam.errors import did_you_mean

from .strokes import after_long_segment, directions, first_motion, long_strokes
from .filter import FilterOutput, near_end_stop, sample_step
from .states import I_KEXTA, I_KEXTB, I_KINT, I_OFFSET, I_X, N_AUG, leak_lpm

#: Fault hypotheses and the state each one reads (sign: +1 above healthy, -1 below).
HYPOTHESES = {
    "K_int": (I_KINT, +1),
    "K_extA": (I_KEXTA, +1),
    "K_extB": (I_KEXTB, +1),
    "offset+": (I_OFFSET, +1),
    "offset-": (I_OFFSET, -1),
}
RESIDUAL_NAMES = ("nu_pA", "nu_pB", "nu_pos") + tuple(f"r_{h}" for h in HYPOTHESES)
#: The alarm trigger that is not a fault hypothesis (session 25; :func:`notch_jump`): its
#: threshold is ``Thresholds.h[NOTCH_TRIGGER]`` [sigma] when the thresholds file has one.
NOTCH_TRIGGER = "notch_flow"
#: the detection filter's calibration states the trigger watches: the valve notches' flows
NOTCH_STATES = ("Q_N_PA", "Q_N_AT", "Q_N_PB", "Q_N_BT")
#: s: the trigger is not armed in the first ``Thresholds.transient_s`` of a stroke that follows a
#: rest or a stroke the other way at least this long (:func:`fdi.strokes.after_long_segment`).
#: Why: there the states learn what the long segment left unseen (in a long stroke their random
#: walk is held, ``FilterConfig.calib_hold_after_s``), and the studies' inputs hardly hold a
#: direction that long. Measured (session 25, healthy 20 s runs of 20-60 s cycles): armed there,
#: it raised false alarms 0.03 and 0.24 s into the first motion after 13-14 s rests (encoder, 200
#: runs; K_int ahead of "none" by 577 and 1024 nats) and 0.25 s into the reversal that ended a
#: 12.7 s retraction (linear, 115 runs; 51 nats). Armed only in steady strokes instead, it lost
#: what it is for, the offsets' early alarms (held out, +-1 % isolated within 1 s 93 / 89 % as
#: without it, wrong decisions 2 -> 5)
NOTCH_REST_S = 2.0
#: s; a baseline window with less unpinned data than this slides on (:func:`baseline_window`)
MIN_BASELINE_S = 0.2
#: Which change tests are held while the pressures are pinned (:func:`pinned`), per parameter:
#: (A at supply and B at tank, B at supply and A at tank). With no flow, an offset changes
#: nothing the sensors see, nor does a leak to tank from the chamber at tank pressure (it
#: carries no flow). The fed chamber's leak and the internal one do show: the supply notch
#: (or the B->T notch) passes them at a pressure drop dp_N (Q / (Q_N x_s))^2, 17 kPa for
#: 0.5 L/min through 3 V of opening, seen in 0.1 s against 20 kPa noise. Measured: the
#: shipped healthy 40 s cycle (494 kg) sat 5 s on the retracted end stop at 0 / 10 MPa while
#: its K_extA estimate crept to 0.43 L/min (the non-negative estimate ratchets where it is
#: unobservable) and alarmed; the healthy 60 s cycle (800 kg) stalls 23 s at 10 / 0 MPa and
#: alarmed as a -8 % offset. The pressure transients at an end stop are NOT pinned and carry
#: much about the valve (a +5 % offset on the end stop is learnt in 0.6 s).
UNOBSERVABLE_PINNED = {"K_int": (False, False), "K_extA": (False, True), "K_extB": (True, False),
                       "offset": (True, True)}
#: m: the piston "rests on an end stop" (:func:`resting_on_stop`) within this of it. Why the
#: offset test is held there: on the NOMINAL plant (the filter's own model, only sensor noise)
#: the offset estimate drifts while the piston rests on the extension stop with the valve at
#: null, and the bank's offset hypothesis then leads the healthy one by 150-360 nats
#: (2026-11-21, 20-60 s cycles, 100 runs from the encoder: 6 confirmed false alarms, 4 of them
#: there). The stop truncates the velocity sigma points (an inelastic stop), which biases the
#: predicted pressures; the offset, which sets the null-leakage balance, absorbs the bias.
STOP_MARGIN_M = 1e-3
#: Pa: K_int's change test is held where |p_A - p_B| is below this (:func:`balanced`): a leak
#: across the piston flows with the root of that difference, so there it carries almost nothing
#: (a 1 L/min leak at 10 MPa passes 0.2 L/min at 0.4 MPa, 0.03 L/min at 10 kPa) and its estimate
#: is free to absorb any small flow-balance error. Measured (session 18): a 3.4 V retraction at
#: 187 kg held p_A = p_B = 6.65 MPa for 4 s and K_int's estimate crept 0.02 -> 0.77 L/min
BALANCE_MARGIN_PA = 0.4e6
#: the tests held while the piston rests on an end stop with the valve at null. K_int too
#: (measured, new populations of healthy 20 s runs: 2 of the 3 false alarms that stood were K_int
#: at rest on the retracted stop at 755-757 kg, p_A 6.6 / p_B 1.0-1.5 MPa, leads 49-68 nats):
#: the same truncated-velocity bias acts on the pressure balance a leak across the piston sets
HELD_ON_STOP = ("K_int", "offset")


#: Operating regimes of the change test, from the measured valve input u:
#: "hold" |u| < band; extension u > band, retraction u < -band; "transient" for the
#: first ``transient_s`` after the direction was entered, "steady" afterwards.
REGIMES = ("hold", "extend-transient", "extend-steady", "retract-transient", "retract-steady")
#: Fault parameter behind each change residual, and the hypotheses it serves.
PARAMS = {"K_int": I_KINT, "K_extA": I_KEXTA, "K_extB": I_KEXTB, "offset": I_OFFSET}
SHIPPED_THRESHOLDS = Path(__file__).resolve().parents[1] / "scenarios" / "faults" / "thresholds.toml"
#: the position sensors a thresholds file is derived for (:attr:`Thresholds.position_sensor`):
#: "encoder", the joint angle from the SAM's quantised encoder (or x computed from it); "linear",
#: x from a linear transducer with white noise (fdi.synth.POSITION_SENSORS); the shipped file of each
SHIPPED_BY_SENSOR = {"encoder": SHIPPED_THRESHOLDS, "linear": SHIPPED_THRESHOLDS.with_name("thresholds_linear.toml")}


#: The allowed values of the Thresholds fields that name a method.
CHOICES = {"position_sensor": tuple(SHIPPED_BY_SENSOR)}
#: keys of older thresholds files whose options were retired (docs/fdi-design.md, "Retired"): the
#: value each may still hold (the one the detector has), or None when any value is ignored
RETIRED_KEYS = {"isolation": "likelihood", "detector": "cusum", "filter": "shipped", "confusable": None,
                "glr_h": None, "glr_start_s": None, "glr_window_s": None}


#: s: the healthy-run lengths a thresholds file may state its level for: at least a tune fault
#: run (fdi.tune.DURATION), at most an hour of simulation per run
MIN_RUN_LENGTH_S, MAX_RUN_LENGTH_S = 4.0, 3600.0


#: the parameters whose estimates wander in a long steady stroke (:attr:`Thresholds.long_stroke_s`):
#: a leak across the piston and a spool offset both bias the flow balance of a steady stroke
#: alike, so the data hardly separate them. The external leaks do not wander there (measured:
#: with the rule on them too, 0.25 L/min K_extA / K_extB leaks that begin inside a long stroke
#: were found in 70 / 57 % of runs instead of 90 / 70 %, for no fewer false alarms)
WANDERING = ("K_int", "offset")

#: the numeric fields a thresholds file may set with a range: (lowest, highest, what a valid
#: value is); an absent key is the dataclass default (for memory_s: no memory)
RANGE_FIELDS = {
    "drift": (0.0, 1e3, "a CUSUM drift in sigma (>= 0)"),
    "long_stroke_drift": (0.0, 1e3, "a CUSUM drift in sigma (>= 0)"),
    "memory_s": (1e-9, 1e9, "a time constant in seconds (> 0; leave it out for none)"),
    "long_stroke_s": (1e-3, 1e9, "a duration in seconds (> 0; leave it out for no long-stroke rule)"),
    "run_length_s": (MIN_RUN_LENGTH_S, MAX_RUN_LENGTH_S,
                     f"a run length in seconds ({MIN_RUN_LENGTH_S:g}-{MAX_RUN_LENGTH_S:g})"),
    "sample_dt_s": (1e-6, 0.5, "a sampling step in seconds (1e-6 to 0.5)"),
    "confirm_nats": (0.0, 1e6, "an evidence in nats (>= 0; 0: every alarm stands)"),
    "trigger_level": (1e-6, 1.0, "a rate of alarms per healthy run (0-1; leave it out for h at false_alarm_level)"),
    "false_alarm_level": (1e-9, 1.0, "a rate of false alarms per healthy run (0-1)"),
    "false_isolation_level": (1e-9, 1.0, "a rate of wrong isolations (0-1)"),
    "warmup_s": (0.0, MAX_RUN_LENGTH_S, "a finite number >= 0 (a duration in seconds)"),
    "baseline_s": (0.0, MAX_RUN_LENGTH_S, "a finite number >= 0 (a duration in seconds)"),
    "transient_s": (0.0, MAX_RUN_LENGTH_S, "a finite number >= 0 (a duration in seconds)"),
    "nis_hold_s": (0.0, MAX_RUN_LENGTH_S, "a finite number >= 0 (a duration in seconds)"),
    "notch_jump_window_s": (1e-3, 60.0, "a window in seconds (1e-3 to 60)"),
    "band_V": (0.0, 1e3, "a finite number >= 0 (an input band in volts)"),
    "nis_limit": (0.0, 1e12, "a finite number >= 0 (a weighted NIS)"),
    "pin_margin_Pa": (-1e12, 1e12, "a pressure margin in Pa (finite; below 0 nothing is pinned)"),
}


def _is_number(x) -> bool:
    """A real number from a file (TOML reads true as a bool, which Python counts as 1)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _is_positive(x) -> bool:
    """A finite number > 0 (TOML reads nan and inf as floats)."""
    return _is_number(x) and 0.0 < x < math.inf


def _is_regime_list(test):
    """A check of a list with one entry per regime (:data:`REGIMES`), each passing test."""
    return lambda v: isinstance(v, list) and len(v) == len(REGIMES) and all(map(test, v))


#: the per-hypothesis and per-parameter tables of a thresholds file: (the keys it must have,
#: the check of each value, what a valid value is).
TABLE_FIELDS = {
    "h": (tuple(HYPOTHESES) + (NOTCH_TRIGGER,), _is_positive,
          f"a CUSUM threshold in sigma s, or the {NOTCH_TRIGGER} trigger's in sigma (> 0)"),
    "sigma": (tuple(PARAMS), _is_regime_list(_is_positive),
              f"a list of {len(REGIMES)} healthy spreads (> 0, SI), one per regime {REGIMES}"),
    "votes": (tuple(PARAMS), _is_regime_list(lambda b: isinstance(b, bool)),
              f"a list of {len(REGIMES)} true/false, one per regime {REGIMES}"),
    "nuisance_sd": (tuple(PARAMS), _is_positive, "a spread (> 0, SI)"),
}

#: keys a table may leave out: files before session 25 have no notch-flow trigger
OPTIONAL_KEYS = {"h": (NOTCH_TRIGGER,)}


def _check_tables(data: dict) -> None:
    """Raise ValueError naming the table, the key and the fault when a table of a thresholds
    file is not what :class:`Thresholds` needs (its numeric fields: :data:`RANGE_FIELDS`)."""
    for name, (keys, ok, what) in TABLE_FIELDS.items():
        table = data.get(name)
        if table is None:
            continue
        if not isinstance(table, dict):
            raise ValueError(f"{name!r} = {table!r} is not a table with the keys {', '.join(keys)}")
        for key, value in table.items():
            if key not in keys:
                raise ValueError(f"{name!r}: unknown key {key!r}{did_you_mean(key, keys)}")
            if not ok(value):
                raise ValueError(f"'{name}.{key}' = {value!r} is not {what}")
        missing = [k for k in keys if k not in table and k not in OPTIONAL_KEYS.get(name, ())]
        if missing:
            raise ValueError(f"{name!r} has no value for {', '.join(map(repr, missing))}")


@dataclass(frozen=True)
class Thresholds:
    """Decision thresholds of the change test (see docs/fdi.md).

    The shipped values (:meth:`shipped`) come from ``samfdi fdi thresholds``: the
    leakage GSA gives ``votes`` and ``confusable``, the nuisance GSA gives ``sigma``
    and ``h``. ``Thresholds()`` is the shipped file when it exists.
    """

    drift: float = 1.0  #: sigma; CUSUM reference value: only r beyond this accumulates
    #: s: the CUSUM forgets with this time constant; None: it never forgets (the classic CUSUM,
    #: sessions 1-10). Why: a healthy run's change residual is not white, it carries an offset
    #: that lasts the whole run (the calibration and load estimates settle at a slightly other
    #: place once the run has moved both ways); the classic CUSUM integrates any such offset
    #: beyond the drift without bound. Measured (docs/fdi.md, "Long recordings"): with the
    #: thresholds of 4 s runs, 44 of 100 healthy 20 s runs false-alarmed.
    memory_s: float | None = None
    #: s: None: no long-stroke rule (sessions 1-11). A number S: from S into an extension or
    #: retraction until S into the rest after it (:func:`long_strokes`) the CUSUMs of K_int and
    #: the offset (:data:`WANDERING`) count only what exceeds ``long_stroke_drift`` instead of
    #: ``drift``. Why: in a steady stroke the
    #: estimates wander along directions the data hardly constrain (K_int with the offset, the
    #: load mass with F_d), driven by the pressure noise (without it the wandering is gone), by
    #: up to about 3 sigma, and snap back when the stroke ends. Measured (docs/fdi.md, "Long
    #: steady strokes"): healthy 20 s runs of 20-60 s cycles at 0-800 kg false-alarm about half
    #: as often (held out: 13 and 17 of 100 instead of 21 and 32), at the same 1 s detection of
    #: the tune's faults (its inputs hold a direction for at most 2 s) and better detection of
    #: faults that begin inside a long stroke than with the tests held there.
    long_stroke_s: float | None = None
    long_stroke_drift: float = 4.0  #: sigma: the CUSUM drift in long strokes (long_stroke_s)
    #: sigma s, per hypothesis; and under :data:`NOTCH_TRIGGER`, if present, the threshold [sigma]
    #: of the notch-flow trigger (:func:`notch_jump`; files before session 25 have none)
    h: dict = field(default_factory=lambda: {k: 1.0 for k in HYPOTHESES})
    #: s: the window over which the notch-flow trigger measures a jump (:func:`notch_jump`)
    notch_jump_window_s: float = 0.2
    warmup_s: float = 0.5  #: no alarms while the filter converges
    #: healthy baseline = mean estimate over [warmup, warmup + baseline_s], its unpinned samples
    #: (later ones if the run starts pinned: :func:`baseline_window`)
    baseline_s: float = 1.0
    #: healthy spread of (estimate - baseline) from model uncertainty, per parameter and regime (SI)
    sigma: dict = field(default_factory=lambda: {
        "K_int": [1.0e-9] * 5, "K_extA": [5e-10] * 5, "K_extB": [6e-10] * 5, "offset": [5e-3] * 5})
    #: regimes in which each parameter's change residual votes (True) or is held (False)
    votes: dict = field(default_factory=lambda: {k: [True] * 5 for k in PARAMS})
    band_V: float = 0.3  #: |u| below this: "hold"
    transient_s: float = 0.3
    #: Pa; chamber pressures within this of the supply and of the tank pressure are "pinned"
    #: (:func:`pinned`: stalled or on an end stop, no flow): the change tests of the parameters
    #: that are then unobservable are held (the CUSUM detector; the optional GLR one holds
    #: nothing). 15 sensor noise std (20 kPa), 3 % of the supply.
    pin_margin_Pa: float = 0.3e6
    nis_limit: float = 9.0  #: weighted NIS (3 channels; mean 3) above this is a model-fit alarm
    nis_hold_s: float = 0.5  #: ... when held this long
    #: per parameter, the weight w of the filter's own std in the change residual's spread,
    #: sqrt((w sd_filter)^2 + sigma_regime^2) (:func:`change_spread`); a parameter left out: 1,
    #: as in every file before session 16 (docs/fdi.md, "The change residual's spread")
    filter_sd_weight: dict = field(default_factory=lambda: {p: 1.0 for p in PARAMS})
    false_alarm_level: float = 0.01  #: the false-alarm level (per run) the detector is for
    #: the rate of CUSUM alarms per healthy run the h were chosen for, above ``false_alarm_level``:
    #: an alarm is a trigger that the bank confirms or withdraws (``confirm_nats``), so h can be
    #: lower than the false-alarm level alone allows; None: h at ``false_alarm_level`` (files
    #: before session 16). Why: the confirmation bank with the calibration uncertain (session 15)
    #: withdraws nearly every healthy trigger (docs/fdi.md, "A lower trigger")
    trigger_level: float | None = None
    run_length_s: float = 4.0  #: ... over healthy runs of this length
    #: s: the sampling step of the recordings the thresholds were derived for. sigma and h depend
    #: on it (measured: the 1 kHz thresholds give 12 % false alarms on 500 Hz recordings), so
    #: replay refuses a recording sampled otherwise (``samfdi fdi thresholds --sample-rate``)
    sample_dt_s: float = 1e-3
    #: the position sensor the thresholds were derived for (SHIPPED_BY_SENSOR): sigma and h depend
    #: on it (measured, healthy 20 s runs, session 17: the encoder file gives 0.5 % false alarms
    #: from the encoder, 0 % from x computed from it, 3.5 % from a linear x sensor with 10 um
    #: white noise); files before session 17 were derived for the encoder
    position_sensor: str = "encoder"
    #: absolute spread of each estimate (SI), for the confidence and the absolute residual r_*
    nuisance_sd: dict = field(default_factory=lambda: {
        "K_int": 1.00e-9, "K_extA": 5.14e-10, "K_extB": 6.07e-10, "offset": 5.19e-3})
    source: str = "placeholder defaults (no thresholds file)"
    #: "likelihood": the stated false-isolation level the log-likelihood margin is derived
    #: from (fdi.isolate.margin_for); not fitted to any run
    false_isolation_level: float = 0.01
    #: "likelihood": an alarm stands only when, within the bank's decision window after it, the
    #: best fault hypothesis' log-likelihood exceeds the healthy hypothesis' by this many nats
    #: (the bank's "none" filter) and its filter has moved the fault parameter by the smallest
    #: size of interest (fdi.isolate.MIN_SINGLE_SIZE); otherwise the alarm is withdrawn, the tests restart after the
    #: window and the run stays "healthy" unless a later alarm stands. 0: every alarm stands
    #: (sessions 1-13). Why: in long steady strokes the K_int and offset estimates wander to
    #: 5 sigma along a direction the data do not constrain; the bank, which compares the
    #: innovations' likelihoods, sees no fault there (measured: the leads at such alarms are -5 to
    #: +6 nats; the bank's decisions on 0.25 L/min leaks lead by 3 to 1400, 95 % by more than 10).
    #: Not ln((1 - a) / a) of a level a (4.6 nats at 1 %): the bank's healthy filter holds the
    #: calibration it learnt before the alarm, so its evidence is inflated by the model
    #: uncertainty (docs/fdi.md, "Confirmed alarms").
    confirm_nats: float = 20.0
    #: "likelihood": also test every pair of faults after the alarm (fdi.isolate.run_pairs,
    #: session 7) so that several simultaneous faults are named
    several_faults: bool = True

    @classmethod
    def load(cls, path: str | Path) -> "Thresholds":
        path = Path(path)
        text = path.read_text()
        if path.suffix == ".toml":
            import tomllib
            data = tomllib.loads(text)
        else:
            data = json.loads(text)
        data = dict(data.get("thresholds", data))
        for key, kept in RETIRED_KEYS.items():
            if key in data and kept is not None and data[key] != kept:
                raise ValueError(f"{key!r} = {data[key]!r}: that option was retired (only {kept!r} is left); derive "
                                 "the thresholds again with `samfdi fdi thresholds`")
            data.pop(key, None)
        known = set(cls.__dataclass_fields__)
        for key in data:
            if key not in known:
                raise ValueError(f"unknown key {key!r}{did_you_mean(key, known)}")
        for key, allowed in CHOICES.items():
            if key in data and data[key] not in allowed:
                raise ValueError(f"{key!r} = {data[key]!r} is not one of {', '.join(map(repr, allowed))}")
        _check_tables(data)
        for key, (lo, hi, what) in RANGE_FIELDS.items():
            v = data.get(key)
            if v is not None and not (_is_number(v) and lo <= v <= hi):
                raise ValueError(f"{key!r} = {v!r} is not {what}")
        level, trigger = data.get("false_alarm_level", cls.false_alarm_level), data.get("trigger_level")
        if trigger is not None and _is_number(level) and trigger < level:
            raise ValueError(f"'trigger_level' = {trigger!r} is below 'false_alarm_level' = {level!r}: the CUSUM "
                             "alarms (triggers) the bank confirms cannot be rarer than the false alarms")
        weights = data.get("filter_sd_weight", {})
        if not isinstance(weights, dict):
            raise ValueError(f"'filter_sd_weight' = {weights!r} is not a table of weights per parameter ({', '.join(PARAMS)})")
        for p, w in weights.items():
            if p not in PARAMS:
                raise ValueError(f"'filter_sd_weight': unknown parameter {p!r}{did_you_mean(p, PARAMS)}")
            if not (_is_number(w) and 0.0 <= w <= 1e3):
                raise ValueError(f"'filter_sd_weight.{p}' = {w!r} is not a weight (>= 0)")
        return cls(**data)

    @classmethod
    def shipped(cls, position_sensor: str = "encoder") -> "Thresholds":
        """The shipped thresholds for a position sensor (SHIPPED_BY_SENSOR)."""
        path = SHIPPED_BY_SENSOR[position_sensor]
        return cls.load(path) if path.exists() else cls(position_sensor=position_sensor)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)

    def sd_weight(self, param: str) -> float:
        """The weight of the filter's std in ``param``'s change residual (:attr:`filter_sd_weight`)."""
        return float(self.filter_sd_weight.get(param, 1.0))



def regimes(u: np.ndarray, dt: float, band: float = 0.3, transient_s: float = 0.3) -> np.ndarray:
    """Regime index (REGIMES) per sample of the input u (B, T)."""
    d, since = directions(u, dt, band)
    out = np.zeros(d.shape, dtype=np.int8)
    trans = since < transient_s
    out[d == 1] = np.where(trans[d == 1], 1, 2)
    out[d == 2] = np.where(trans[d == 2], 3, 4)
    return out


def pinned(out: FilterOutput, th: "Thresholds") -> np.ndarray:
    """(B, T, 2) bool: the chamber pressures pinned to the rails, [..., 0] A within
    ``th.pin_margin_Pa`` of the supply and B within it of the tank pressure, [..., 1] the other
    way round: the cylinder is stalled against its load or held on an end stop with the valve
    open, and no oil flows but the leaks. Pressures are the filter's posterior means (finite
    through NaN gaps); the supply is the measured p_S when the recording has it (the plant's in
    its gaps), else the plant's. False everywhere when the output carries no measured data
    (``out.inp``)."""
    B, T = out.mean.shape[:2]
    if out.inp is None:
        return np.zeros((B, T, 2), dtype=bool)
    p_S = out.inp.params[:, P.p_S][:, None]
    if out.inp.pS is not None:  # measured; in its gaps the plant's, as the filter does
        p_S = np.where(np.isnan(out.inp.pS), p_S, out.inp.pS)
    p_T = out.inp.params[:, P.p_T][:, None]
    hi = out.mean[:, :, :2] >= (p_S - th.pin_margin_Pa)[..., None]
    lo = out.mean[:, :, :2] <= (p_T + th.pin_margin_Pa)[..., None]
    return np.stack([hi[..., 0] & lo[..., 1], hi[..., 1] & lo[..., 0]], axis=2)


def on_end_stop(out: FilterOutput) -> np.ndarray:
    """(B, T) bool: the piston within STOP_MARGIN_M of an end stop (:func:`fdi.ukf.near_end_stop`).
    Position: the filter's posterior mean. False where the output carries no measured data
    (``out.inp``)."""
    B, T = out.mean.shape[:2]
    if out.inp is None:
        return np.zeros((B, T), dtype=bool)
    return near_end_stop(out.mean[:, :, I_X], out.inp.params, STOP_MARGIN_M)


def resting_on_stop(out: FilterOutput, th: "Thresholds") -> np.ndarray:
    """(B, T) bool: the piston on an end stop (:func:`on_end_stop`) with the valve input in the
    hold band: the piston is blocked and the spool at null, so the offset only shifts the
    balance of the valve's null leakage."""
    if out.u is None:
        return np.zeros(out.mean.shape[:2], dtype=bool)
    return on_end_stop(out) & (np.abs(out.u) < th.band_V)


def balanced(out: FilterOutput) -> np.ndarray:
    """(B, T) bool: the chamber pressures within BALANCE_MARGIN_PA of each other (the filter's
    posterior means), where a leak across the piston carries almost no flow."""
    return np.abs(out.mean[:, :, S.p_A] - out.mean[:, :, S.p_B]) < BALANCE_MARGIN_PA


def held(out: FilterOutput, th: "Thresholds") -> np.ndarray:
    """(B, 4, T) bool, PARAMS order: where each change test is held because the pinned
    pressures (:func:`pinned`) make its parameter unobservable (:data:`UNOBSERVABLE_PINNED`),
    the tests of HELD_ON_STOP while the piston rests on an end stop (:func:`resting_on_stop`),
    and K_int's where the pressures balance (:func:`balanced`)."""
    pin = pinned(out, th)
    hidden = np.stack([(pin[..., 0] & a) | (pin[..., 1] & b) for a, b in UNOBSERVABLE_PINNED.values()], axis=1)
    rest = resting_on_stop(out, th)
    for p in HELD_ON_STOP:
        hidden[:, list(PARAMS).index(p)] |= rest
    hidden[:, list(PARAMS).index("K_int")] |= balanced(out)
    return hidden


def held_on_stop(out: FilterOutput, th: "Thresholds") -> np.ndarray:
    """(B, 4, T) bool, PARAMS order: the tests held (:func:`held`) while the piston is on an end
    stop. There the model's inelastic stop biases the filters' predicted pressures, and a free
    fault parameter that cannot act fits that bias: the likelihood bank names no fault there
    (``hidden`` of :func:`fdi.isolate.isolate`). Measured, healthy 20 s runs of 20-60 s cycles
    from x (100 runs, seed 999): 5 of the 7 confirmed false alarms were on the retracted stop
    with the valve open (A at tank, B at supply), the bank's K_extA or offset ahead of "none" by
    21-135 nats; with every held sample hidden (stalls too) offset +2 % at 534-800 kg lost 2 of
    14 runs within 1 s, on the stop alone none."""
    return held(out, th) & on_end_stop(out)[:, None, :]


def cusum_drift(param: str, long_stroke: np.ndarray, th: "Thresholds") -> float | np.ndarray:
    """The CUSUM drift [sigma] of ``param``'s change test: ``th.long_stroke_drift`` on the
    long-stroke samples ``long_stroke`` (B, T; :func:`long_stroke_mask`) if it wanders there
    (:data:`WANDERING`), else ``th.drift``."""
    if param not in WANDERING or not long_stroke.any():
        return th.drift
    return np.where(long_stroke, th.long_stroke_drift, th.drift)


def long_stroke_mask(out: FilterOutput, th: "Thresholds") -> np.ndarray:
    """(B, T) bool: the samples under the long-stroke rule (:attr:`Thresholds.long_stroke_s`;
    all False without it or without the input)."""
    if th.long_stroke_s is None or out.u is None or len(out.t) < 2:
        return np.zeros(out.mean.shape[:2], dtype=bool)
    return long_strokes(out.u, sample_step(out.t), th.band_V, th.long_stroke_s)


def baseline_window(t: np.ndarray, hidden: np.ndarray, th: "Thresholds") -> tuple[np.ndarray, np.ndarray]:
    """Per run and parameter, the samples of its healthy baseline and those at which its change
    test is armed, both (B, P, T) bool, given the samples at which it is hidden (B, P, T;
    :func:`held`). The baseline is the samples of [warmup, warmup + baseline_s] that do not
    hide it; with fewer than ``MIN_BASELINE_S`` of them there (pinned from the start) it is the
    parameter's first ``baseline_s`` of such samples after the warm-up instead, armed after them
    (never, if there are not that many). Measured: the healthy 60 s cycle at 800 kg is pinned
    for its first 24 s; an offset baseline from there was 0.4 % (4 sigma) off the offset
    estimate of the first unpinned hold and alarmed offset+. A K_extA baseline from the same
    kind of stall (at 10 / 0 MPa, where K_extA shows) is sound, and sliding it over a 0.5 L/min
    step at 2 s delayed its alarm from 2.1 to 4.3 s."""
    dt = t[1] - t[0] if len(t) > 1 else 1e-3
    after = t >= th.warmup_s
    window = after & (t < th.warmup_s + th.baseline_s)
    if not window.any():  # a record shorter than the warm-up: its first quarter
        window = np.zeros_like(t, dtype=bool)
        window[: max(1, len(t) // 4)] = True
    seen = ~hidden
    w = window & seen
    ready = np.broadcast_to(t >= th.warmup_s + th.baseline_s, hidden.shape).copy()
    slide = w.sum(axis=2) * dt < MIN_BASELINE_S  # (B, P)
    if slide.any():
        n_base = max(1, int(round(th.baseline_s / dt)))
        count = np.cumsum(after & seen[slide], axis=1)
        w[slide] = after & seen[slide] & (count <= n_base)
        full = count >= n_base  # from the last baseline sample on; armed from the sample after it
        ready[slide] = np.concatenate([np.zeros((len(full), 1), dtype=bool), full[:, :-1]], axis=1)
    return w, ready


def before_motion(out: FilterOutput, th: "Thresholds") -> np.ndarray:
    """(B, T) bool: the samples before the valve input first leaves the hold band (``th.band_V``)
    and the ``th.warmup_s`` after that (all False without the input; all True if it never leaves).
    A recording that starts at rest learns no baseline there: at rest the load mass and the
    unknown force trade freely (an unobservable direction the filter's mean wanders along:
    measured, m_L +41 % with F_d -20 kN in a 2 s rest at 394 kg), the piston creeps and the
    friction builds, and the first motion then moves the fault estimates far from a baseline
    learnt at rest (session 18: 14 of 200 healthy 20 s runs of 20-60 s cycles that began with
    a rest of 1.6-12 s false-alarmed 0.04-0.9 s after their first motion)."""
    if out.u is None:
        return np.zeros(out.mean.shape[:2], dtype=bool)
    dt = sample_step(out.t)
    k_move = first_motion(out.u, th.band_V)
    return np.arange(out.u.shape[1])[None, :] < (k_move + int(round(th.warmup_s / dt)))[:, None]


def _first_motion_s(out: FilterOutput, th: "Thresholds", b: int) -> float | None:
    """Time [s] of run b's first motion (:func:`fdi.strokes.first_motion`); 0 without the input,
    None if the input never leaves the hold band."""
    if out.u is None:
        return 0.0
    k = int(first_motion(out.u[b:b + 1], th.band_V)[0])
    return float(out.t[k]) if k < len(out.t) else None


def own_baseline(out: FilterOutput, th: "Thresholds", hidden: np.ndarray | None = None):
    """The recording's own healthy baseline: (B, 4) mean of each fault estimate over its
    baseline window (:func:`baseline_window`, the samples of [warmup, warmup + baseline_s] at
    which it is not ``hidden``, (B, 4, T), nor before the first motion, :func:`before_motion`),
    and the samples at which its test is armed (B, 4, T)."""
    hidden = held(out, th) if hidden is None else hidden
    w, ready = baseline_window(out.t, hidden | before_motion(out, th)[:, None, :], th)
    est = np.stack([out.mean[:, :, j] for j in PARAMS.values()], axis=1)
    return np.where(w, est, 0.0).sum(axis=2) / np.maximum(w.sum(axis=2), 1), ready


def baseline_values(out: FilterOutput, th: "Thresholds", hidden: np.ndarray | None = None) -> np.ndarray:
    """(B, 4) the baseline of :func:`own_baseline`."""
    return own_baseline(out, th, hidden)[0]


def change_residuals(out: FilterOutput, th: "Thresholds", baseline: np.ndarray | None = None,
                     u: np.ndarray | None = None):
    """Change residuals d_<param> = (estimate - baseline) / :func:`change_spread`, name -> (B, T),
    the regime index (B, T) and the samples at which each is held (B, 4, T; :func:`held`). Zero
    before the baseline is known."""
    reg, hidden, base, ready = _test_masks(out, th, baseline, u)
    return _changes(out, th, reg, base, ready), reg, hidden


def _changes(out: FilterOutput, th: "Thresholds", reg, base, ready) -> dict:
    """The change residuals of :func:`change_residuals` from its masks (:func:`_test_masks`)."""
    res = {}
    for i, (name, j) in enumerate(PARAMS.items()):
        sd = change_spread(out.std[:, :, j], np.asarray(th.sigma[name], dtype=float)[reg], th.sd_weight(name))
        res[name] = np.where(ready[:, i], (out.mean[:, :, j] - base[:, i:i + 1]) / sd, 0.0)
    return res


def change_spread(sd_filter: np.ndarray, sigma: np.ndarray, w: float) -> np.ndarray:
    """The spread a change residual is counted in, sqrt((w sd_filter)^2 + sigma^2): the filter's
    std of the estimate weighted by w and the healthy spread of the change sigma (regime's;
    same units, elementwise)."""
    return np.maximum(np.sqrt((w * sd_filter) ** 2 + sigma**2), 1e-300)


def _test_masks(out: FilterOutput, th: "Thresholds", baseline=None, u: np.ndarray | None = None):
    """(regime (B, T), held (B, 4, T), baseline (B, 4), armed (B, 4, T)) of the change tests."""
    dt = sample_step(out.t)
    u = out.u if u is None else u
    reg = regimes(u, dt, th.band_V, th.transient_s) if u is not None else np.full(out.mean.shape[:2], 2, np.int8)
    hidden = held(out, th)
    if baseline is None:
        base, ready = own_baseline(out, th, hidden)
    else:
        base = np.broadcast_to(np.atleast_2d(baseline), (out.mean.shape[0], 4))
        ready = np.broadcast_to(out.t >= th.warmup_s, hidden.shape)
    return reg, hidden, base, ready


def tested_seconds(out: FilterOutput, th: "Thresholds", baseline=None) -> np.ndarray:
    """(B, 4) seconds in which each parameter's change test ran: armed (after its baseline),
    voting in the regime, not held by pinned pressures. A parameter tested for less than
    MIN_TESTED_S was not looked at, whatever the statistic says."""
    dt = sample_step(out.t)
    reg, hidden, _, ready = _test_masks(out, th, baseline)
    votes = np.stack([np.asarray(th.votes[p], dtype=bool)[reg] for p in PARAMS], axis=1)
    warm = out.t >= th.warmup_s
    return (ready & ~hidden & votes & warm).sum(axis=2) * dt


def residuals(out: FilterOutput, th: "Thresholds | None" = None, baseline=None) -> dict[str, np.ndarray]:
    """All residuals, name -> (B, T): innovations, absolute r_<hypothesis> and change d_<param>;
    with thresholds also the regime, the pinned samples and the long-stroke samples (0 / 1)."""
    res = {"nu_pA": out.nu[:, :, 0], "nu_pB": out.nu[:, :, 1], "nu_pos": out.nu[:, :, 2]}
    for name, (j, sign) in HYPOTHESES.items():
        extra = 0.0 if th is None else th.nuisance_sd.get(name.rstrip("+-"), 0.0)
        sd = np.maximum(np.sqrt(out.std[:, :, j] ** 2 + extra**2), 1e-300)
        res[f"r_{name}"] = sign * out.mean[:, :, j] / sd  # healthy value is 0 for every fault
    if th is not None:
        chg, reg, hidden = change_residuals(out, th, baseline)
        for name, r in chg.items():
            res[f"d_{name}"] = r
        res["regime"] = reg.astype(float)
        res["pinned"] = hidden.any(axis=1).astype(float)
        res["long_stroke"] = long_stroke_mask(out, th).astype(float)
    return res


def cusum(r: np.ndarray, drift: float | np.ndarray, dt: float, warmup: int | np.ndarray = 0,
          active: np.ndarray | None = None, memory_s: float | None = None) -> np.ndarray:
    """Continuous-time one-sided CUSUM of r (B, T) [sigma s] with memory ``memory_s`` [s] (None:
    none forgotten); where ``active`` is False (a regime in which the residual does not vote)
    the statistic is held: g_k = max(0, a g_(k-1) + (r_k - drift_k) dt), a = exp(-dt / memory_s),
    for k >= warmup, g = 0 before. ``drift``: a number or (B, T); ``warmup``: a sample index, or
    one per run (B,) (a test restarted after a withdrawn alarm). A constant r > drift brings g
    to (r - drift) memory_s."""
    excess = r - drift
    # a NaN residual (a gap) counts as r = 0: the statistic decays, it does not jump
    inc = np.ascontiguousarray(np.where(np.isnan(excess), -np.broadcast_to(drift, excess.shape), excess) * dt,
                               dtype=float)
    act = np.ones(inc.shape, dtype=bool) if active is None else np.ascontiguousarray(np.broadcast_to(active, inc.shape))
    keep = 1.0 if memory_s is None else math.exp(-dt / memory_s)
    start = np.ascontiguousarray(np.broadcast_to(np.asarray(warmup, dtype=np.int64), inc.shape[:1]))
    return _cusum_recursion(inc, act, keep, start)


@numba.njit(cache=True)
def _cusum_recursion(inc, active, keep, start):
    """g[b, k] = max(0, keep g[b, k-1] + inc[b, k]) where active, g[b, k-1] where not, from
    k = start[b] on (0 before)."""
    B, T = inc.shape
    g = np.zeros((B, T))
    for b in range(B):
        acc = 0.0
        for k in range(max(0, start[b]), T):
            if active[b, k]:
                acc = max(0.0, keep * acc + inc[b, k])
            g[b, k] = acc
    return g


def statistics(out: FilterOutput, th: Thresholds, baseline=None,
               start: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """CUSUM statistic per hypothesis on its change residual, name -> (B, T); held where
    the residual does not vote and where pinned pressures hide its parameter (:func:`held`);
    the drift of each test from :func:`cusum_drift` (larger for K_int and the offset in long
    strokes). With the notch-flow trigger (:func:`uses_notch_trigger`) also its statistic under
    :data:`NOTCH_TRIGGER` (:func:`notch_jump`, armed by :func:`notch_armed`). ``start``: (B,)
    samples at which each run's tests restart from 0 (after a withdrawn alarm,
    :func:`fdi.isolate.isolate`); never before the warm-up."""
    dt = sample_step(out.t)
    warm = int(round(th.warmup_s / dt))
    if start is not None:
        warm = np.maximum(warm, np.asarray(start, dtype=np.int64))
    reg, hidden, base, ready = _test_masks(out, th, baseline)
    chg = _changes(out, th, reg, base, ready)
    long_stroke = long_stroke_mask(out, th)
    stats = {}
    for h, (j, sign) in HYPOTHESES.items():
        param = h.rstrip("+-")
        active = np.asarray(th.votes[param], dtype=bool)[reg] & ~hidden[:, list(PARAMS).index(param)]
        stats[h] = cusum(sign * chg[param], cusum_drift(param, long_stroke, th), dt, warm, active, th.memory_s)
    if uses_notch_trigger(out, th):
        stats[NOTCH_TRIGGER] = notch_jump(out, th, notch_armed(out, th, ready), warm)
    return stats


def notch_armed(out: FilterOutput, th: Thresholds, ready: np.ndarray) -> np.ndarray:
    """(B, T) where the notch-flow trigger is armed: every change test armed (``ready``, (B, 4, T))
    and not just after a long rest or stroke (:data:`NOTCH_REST_S`; everywhere without the input)."""
    armed = ready.all(axis=1)
    if out.u is None:
        return armed
    return armed & ~after_long_segment(out.u, sample_step(out.t), th.band_V, NOTCH_REST_S, th.transient_s)


def uses_notch_trigger(out: FilterOutput, th: Thresholds) -> bool:
    """Whether the notch-flow trigger runs: the thresholds have its h and the detection filter has
    notch-flow states."""
    return NOTCH_TRIGGER in th.h and has_notch_states(out)


def has_notch_states(out: FilterOutput) -> bool:
    """Whether the filter that made ``out`` estimates the notch flows (:data:`NOTCH_STATES`)."""
    return all(n in out.config.calibration.states for n in NOTCH_STATES)


def notch_jump(out: FilterOutput, th: Thresholds, armed: np.ndarray, start=0) -> np.ndarray:
    """The notch-flow trigger's statistic (B, T) [sigma]: the largest jump of a notch-flow
    calibration state of the detection filter (:data:`NOTCH_STATES`) over the last
    ``th.notch_jump_window_s``, in its own posterior std at the window's start, less
    ``th.drift``, and 0 below that; 0 where not ``armed`` (B, T; :func:`notch_armed`) and before
    ``start`` + the window (a sample, or one per run (B,)). It alarms above ``th.h[NOTCH_TRIGGER]``.

    Why: in a steady stroke a fault that begins changes the flow balance as a notch-flow error
    does, and the filter puts the change where its covariance is largest, often on the notch
    states rather than on the fault state (measured, session 25: a -1 % offset stepping in a
    3.7 V retraction moved the A->T and P->B notch states by +4 % within 0.1 s while the offset
    estimate did not move until the valve came to rest 0.85 s later). A healthy machine's notch
    states only learn, by about their std; a jump of several std is news. The trigger says only
    *when*: the likelihood bank names the fault (:func:`fdi.isolate.isolate`), or withdraws it."""
    dt = sample_step(out.t)
    w = max(1, int(round(th.notch_jump_window_s / dt)))
    cols = [N_AUG + out.config.calibration.states.index(n) for n in NOTCH_STATES]
    z, sd = out.mean[:, :, cols], out.std[:, :, cols]
    jump = np.zeros(out.mean.shape[:2])
    if out.mean.shape[1] > w:
        jump[:, w:] = (np.abs(z[:, w:] - z[:, :-w]) / np.maximum(sd[:, :-w], 1e-300)).max(axis=2)
    k = np.arange(jump.shape[1])
    after = k[None, :] >= np.reshape(np.asarray(start, dtype=np.int64), (-1, 1)) + w
    return np.where(armed & after, np.maximum(jump - th.drift, 0.0), 0.0)


#: s: after a withdrawn alarm the change tests restart with each parameter's baseline re-learnt
#: as its mean estimate over this long before the restart (the end of the window the bank judged
#: healthy): :func:`restarted_statistics`
REBASE_S = 0.5
#: the parameters whose baselines are re-learnt after a withdrawn alarm: those that wander in long
#: strokes (:data:`WANDERING`), whose healthy excursions the re-learning is for. The external
#: leaks keep their baselines: their estimates do not wander, so an excursion the bank could not
#: confirm within its window is either gone soon or a leak too small to show there, which a
#: re-learnt baseline would hide for good (measured, session 17: 0.25 L/min K_extB in 10 s
#: recordings, 50 runs, judged as replay does: never found 3 -> 1; healthy 20 s runs, 500 from the
#: encoder and 500 from a linear x sensor: false alarms 2 -> 2 and 6 -> 6)
REBASE_PARAMS = WANDERING


def restarted_statistics(out: FilterOutput, th: Thresholds, baseline=None):
    """The ``restart`` of :func:`fdi.isolate.isolate`: start (B,) -> the statistics restarted
    there, each restarted run (start > 0) with the baselines of REBASE_PARAMS re-learnt as its
    mean estimates over the REBASE_S before start (the others as before); the runs not restarted
    with ``baseline`` (None: their own). Why re-learn: the
    bank has just judged the estimates' excursion healthy, so it is the machine's healthy state
    now; kept, the test alarms on it again and again and one of those looks may pass the
    confirmation (measured, 20-60 s cycles from the encoder: false alarms 2 -> 0 and 4 -> 2 of
    100, no fault beginning inside such a cycle found later; docs/fdi.md, "Confirmed alarms")."""
    dt = sample_step(out.t)
    n = max(1, int(round(REBASE_S / dt)))
    B = out.mean.shape[0]
    base0 = baseline_values(out, th) if baseline is None else np.broadcast_to(np.atleast_2d(baseline), (B, 4))
    cols = list(PARAMS.values())

    relearn = [i for i, p in enumerate(PARAMS) if p in REBASE_PARAMS]

    def restart(start: np.ndarray) -> dict:
        base = np.array(base0, dtype=float)
        for b in np.flatnonzero(start > 0):
            base[b, relearn] = out.mean[b, max(0, start[b] - n):start[b]][:, cols].mean(axis=0)[relearn]
        return statistics(out, th, base, start)

    return restart


def alarm_judging(out: FilterOutput, th: Thresholds, baseline=None) -> dict:
    """The keyword arguments of :func:`fdi.isolate.isolate` that judge alarms as the detector
    does: the confirmation evidence (``th.confirm_nats``), the tests restarted with re-learnt
    baselines after a withdrawn alarm (:func:`restarted_statistics`; not for the GLR detector,
    whose statistics are not CUSUMs) and no fault named on an end stop where it cannot act
    (:func:`held_on_stop`, :func:`on_end_stop`). Replay (:func:`diagnose`) and the tune both take them from here, so
    that they judge alike."""
    from . import isolate

    return {"confirm": isolate.confirm_evidence(th),
            "restart": restarted_statistics(out, th, baseline),
            "hidden": held_on_stop(out, th), "on_stop": on_end_stop(out)}


def detector_statistics(out: FilterOutput, th: Thresholds, diag: "Diagnosis", baseline=None, b: int = 0) -> dict:
    """The statistics of run b, name -> (1, T), as the detector ran them: after each withdrawn
    alarm restarted, their baseline re-learnt (``diag.likelihood["tests_restarted_s"]``,
    :func:`restarted_statistics`); without withdrawn alarms, :func:`statistics`."""
    one = slice(b, b + 1)
    stats = {h: g[one].copy() for h, g in statistics(out, th, baseline).items()}
    restart = restarted_statistics(out, th, baseline)
    for ts in diag.likelihood.get("tests_restarted_s", []):
        k = int(np.searchsorted(out.t, ts))
        start = np.zeros(out.mean.shape[0], dtype=np.int64)
        start[b] = k
        for h, g in restart(start).items():
            stats[h][0, k:] = g[b, k:]
    return stats


def first_alarm(g: np.ndarray, h: float) -> np.ndarray:
    """Index of the first sample with g > h per row (-1: none)."""
    above = g > h
    idx = np.argmax(above, axis=1)
    return np.where(above.any(axis=1), idx, -1)


def nis_alarm(out: FilterOutput, th: Thresholds) -> np.ndarray:
    dt = sample_step(out.t)
    hold = max(1, int(round(th.nis_hold_s / dt)))
    warm = int(round(th.warmup_s / dt))
    hi = out.nis > th.nis_limit
    hi[:, :warm] = False
    # run length of consecutive high samples: k minus the last low sample at or before k
    k = np.arange(hi.shape[1])
    last_low = np.maximum.accumulate(np.where(hi, -1, k[None, :]), axis=1)
    long_run = (k[None, :] - last_low) >= hold
    return np.where(long_run.any(axis=1), np.argmax(long_run, axis=1), -1)


@dataclass
class Diagnosis:
    status: str  #: "healthy" | "fault" | "several faults" | "fault, not isolable"
    isolated: list  #: hypotheses held responsible (candidates when not isolable)
    detection_time_s: float | None
    alarms: dict  #: hypothesis -> first alarm time [s]
    size: dict  #: hypothesis -> estimated size ({"value", "unit", "minus_2sigma", "plus_2sigma"})
    confidence: dict  #: hypothesis -> probability the parameter is off its healthy value
    model_fit_alarm_s: float | None
    filter_health: dict
    thresholds: dict
    note: str = ""
    #: "likelihood" isolation: when the bank decided [s] (None: not isolable or not run), and
    #: each hypothesis' log-likelihood relative to the best [nats] at that instant
    isolation_time_s: float | None = None
    likelihood: dict = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, default=float)


def diagnose(out: FilterOutput, th: Thresholds | None = None, b: int = 0,
             stats: dict | None = None, baseline=None, decision=None) -> Diagnosis:
    """The diagnosis of filter run b. With ``th.isolation == "likelihood"`` an alarm is
    isolated and sized by the likelihood bank (``decision``: a precomputed
    :class:`fdi.isolate.Decision` of run b, else it is computed here)."""
    th = Thresholds.shipped() if th is None else th
    stats = stats if stats is not None else statistics(out, th, baseline)
    t = out.t
    alarms = {}
    for h, g in stats.items():
        k = int(first_alarm(g[b:b + 1], th.h[h])[0])
        if k >= 0:
            alarms[h] = float(t[k])
    k_nis = int(nis_alarm(out, th)[b])
    nis_time = float(t[k_nis]) if k_nis >= 0 else None
    # one-sided offset: keep only the side that alarmed first
    if "offset+" in alarms and "offset-" in alarms:
        drop = "offset+" if alarms["offset+"] > alarms["offset-"] else "offset-"
        del alarms[drop]
    size, conf = {}, {}
    dt_s = t[1] - t[0] if len(t) > 1 else 0.0
    health = {"nan_samples": int(out.n_nan[b]), "jitter_events": int(out.n_jitter[b]),
              "covariance_resets": int(out.n_cov_reset[b]), "state_resets": int(out.n_state_reset[b]),
              # stalled or on an end stop at supply / tank pressure: the tests it hides are held
              "pinned_s": float(pinned(out, th)[b].any(axis=1).sum() * dt_s),
              # on an end stop with the valve at null: the K_int and offset tests are held
              "resting_on_stop_s": float(resting_on_stop(out, th)[b].sum() * dt_s),
              # in long strokes and the rest after them the K_int and offset tests count only
              # large excursions
              "long_stroke_s": float(long_stroke_mask(out, th)[b].sum() * dt_s),
              # the own baseline is learnt from the first motion on (before_motion); None: never moved
              "first_motion_s": _first_motion_s(out, th, b)}
    names = sorted(alarms, key=alarms.get)
    note = ""
    iso_time, lik = None, {}
    if names:
        status, isolated, size, conf, iso_time, lik, note = _likelihood_isolation(out, th, b, stats, decision,
                                                                                  baseline)
    elif nis_time is not None:
        status, isolated = "fault, not isolable", []
        note = ("the model stopped fitting the measurements (NIS alarm) but no fault parameter "
                "explains it: an unmodelled fault, a sensor fault or a plant-file mismatch")
    else:
        status, isolated = "healthy", []
    warning = model_fit_warning(nis_time, health)
    if warning:
        health["model_fit_warning"] = warning
        if not (status == "fault, not isolable" and not names):  # that note says it already
            note = f"{note}; {warning}" if note else warning
    tested = tested_seconds(out, th, baseline)[b]
    health["tested_s"] = {p: float(s) for p, s in zip(PARAMS, tested)}
    untested = [p for p, s in zip(PARAMS, tested) if s < MIN_TESTED_S]
    if untested and status == "healthy":
        untested_note = (f"healthy as far as tested: {', '.join(untested)} tested for less than {MIN_TESTED_S:g} s "
                         + ("(the pressures pinned at supply and tank, the recording too short after the baseline, "
                            "which is learnt from the first motion, or never in a regime where the thresholds let "
                            "that residual vote)" if health["first_motion_s"] is not None else
                            f"(the valve input never left its +-{th.band_V:g} V hold band, and the baseline is "
                            "learnt from the first motion)"))
        note = f"{untested_note}; {note}" if note else untested_note
    return Diagnosis(
        status=status, isolated=isolated,
        detection_time_s=(lik.get("alarm_s", alarms[names[0]]) if status != "healthy" and names else nis_time),
        alarms=alarms, size=size, confidence=conf, model_fit_alarm_s=nis_time, filter_health=health,
        isolation_time_s=iso_time, likelihood=lik,
        thresholds={"drift_sigma": th.drift, "h_sigma_s": dict(th.h), "warmup_s": th.warmup_s,
                    "baseline": "reference recording" if baseline is not None else
                    f"own estimates over [{th.warmup_s:g}, {th.warmup_s + th.baseline_s:g}] s after the first motion "
                    f"(unpinned samples; the first {th.baseline_s:g} s of them if the record starts pinned)",
                    "false_alarm_level": th.false_alarm_level, "trigger_level": th.trigger_level,
                    "run_length_s": th.run_length_s, "filter_sd_weight": {p: th.sd_weight(p) for p in PARAMS},
                    "cusum_memory_s": th.memory_s, "long_stroke_s": th.long_stroke_s,
                    "long_stroke_drift_sigma": th.long_stroke_drift,
                    "isolation": "likelihood", "position_sensor": th.position_sensor, "source": th.source},
        note=note,
    )


#: s: a parameter's change test that ran for less than this (armed, unpinned, voting) has not
#: looked at it: the test needs a few tenths of a second of a fault to alarm (mean delays
#: 0.1-0.5 s at 0.25-1 L/min), so "healthy" would mean "not looked at"
MIN_TESTED_S = 0.5


def model_fit_warning(nis_time: float | None, health: dict) -> str:
    """A warning when the model stopped fitting the recording (an NIS alarm, or the filter had
    to reset its covariance or state; none of the 41 shipped scenarios does either, on the
    nominal plant): then a named fault may be a symptom of a plant-file mismatch. '' if not."""
    resets = health["covariance_resets"] + health["state_resets"]
    if nis_time is None and resets == 0:
        return ""
    why = [f"NIS alarm at t = {nis_time:.3f} s"] if nis_time is not None else []
    if resets:
        why.append(f"{health['covariance_resets']} covariance and {health['state_resets']} state resets")
    return (f"the model does not fit this recording ({'; '.join(why)}): the diagnosis may reflect a plant "
            "file that does not describe this machine rather than a fault; check the plant file "
            "(`samfdi mismatch` locates what differs)")


def _likelihood_isolation(out: FilterOutput, th: Thresholds, b: int, stats: dict, decision=None, baseline=None):
    """Status, isolated, size, confidence, isolation time, likelihoods and note of run b from
    the likelihood bank (fdi.isolate), run up to DECISION_WINDOW_S after each alarm until one
    is confirmed (``th.confirm_nats``). ``baseline``: as given to :func:`statistics`."""
    from . import isolate

    dt = sample_step(out.t)
    margin = isolate.margin_for(th.false_isolation_level)
    if decision is None:
        # the change test is armed after the baseline window (own baseline) or the warm-up
        k_ready = int(round((th.warmup_s + (th.baseline_s if baseline is None else 0.0)) / dt))
        decision = isolate.isolate(out, stats, th.h, k_ready, margin, horizon_s=isolate.DECISION_WINDOW_S,
                                   rows=[b], pairs=th.several_faults, **alarm_judging(out, th, baseline))[b]
    d = decision
    if not d.confirmed:
        return _withdrawn(out, th, d)
    name = isolate.hypothesis_name(d.hypothesis or (d.candidates[0] if d.candidates else "offset"), d.size)
    # +-2 sigma band: the bank filter's std and the healthy spread from model uncertainty
    m, s = d.size, math.hypot(d.size_sd, th.nuisance_sd.get(name.rstrip("+-"), 0.0))
    if name.startswith("K_"):
        size = {"value": float(leak_lpm(m)), "minus_2sigma": float(leak_lpm(m - 2 * s)),
                "plus_2sigma": float(leak_lpm(m + 2 * s)), "unit": "L/min at 10 MPa", "K_m3_per_s_sqrtPa": m}
    else:
        size = {"value": 100 * m, "minus_2sigma": 100 * (m - 2 * s), "plus_2sigma": 100 * (m + 2 * s),
                "unit": "% of spool travel"}
    # confidence: posterior probability of each hypothesis with equal priors, exp(llr) normalised
    w = {h: math.exp(v) for h, v in d.llr.items()}
    tot = sum(w.values())
    conf = {isolate.hypothesis_name(h, d.size if h == d.hypothesis else 0.0): v / tot for h, v in w.items()}
    lik = {"log_likelihood_minus_best_nats": d.llr, "best_minus_healthy_nats": d.llr_none,
           "margin_nats": margin, "bank_start_s": float(out.t[min(d.k0, len(out.t) - 1)]),
           **_alarm_record(out, th, d)}
    if d.pair_llr:
        lik["pair_minus_best_single_nats"] = d.pair_llr
    if d.several:
        return _several(out, th, d, lik, margin)
    if d.revised is not None:
        return _revised(out, th, d, lik, isolate.hypothesis_name(isolate.best_single(d), d.size))
    if d.pair_candidates:
        # the member of each leading pair that is not the best single fault (either order)
        base = name.rstrip("+-")
        second = list(dict.fromkeys(m for p in d.pair_candidates for m in p.split(isolate.PAIR_SEP) if m != base))
        pair_margin = isolate.margin_for(th.false_isolation_level, len(isolate.MULTI))
        lead = max(pair_margin, isolate.confirm_evidence(th))
        pairs = ", ".join(f"{p} ({d.pair_llr[p]:+.1f} nats)" if p in d.pair_llr else p for p in d.pair_candidates)
        note = (f"no single fault explains the data after the alarm: the pairs {pairs} lead every single fault "
                f"by >= {lead:.3g} nats, but none leads the others by {pair_margin:.3g} nats (the margin of a "
                f"{th.false_isolation_level:g} false-isolation level): the second fault is not isolable")
        return "fault, not isolable", [name] + second, {name: size}, conf, None, lik, note
    if d.hypothesis is not None:
        note = ""
        if d.window_misfit:
            note = (f"the data after the alarm fit no constant fault or pair (every mean NIS above "
                    f"{isolate.FIT_NIS:g}, the filter's expected value): the fault may be intermittent or "
                    f"changing; the decision at the alarm stands")
        return "fault", [name], {name: size}, conf, float(out.t[d.index]), lik, note
    cands = [isolate.hypothesis_name(h, d.size) for h in d.candidates]
    note = (f"no single-fault hypothesis beats the others by {margin:.2g} nats (the margin of a "
            f"{th.false_isolation_level:g} false-isolation level): {', '.join(cands)} explain the data alike")
    return "fault, not isolable", cands, {name: size}, conf, None, lik, note


def _alarm_record(out: FilterOutput, th: Thresholds, d) -> dict:
    """The likelihood entries of the alarm a decision answers: its time, the confirmation
    (evidence needed, instant) and the run's withdrawn alarms [s]."""
    t = out.t
    rec = {"alarm_s": float(t[d.alarm]) if d.alarm >= 0 else None,
           "confirm_nats": th.confirm_nats if th.confirm_nats > 0 else None,
           "confirmed_s": float(t[d.confirm_index]) if d.confirm_index >= 0 else None,
           "withdrawn_alarms_s": [float(t[k]) for k in d.withdrawn],
           "tests_restarted_s": [float(t[k]) for k in d.restarts if k < len(t)]}  # not at the record's end
    if d.episodes_capped:
        rec["episodes_capped"] = len(d.withdrawn)
    return rec


def _withdrawn(out: FilterOutput, th: Thresholds, d):
    """Status, isolated, size, confidence, isolation time, likelihoods and note of a run none of
    whose alarms was confirmed: healthy, with the withdrawn alarms."""
    from . import isolate

    rec = _alarm_record(out, th, d)
    times = ", ".join(f"{s:.3f}" for s in rec["withdrawn_alarms_s"])
    least = isolate.MIN_SINGLE_SIZE
    note = (f"alarm(s) at t = {times} s withdrawn: in the {isolate.DECISION_WINDOW_S:g} s after each, no fault hypothesis "
            f"explained the measurements better than the healthy model by {rec['confirm_nats']:.2g} nats with its "
            f"fault parameter moved by at least {leak_lpm(least['K_int']):.2g} L/min or {100 * least['offset']:.2g} % "
            f"(largest lead {d.lead_max:.1f} nats in the last window)")
    if d.episodes_capped:
        note += f"; the tests were not restarted after {rec['episodes_capped']} withdrawn alarms"
    return "healthy", [], {}, {}, None, {"best_minus_healthy_nats": d.llr_none, **rec}, note


def _revised(out: FilterOutput, th: Thresholds, d, lik: dict, early: str):
    """Status, isolated, size, confidence, isolation time, likelihoods and note of a decision
    that the several-faults window overturned (fdi.isolate.Decision.revised): the later single
    fault, sized by that window's filter, its confidence the posterior bound of its lead."""
    from . import isolate

    name = isolate.hypothesis_name(d.revised, d.revised_size)
    s = math.hypot(d.revised_size_sd, th.nuisance_sd.get(d.revised, 0.0))
    lik = {**lik, "revised_from": early, "revised_lead_nats": d.revised_llr}
    if d.index >= 0:
        first = f"first isolated as {early} at {float(out.t[d.index]):.3f} s"
    else:
        first = f"not isolable at first (best {early}; candidates {', '.join(d.candidates)})"
    note = (f"{first}; the data after the alarm (restarted filters, to {float(out.t[d.revised_index]):.3f} s) "
            f"favour {name} over every other single fault by {d.revised_llr:.0f} nats: revised to {name}")
    conf = {name: 1.0 - isolate.margin_level(min(d.revised_llr, 700.0))}
    return "fault", [name], {name: _size_entry(name, d.revised_size, s)}, conf, float(out.t[d.revised_index]), lik, note


def _size_entry(name: str, m: float, s: float) -> dict:
    """The size of a change m +- 2 s (SI) of hypothesis ``name`` in L/min at 10 MPa or %."""
    if name.startswith("K_"):
        return {"value": float(leak_lpm(m)), "minus_2sigma": float(leak_lpm(m - 2 * s)),
                "plus_2sigma": float(leak_lpm(m + 2 * s)), "unit": "L/min at 10 MPa", "K_m3_per_s_sqrtPa": m}
    return {"value": 100 * m, "minus_2sigma": 100 * (m - 2 * s), "plus_2sigma": 100 * (m + 2 * s),
            "unit": "% of spool travel"}


def _several(out: FilterOutput, th: Thresholds, d, lik: dict, margin: float):
    """Status, isolated, size, confidence, isolation time, likelihoods and note of an accepted
    pair: both members sized by the pair's filter (+-2 sigma with the healthy spread); the
    confidence of a member is the posterior probability (equal priors, exp of the
    log-likelihoods of H1 and its pairs) of the hypotheses that contain it."""
    from . import isolate

    names, size = [], {}
    for m in d.several:
        nm = isolate.hypothesis_name(m, d.several_size[m])
        names.append(nm)
        s = math.hypot(d.several_size_sd[m], th.nuisance_sd.get(m, 0.0))
        size[nm] = _size_entry(nm, d.several_size[m], s)
    h1 = isolate.best_single(d)
    w = {h1: 1.0, **{p: math.exp(min(v, 700.0)) for p, v in d.pair_llr.items()}}
    tot = sum(w.values())
    conf = {nm: sum(v for p, v in w.items() if m in p.split(isolate.PAIR_SEP)) / tot for m, nm in zip(d.several, names)}
    note = (f"{'+'.join(d.several)} leads {h1} alone and the other pairs by >= {margin:.2g} nats "
            f"(the margin of a {th.false_isolation_level:g} false-isolation level)")
    return "several faults", names, size, conf, float(out.t[d.several_index]), lik, note

