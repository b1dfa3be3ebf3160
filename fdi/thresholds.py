"""The detector's settings: :class:`Thresholds`, in groups, checked once when built.

A thresholds file (``samfdi fdi thresholds`` writes one; the shipped ones are
``scenarios/faults/thresholds.toml`` for the encoder and ``thresholds_linear.toml`` for a linear
position transducer) is one flat TOML table ``[thresholds]``: each key is a field of one group,
each table (``h``, ``sigma``, ...) a dict field. ``Thresholds.load`` names the file's key and
what is wrong with it; an absent key takes the default.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

from sam.errors import did_you_mean

from .faults import HYPOTHESES, NOTCH_TRIGGER, PARAMS, REGIMES
from .states import leak_lpm

SHIPPED_THRESHOLDS = Path(__file__).resolve().parents[1] / "scenarios" / "faults" / "thresholds.toml"
#: the position sensors a thresholds file is derived for, and the shipped file of each: "encoder",
#: the joint angle from the SAM's quantised encoder (or x computed from it); "linear", x from a
#: linear transducer with white noise (fdi.synth.POSITION_SENSORS)
SHIPPED_BY_SENSOR = {"encoder": SHIPPED_THRESHOLDS, "linear": SHIPPED_THRESHOLDS.with_name("thresholds_linear.toml")}
#: s: the healthy-run lengths a file may state its level for: at least a tune fault run, at most
#: an hour of simulation per run
MIN_RUN_LENGTH_S, MAX_RUN_LENGTH_S = 4.0, 3600.0
#: keys of older files whose options were retired (docs/fdi-design.md, "Retired"): the value each
#: may still hold (the one the detector has), or None when any value is ignored
RETIRED_KEYS = {"isolation": "likelihood", "detector": "cusum", "filter": "shipped", "confusable": None,
                "glr_h": None, "glr_start_s": None, "glr_window_s": None}


def _is_number(x) -> bool:
    """A real number (TOML reads true as a bool, which Python counts as 1)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _is_positive(x) -> bool:
    """A finite number > 0 (TOML reads nan and inf as floats)."""
    return _is_number(x) and 0.0 < x < math.inf


def _is_regime_list(test):
    """A check of a list with one entry per regime (:data:`REGIMES`), each passing test."""
    return lambda v: isinstance(v, (list, tuple)) and len(v) == len(REGIMES) and all(map(test, v))


_DURATION = (0.0, MAX_RUN_LENGTH_S, "a finite number >= 0 (a duration in seconds)")
#: the numeric fields: (lowest, highest, what a valid value is); None is allowed where the
#: default is None (memory_s, long_stroke_s, trigger_level)
RANGES = {
    "warmup_s": _DURATION, "baseline_s": _DURATION, "min_baseline_s": _DURATION, "min_tested_s": _DURATION,
    "band_V": (0.0, 1e3, "a finite number >= 0 (an input band in volts)"),
    "transient_s": _DURATION,
    "pin_margin_Pa": (-1e12, 1e12, "a pressure margin in Pa (finite; below 0 nothing is pinned)"),
    "balance_margin_Pa": (0.0, 1e12, "a pressure difference in Pa (>= 0)"),
    "long_stroke_s": (1e-3, 1e9, "a duration in seconds (> 0; leave it out for no long-stroke rule)"),
    "drift": (0.0, 1e3, "a CUSUM drift in sigma (>= 0)"),
    "long_stroke_drift": (0.0, 1e3, "a CUSUM drift in sigma (>= 0)"),
    "memory_s": (1e-9, 1e9, "a time constant in seconds (> 0; leave it out for none)"),
    "notch_jump_window_s": (1e-3, 60.0, "a window in seconds (1e-3 to 60)"),
    "notch_rest_s": _DURATION,
    "nis_limit": (0.0, 1e12, "a finite number >= 0 (a weighted NIS)"),
    "nis_hold_s": _DURATION,
    "confirm_nats": (0.0, 1e6, "an evidence in nats (>= 0; 0: every alarm stands)"),
    "persist_s": (0.0, 10.0, "a duration in s (0-10; 0: not asked)"),
    "false_isolation_level": (1e-9, 1.0, "a rate of wrong isolations (0-1)"),
    "rebase_s": (1e-6, MAX_RUN_LENGTH_S, "a duration in seconds (> 0)"),
    "false_alarm_level": (1e-9, 1.0, "a rate of false alarms per healthy run (0-1)"),
    "trigger_level": (1e-6, 1.0, "a rate of alarms per healthy run (0-1; leave it out for h at false_alarm_level)"),
    "run_length_s": (MIN_RUN_LENGTH_S, MAX_RUN_LENGTH_S,
                     f"a run length in seconds ({MIN_RUN_LENGTH_S:g}-{MAX_RUN_LENGTH_S:g})"),
    "sample_dt_s": (1e-6, 0.5, "a sampling step in seconds (1e-6 to 0.5)"),
}
#: the tables: (the keys each must have, the check of a value, what a valid value is, optional keys)
TABLES = {
    "h": (tuple(HYPOTHESES) + (NOTCH_TRIGGER,), _is_positive,
          f"a CUSUM threshold in sigma s, or the {NOTCH_TRIGGER} trigger's in sigma (> 0)", (NOTCH_TRIGGER,)),
    "sigma": (tuple(PARAMS), _is_regime_list(_is_positive),
              f"a list of {len(REGIMES)} healthy spreads (> 0, SI), one per regime {REGIMES}", ()),
    "votes": (tuple(PARAMS), _is_regime_list(lambda b: isinstance(b, bool)),
              f"a list of {len(REGIMES)} true/false, one per regime {REGIMES}", ()),
    "nuisance_sd": (tuple(PARAMS), _is_positive, "a spread (> 0, SI)", ()),
    "filter_sd_weight": (tuple(PARAMS), lambda w: _is_number(w) and 0.0 <= w <= 1e3, "a weight (>= 0)",
                         tuple(PARAMS)),
}
CHOICES = {"position_sensor": tuple(SHIPPED_BY_SENSOR)}
#: the fields that are a list of distinct names, and the names each may hold
NAME_LISTS = {"long_stroke_params": tuple(PARAMS)}


def _check(group) -> None:
    """Raise ValueError naming the field (and key) of ``group`` that is not valid."""
    for f in fields(group):
        v = getattr(group, f.name)
        if f.name in RANGES:
            lo, hi, what = RANGES[f.name]
            if not (v is None and f.default is None) and not (_is_number(v) and lo <= v <= hi):
                raise ValueError(f"{f.name!r} = {v!r} is not {what}")
        elif f.name in TABLES:
            keys, ok, what, optional = TABLES[f.name]
            if not isinstance(v, dict):
                raise ValueError(f"{f.name!r} = {v!r} is not a table with the keys {', '.join(keys)}")
            for key, value in v.items():
                if key not in keys:
                    raise ValueError(f"{f.name!r}: unknown key {key!r}{did_you_mean(key, keys)}")
                if not ok(value):
                    raise ValueError(f"'{f.name}.{key}' = {value!r} is not {what}")
            missing = [k for k in keys if k not in v and k not in optional]
            if missing:
                raise ValueError(f"{f.name!r} has no value for {', '.join(map(repr, missing))}")
        elif f.name in NAME_LISTS:
            ok = isinstance(v, (list, tuple)) and len(set(v)) == len(v) and all(x in NAME_LISTS[f.name] for x in v)
            if not ok:
                raise ValueError(f"{f.name!r} = {v!r} is not a list of distinct names out of "
                                 f"{', '.join(map(repr, NAME_LISTS[f.name]))}")
        elif f.name in CHOICES and v not in CHOICES[f.name]:
            raise ValueError(f"{f.name!r} = {v!r} is not one of {', '.join(map(repr, CHOICES[f.name]))}")
        elif f.type == "bool" and not isinstance(v, bool):
            raise ValueError(f"{f.name!r} = {v!r} is not true or false")
        elif f.type == "str" and not isinstance(v, str):
            raise ValueError(f"{f.name!r} = {v!r} is not a text")


@dataclass(frozen=True)
class Window:
    """When the change tests look."""

    warmup_s: float = 0.5  #: s: no alarms while the filter converges
    #: s: the healthy baseline is the mean estimate over [warmup, warmup + baseline_s] from the
    #: first motion, its unpinned samples (later ones if the run starts pinned)
    baseline_s: float = 1.0
    #: s: a baseline window with less unpinned data than this slides on to the first baseline_s
    #: of such samples
    min_baseline_s: float = 0.2
    #: s: a test that ran (armed, voting, not held) for less than this has not looked at its
    #: parameter: "healthy" would mean "not looked at" (a test needs a few tenths of a second)
    min_tested_s: float = 0.5

    def __post_init__(self):
        _check(self)


@dataclass(frozen=True)
class Regimes:
    """The operating conditions of each sample, from the input and the filter's estimates."""

    band_V: float = 0.3  #: V: |u| below this is "hold"
    transient_s: float = 0.3  #: s: the first this long of a direction is its transient regime
    #: Pa: chamber pressures within this of supply and tank are "pinned" (stalled or on an end
    #: stop with the valve open: no flow), and the tests of the parameters that then cannot show
    #: are held. 15 sensor noise std, 3 % of the supply.
    pin_margin_Pa: float = 0.3e6
    #: Pa: K_int's test is held where |p_A - p_B| is below this: a leak across the piston flows
    #: with the root of that difference, so there it carries almost nothing
    balance_margin_Pa: float = 0.4e6
    #: s: None: no long-stroke rule. S: from S into an extension or retraction until S into the
    #: rest after it, the K_int and offset tests count only what exceeds ``long_stroke_drift``
    #: (there those estimates wander along directions the data hardly constrain)
    long_stroke_s: float | None = None

    def __post_init__(self):
        _check(self)


@dataclass(frozen=True)
class ChangeTest:
    """The one-sided CUSUMs on the change residuals (estimate - baseline) / spread, and the
    notch-flow trigger. sigma, votes and h come from the sensitivity studies (fdi.study)."""

    #: hypothesis -> CUSUM threshold [sigma s]; under NOTCH_TRIGGER, if present, the notch-flow
    #: trigger's threshold [sigma]
    h: dict = field(default_factory=lambda: {k: 1.0 for k in HYPOTHESES})
    #: parameter -> healthy spread of (estimate - baseline) per regime (REGIMES), SI
    sigma: dict = field(default_factory=lambda: {
        "K_int": [1.0e-9] * 5, "K_extA": [5e-10] * 5, "K_extB": [6e-10] * 5, "offset": [5e-3] * 5})
    #: parameter -> per regime whether its residual votes (True) or is held (False)
    votes: dict = field(default_factory=lambda: {k: [True] * 5 for k in PARAMS})
    #: parameter -> weight w of the filter's own std in the spread sqrt((w sd)^2 + sigma^2); 1 if left out
    filter_sd_weight: dict = field(default_factory=lambda: {p: 1.0 for p in PARAMS})
    #: parameter -> absolute healthy spread of its estimate (SI): the absolute residuals r_*
    #: and the size bands of a diagnosis
    nuisance_sd: dict = field(default_factory=lambda: {
        "K_int": 1.00e-9, "K_extA": 5.14e-10, "K_extB": 6.07e-10, "offset": 5.19e-3})
    drift: float = 1.0  #: sigma: the CUSUM's reference value: only r beyond it accumulates
    long_stroke_drift: float = 4.0  #: sigma: the drift of the ``long_stroke_params`` tests in long strokes
    #: the parameters whose tests take ``long_stroke_drift`` in long strokes: those whose estimates
    #: still wander there with the calibration held: the offset's, not K_int's (docs/fdi-design.md,
    #: "The change test")
    long_stroke_params: tuple = ("offset",)
    #: s: the CUSUM forgets with this time constant (None: never): a healthy run's change
    #: residual carries an offset that lasts the run, which a classic CUSUM integrates without bound
    memory_s: float | None = None
    notch_jump_window_s: float = 0.2  #: s: the window over which the notch-flow trigger measures a jump
    #: s: the trigger is not armed in the first transient_s of a stroke after a rest or a stroke the
    #: other way this long: there the notch states learn what the long segment left unseen
    notch_rest_s: float = 2.0
    #: s: after a withdrawn alarm the K_int and offset baselines are re-learnt over this long
    #: before the restart: the bank has just judged that excursion healthy
    rebase_s: float = 0.5

    def __post_init__(self):
        _check(self)
        object.__setattr__(self, "long_stroke_params", tuple(self.long_stroke_params))  # a TOML list reads back equal

    def sd_weight(self, param: str) -> float:
        """The weight of the filter's std in ``param``'s change residual (``filter_sd_weight``)."""
        return float(self.filter_sd_weight.get(param, 1.0))


@dataclass(frozen=True)
class ModelFit:
    """The model-fit alarm: the filter's weighted NIS (3 channels; mean 3) stays high."""

    nis_limit: float = 9.0  #: weighted NIS above this ...
    nis_hold_s: float = 0.5  #: s: ... for this long is a model-fit alarm

    def __post_init__(self):
        _check(self)


@dataclass(frozen=True)
class Confirmation:
    """How the likelihood bank confirms, names and sizes an alarm (fdi.isolation)."""

    #: nats: an alarm stands only when, within the bank's window after it, the best fault beats
    #: the healthy hypothesis by this much with its parameter moved by the smallest size of
    #: interest; otherwise it is withdrawn and the tests restart (0: every alarm stands)
    #: nats; healthy episodes where the model's form errs (a valve parked at its null band's edge)
    #: lead by tens of nats on rig recordings (docs/fdi.md, "On rig recordings"). The lead is
    #: counted at its honest size: divided by the colour of the leading filter's pressure
    #: innovations (fdi.whiteness; BankDesign.colour_lag_s, colour_z, colour_channels)
    confirm_nats: float = 50.0
    #: s: the confirming lead must also have grown over the last this long (0: not asked). A
    #: fault that is there keeps adding evidence; a healthy transient that the model's form
    #: mispredicts (a step out of a hold, a stop impact) adds it once, then stalls
    persist_s: float = 0.3
    #: the stated probability that the named fault is not the one that produced the data: sets
    #: the likelihood margin (fdi.isolation.margin_for); not fitted to any run
    false_isolation_level: float = 0.01
    several_faults: bool = True  #: also test every pair of faults after a confirmed alarm

    def __post_init__(self):
        _check(self)


@dataclass(frozen=True)
class Derivation:
    """What the thresholds were derived for: their false-alarm statement and its conditions."""

    false_alarm_level: float = 0.01  #: the false-alarm rate per healthy run the detector is for
    #: the rate of CUSUM alarms per healthy run h was set for (each a trigger the bank confirms or
    #: withdraws); None: h at false_alarm_level
    trigger_level: float | None = None
    run_length_s: float = 4.0  #: s: the healthy-run length the levels are stated for
    #: s: the sampling step of the recordings they are for (sigma and h depend on it)
    sample_dt_s: float = 1e-3
    position_sensor: str = "encoder"  #: the position sensor they are for (SHIPPED_BY_SENSOR)
    source: str = "placeholder defaults (no thresholds file)"  #: how they were made

    def __post_init__(self):
        _check(self)


#: the groups of Thresholds and their classes, in file order
GROUPS = {"window": Window, "regimes": Regimes, "test": ChangeTest, "fit": ModelFit, "confirmation": Confirmation,
          "derived": Derivation}
#: a file key (a field of one group) -> its group
KEY_GROUP = {f.name: g for g, cls in GROUPS.items() for f in fields(cls)}


@dataclass(frozen=True)
class Thresholds:
    """The detector's settings (see docs/fdi.md). ``Thresholds.shipped()`` reads the shipped file;
    ``Thresholds()`` is placeholder defaults. A variant: ``th.with_(drift=1.5, run_length_s=4.0)``."""

    window: Window = field(default_factory=Window)  #: when the tests look
    regimes: Regimes = field(default_factory=Regimes)  #: each sample's operating conditions
    test: ChangeTest = field(default_factory=ChangeTest)  #: the CUSUMs and the notch-flow trigger
    fit: ModelFit = field(default_factory=ModelFit)  #: the model-fit (NIS) alarm
    confirmation: Confirmation = field(default_factory=Confirmation)  #: the bank's confirmation and naming
    derived: Derivation = field(default_factory=Derivation)  #: what they were derived for

    def __post_init__(self):
        for name, cls in GROUPS.items():
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"Thresholds.{name} = {getattr(self, name)!r} is not a {cls.__name__}")
        level, trigger = self.derived.false_alarm_level, self.derived.trigger_level
        if trigger is not None and trigger < level:
            raise ValueError(f"'trigger_level' = {trigger!r} is below 'false_alarm_level' = {level!r}: the CUSUM "
                             "alarms (triggers) the bank confirms cannot be rarer than the false alarms")

    def with_(self, **values) -> "Thresholds":
        """These thresholds with some fields replaced, by their (file) names."""
        groups = {}
        for key, value in values.items():
            if key not in KEY_GROUP:
                raise ValueError(f"unknown key {key!r}{did_you_mean(key, KEY_GROUP)}")
            groups.setdefault(KEY_GROUP[key], {})[key] = value
        return replace(self, **{g: replace(getattr(self, g), **kw) for g, kw in groups.items()})

    @classmethod
    def from_dict(cls, data: dict) -> "Thresholds":
        """Thresholds from a flat table of file keys; ValueError names a key that is not valid."""
        data = dict(data)
        for key, kept in RETIRED_KEYS.items():
            if key in data and kept is not None and data[key] != kept:
                raise ValueError(f"{key!r} = {data[key]!r}: that option was retired (only {kept!r} is left); derive "
                                 "the thresholds again with `samfdi fdi thresholds`")
            data.pop(key, None)
        return cls().with_(**data)

    @classmethod
    def load(cls, path: str | Path) -> "Thresholds":
        """The thresholds of a file (.toml from `samfdi fdi thresholds`, or .json)."""
        path = Path(path)
        text = path.read_text()
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
        return cls.from_dict(data.get("thresholds", data))

    @classmethod
    def shipped(cls, position_sensor: str = "encoder") -> "Thresholds":
        """The shipped thresholds for a position sensor (SHIPPED_BY_SENSOR)."""
        path = SHIPPED_BY_SENSOR[position_sensor]
        return cls.load(path) if path.exists() else cls().with_(position_sensor=position_sensor)

    def flat(self) -> dict:
        """Every field by its file key, in file order."""
        return {k: v for g in GROUPS for k, v in asdict(getattr(self, g)).items()}

    def to_json(self) -> str:
        """The flat table (:meth:`Thresholds.flat`) as JSON (thresholds_used.json; the tune's fingerprint)."""
        return json.dumps(self.flat(), indent=2)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(type(v))


def to_toml(th: Thresholds) -> str:
    """The thresholds as a file :meth:`Thresholds.load` reads back to the same object."""
    lines = ["# Thresholds of the change test, from `samfdi fdi thresholds` (fdi/study.py, docs/fdi.md).",
             "# Units: sigma SI (leaks m^3/(s Pa^0.5), offset fraction of travel), h in sigma s.",
             f"# regimes (sigma and votes lists): {list(REGIMES)}", "[thresholds]"]
    tables = []
    for k, v in th.flat().items():
        if v is None:  # TOML has no null: an absent key is the default
            continue
        if isinstance(v, dict):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in tables:
        lines.append(f"\n[thresholds.{k}]")
        for kk, vv in v.items():
            lines.append(f'"{kk}" = {_toml_value(vv)}')
    return "\n".join(lines) + "\n"


def describe(th: Thresholds) -> str:
    """A person-readable table of the thresholds."""
    t, d = th.test, th.derived
    memory = "none" if t.memory_s is None else f"{t.memory_s:g} s"
    w = th.window
    window = f"[{w.warmup_s:g}, {w.warmup_s + w.baseline_s:g}] s"
    long_rule = ("" if th.regimes.long_stroke_s is None else
                 f"; {' and '.join(t.long_stroke_params) or 'no test'} drift {t.long_stroke_drift:g} sigma from "
                 f"{th.regimes.long_stroke_s:g} s into a "
                 f"stroke until {th.regimes.long_stroke_s:g} s into the rest after it")
    lines = [f"CUSUM drift {t.drift:g} sigma, memory {memory}; baseline over {window}{long_rule}; "
             f"false-alarm level {d.false_alarm_level:g} per {d.run_length_s:g} s run"
             + ("" if d.trigger_level is None else
                f" (h for CUSUM alarms at {d.trigger_level:g} per run; an alarm stands when the bank "
                f"confirms it by {th.confirmation.confirm_nats:g} nats)") + f"; for the {d.position_sensor} position sensor",
             "", "| hypothesis | h [sigma s] |", "|---|---|"]
    lines += [f"| {k} | {v:.3g} |" for k, v in t.h.items() if k != NOTCH_TRIGGER]
    if NOTCH_TRIGGER in t.h:
        lines += ["", f"notch-flow trigger: a notch-flow calibration state jumping by more than "
                  f"{t.h[NOTCH_TRIGGER] + t.drift:.3g} of its std within {t.notch_jump_window_s:g} s "
                  f"(h = {t.h[NOTCH_TRIGGER]:.3g} sigma beyond the drift); the bank names the fault"]
    alone = [p for p in t.sigma if t.sd_weight(p) == 0.0]
    lines += ["", "change residual d_p = (estimate - baseline) / sqrt((w sd_filter)^2 + sigma^2), w per parameter: "
              + ", ".join(f"{p} {t.sd_weight(p):g}" for p in t.sigma)
              + (f" ({', '.join(alone)}: counted in the healthy spread sigma alone)" if alone else "")]
    lines += ["", "sigma (healthy spread of estimate - baseline) per regime; * = residual votes there:", "",
              "| parameter | " + " | ".join(REGIMES) + " |", "|---|" + "---|" * len(REGIMES)]
    for p, s in t.sigma.items():
        conv = (lambda x: f"{100 * x:.2f} %") if p == "offset" else (lambda x: f"{float(leak_lpm(x)):.3f} L/min")
        lines.append(f"| {p} | " + " | ".join(conv(x) + ("*" if v else "") for x, v in zip(s, t.votes[p])) + " |")
    lines += ["", f"source: {d.source}"]
    return "\n".join(lines)
