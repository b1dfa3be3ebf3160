"""Scenarios: one simulated test-bed run described in a TOML file.

A scenario names the plant file, the input profile, duration and step, the load
(possibly time-varying), fault profiles, sensor settings and the seed; running
it gives a :class:`sam.recording.Recording` in the shared format, with the
ground truth in ``true_*`` columns. See ``scenarios/paper_step.toml``::

    description = "..."
    plant = "plants/sam.toml"      # optional, relative to the scenario file
    duration_s = 4.0
    dt_s = 0.001                   # Euler step T
    output_dt_s = 0.001            # optional: sample interval of the recording
    seed = 1
    [input]                        # see sam.profiles.INPUT_KINDS
    kind = "step"
    amplitude_V = 2.5
    [load]                         # m_L_kg = 494.0, or a profile of m_L [kg]
    m_L_kg = 494.0
    [faults.K_extA]                # K_int, K_extA, K_extB: leaks; offset: the spool's
    kind = "step"
    value = 0.5
    unit = "L/min"                 # L/min at 10 MPa, or "m^3/(s Pa^0.5)" (the default: K of Eqs. (41)-(43))
    t0_s = 1.0
    [faults.offset]
    kind = "step"
    value = 2.0
    unit = "%"                     # % of the spool travel, or "1" (the default: a fraction)
    t0_s = 1.0
    [sensors]                      # see sam.measurement.Sensors
    pressure_noise_Pa = 20e3
    [initial]
    x_m = 0.0
    [plant_overrides.effects]      # optional: any plant table, on top of the plant file
    air_fraction = 0.01
    [numerics]                     # optional: the model's step (sam.dynamics.step)
    substeps = 1                   # sub-steps of dt_s / substeps per step
    scheme = "euler"               # "euler" (Eq. (22)), "semi_implicit", "heun", "rk4"

A ``[control]`` table (sam.control) instead of ``[input]`` asks for closed-loop position
control, which the rig simulator runs (``samfdi simulate --engine rig``); ``[rig]`` tables are
read by the rig simulator only.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .constants import DT_DEFAULT
from .control import Control, parse_control
from .dynamics import SCHEMES
from .errors import UserError, did_you_mean, where
from .hydraulics import flow_coefficient, leak_coefficient, leak_lpm
from .measurement import Sensors, measure
from .params import P, Plant
from .plant import load_plant, read_toml, refuse_other_kind
from .profiles import INPUT_KINDS, PROFILE_KINDS, U_LIMIT_V, evaluate
from .recording import Recording
from .simulate import initial_state, simulate_batch
from .stability import STABLE_GROWTH, diverged, largest_stable_step, step_growth

FAULT_NAMES = ("K_int", "K_extA", "K_extB", "offset")
#: units a fault size may be given in (key ``unit``), with their factor to the model's; the first is the default
LEAK_UNITS = {"m^3/(s Pa^0.5)": 1.0, "L/min": leak_coefficient(1.0)}  # L/min: passed at 10 MPa
OFFSET_UNITS = {"1": 1.0, "%": 0.01}  # of the spool's full travel
#: a spool offset above this share of the travel is warned about: twice the paper's largest (Table 1, +-5 %)
OFFSET_WARN = 0.10
_TOP_KEYS = {"description", "plant", "duration_s", "dt_s", "output_dt_s", "seed", "input", "load",
             "faults", "sensors", "initial", "plant_overrides", "name", "control", "numerics", "rig"}
#: Ground-truth columns: recording name -> model parameter or state.
_TRUE_PARAMS = {"true_K_int": "K_int", "true_K_extA": "K_extA", "true_K_extB": "K_extB",
                "true_offset": "offset", "true_mL": "m_L"}
_TRUE_STATES = {"true_pA": "p_A", "true_pB": "p_B", "true_x": "x", "true_v": "v", "true_xs": "x_s"}


class ScenarioWarning(UserWarning):
    """A scenario that runs but probably says something else than its author meant."""


@dataclass(frozen=True)
class Scenario:
    """A parsed, validated scenario (all arrays on the Euler grid, n_steps long)."""

    name: str
    description: str
    plant: Plant
    dt: float  #: s, Euler step
    output_every: int  #: keep every k-th step in the recording
    t: np.ndarray  #: (n_steps,) s
    u: np.ndarray  #: (n_steps,) V
    time_varying: dict[str, np.ndarray]  #: parameter name -> (n_steps,)
    sensors: Sensors
    seed: int
    x0_m: float = 0.0
    source: Path | None = None
    metadata: dict[str, str] = field(default_factory=dict)
    control: Control | None = None  #: closed-loop position control (then u is NaN: the loop makes it)
    substeps: int = 1  #: the model's sub-steps per dt (sam.dynamics.step)
    scheme: str = "euler"  #: the model's scheme, a key of sam.dynamics.SCHEMES

    def start_params(self) -> np.ndarray:
        """The plant's parameter vector (len(P),) with the time-varying ones (load, faults) at t = 0."""
        params = self.plant.vector()
        for name, values in self.time_varying.items():
            params[P[name]] = values[0]
        return params

    def initial_state(self) -> np.ndarray:
        """The state at t = 0 (7,): at rest with the valve centred, piston at ``x0_m``, holding the
        scenario's load at t = 0 (not the plant file's m_L), so a held valve starts in equilibrium."""
        return initial_state(self.start_params(), self.x0_m)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file; every error names the file and the key."""
    path = Path(path)
    table = read_toml(path)
    return scenario_from_table(table, path)


def scenario_from_table(table: dict[str, Any], source: Path) -> Scenario:
    refuse_other_kind(table, source, "a scenario file", "`samfdi simulate` takes a scenario such as "
                      "scenarios/paper_step.toml (a study runs with `samfdi gsa run`)")
    for key in table:
        if key not in _TOP_KEYS:
            raise UserError(f"{where(source, key)}: unknown key{did_you_mean(key, _TOP_KEYS)}; "
                            f"allowed: {sorted(_TOP_KEYS)}")
    base = source.parent
    plant_path = table.get("plant")
    if plant_path is not None and not isinstance(plant_path, str):
        raise UserError(f"{where(source, 'plant')}: expected a file name")
    plant = load_plant(base / plant_path if plant_path else None, table.get("plant_overrides"))
    duration = _positive(table, "duration_s", source)
    dt = _positive(table, "dt_s", source, DT_DEFAULT)
    output_dt = _positive(table, "output_dt_s", source, dt)
    output_every = int(round(output_dt / dt))
    if output_every < 1 or abs(output_every * dt - output_dt) > 1e-9 * output_dt:
        raise UserError(f"{where(source, 'output_dt_s')}: must be a whole multiple of dt_s = {dt} s")
    if duration < 2 * dt:
        raise UserError(f"{where(source, 'duration_s')}: {duration} s is shorter than two steps of {dt} s")
    n_steps = int(round(duration / dt))
    t = np.arange(n_steps) * dt
    seed = table.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise UserError(f"{where(source, 'seed')}: expected a non-negative integer, got {seed!r}")
    control = parse_control(table, t, source, plant.cylinder.x_max)
    if control is not None and "input" in table:
        raise UserError(f"{where(source, 'input')}: give [input] (open loop) or [control] (closed loop), not both")
    u = np.full_like(t, np.nan) if control is not None else _input(table, t, source, base, seed)
    time_varying = {**_faults(table, t, source, plant), **load_mass_profile(table, t, source)}
    numerics = _numerics(table, source)
    # a closed loop's u is the controller's, somewhere within its limits; each sub-step is an Euler step or more stable
    u_range = u if control is None else np.array([-control.u_limit_V, control.u_limit_V])
    check_step(plant.vector(), time_varying, u_range, dt / numerics["substeps"], source,
               "dt_s" if numerics["substeps"] == 1 else "numerics.substeps")
    return Scenario(
        name=str(table.get("name", source.stem)),
        description=str(table.get("description", "")),
        plant=plant, dt=dt, output_every=output_every, t=t, u=u, time_varying=time_varying,
        sensors=_sensors(table, source), seed=seed, x0_m=_initial(table, source, plant),
        source=source, control=control, **numerics,
    )


def _positive(table, key, source, default=None) -> float:
    value = table.get(key, default)
    if value is None:
        raise UserError(f"{where(source, key)}: missing")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise UserError(f"{where(source, key)}: expected a positive number of seconds, got {value!r}")
    return float(value)


def _table(table, key, source) -> dict:
    value = table.get(key, {})
    if not isinstance(value, dict):
        raise UserError(f"{where(source, key)}: expected a table [{key}]")
    return value


def _input(table, t, source, base, seed) -> np.ndarray:
    spec = dict(_table(table, "input", source))
    if not spec:
        raise UserError(f"{where(source, 'input')}: missing [input] table")
    if spec.get("kind") == "prbs":
        spec.setdefault("seed", seed)
    extra = {"base_dir": base} if spec.get("kind") == "pwl_csv" else {}
    u = evaluate(INPUT_KINDS, spec, t, source, "input", **extra)
    if np.any(np.abs(u) > U_LIMIT_V):
        raise UserError(f"{where(source, 'input')}: the control signal leaves +-{U_LIMIT_V} V "
                        f"(max |u| = {np.max(np.abs(u)):.3g} V)")
    return u


def _faults(table, t, source, plant) -> dict[str, np.ndarray]:
    faults = _table(table, "faults", source)
    out = {}
    for name, spec in faults.items():
        field_ = f"faults.{name}"
        if name not in FAULT_NAMES:
            raise UserError(f"{where(source, field_)}: unknown fault; expected one of {list(FAULT_NAMES)}")
        if not isinstance(spec, dict):
            raise UserError(f"{where(source, field_)}: expected a table with a 'kind'")
        spec = dict(spec)
        units = OFFSET_UNITS if name == "offset" else LEAK_UNITS
        unit = spec.pop("unit", next(iter(units)))
        if unit not in units:
            raise UserError(f"{where(source, field_ + '.unit')}: expected one of {list(units)}, got {unit!r}")
        values = evaluate(PROFILE_KINDS, spec, t, source, field_) * units[unit]
        if name == "offset":
            _check_offset(values, unit, source)
        else:
            _check_leak(values, unit, plant, source, field_)
        out[name] = values
    return out


def _check_leak(K: np.ndarray, unit: str, plant: Plant, source, field_: str) -> None:
    """Refuse a leak that is no leak: negative, or passing more than the fully open valve delivers
    (a burst line; typically an L/min figure typed where K was expected)."""
    if np.any(K < 0):
        raise UserError(f"{where(source, field_)}: a leak coefficient cannot be negative")
    v = plant.valve
    K_valve = max(flow_coefficient(v.Q_N_PA, v.dp_N_PA), flow_coefficient(v.Q_N_PB, v.dp_N_PB))
    worst = float(np.max(K))
    if worst > K_valve:
        hint = (f"; if you meant {worst:g} L/min at 10 MPa, add unit = \"L/min\"" if unit != "L/min" else "")
        raise UserError(
            f"{where(source, field_)}: a leak of {leak_lpm(worst):.3g} L/min at 10 MPa (K = {worst:.3g} "
            f"m^3/(s Pa^0.5)) passes more than the fully open valve can deliver ({leak_lpm(K_valve):.3g} L/min "
            f"at 10 MPa): a burst line, not a leak{hint}")


def _check_offset(values: np.ndarray, unit: str, source) -> None:
    worst = float(np.max(np.abs(values)))
    hint = "" if unit == "%" else f"; if you meant {worst:g} %, write unit = \"%\""
    if worst >= 1:
        raise UserError(f"{where(source, 'faults.offset')}: an offset of {100 * worst:g} % of the spool travel; "
                        f"|offset| must be below 100 % (a fraction below 1, or unit = \"%\")")
    if worst > OFFSET_WARN:
        warnings.warn(f"{where(source, 'faults.offset')}: an offset of {100 * worst:g} % of the spool travel, the "
                      f"valve {100 * worst:g} % open at u = 0 (the paper studies up to 5 %){hint}",
                      ScenarioWarning, stacklevel=4)


def check_step(params: np.ndarray, time_varying: dict[str, np.ndarray], u: np.ndarray, dt: float, source,
               field_: str) -> None:
    """Refuse a step ``dt`` [s] that is unstable for the plant (:mod:`sam.stability`): checked for each
    parameter row of ``params`` ((len(P),) or (n, len(P))), with the run's time-varying parameters at
    their first, last and largest values, at rest and at the smallest and largest control signal."""
    rows = []
    for base in np.atleast_2d(params):
        for pick in (lambda v: v[0], lambda v: v[-1], np.max):
            row = np.array(base, dtype=float)
            for name, values in time_varying.items():
                row[P[name]] = pick(np.atleast_1d(values))
            rows.append(row)
    rows = np.array(rows)
    u_values = (0.0, float(np.min(u)), float(np.max(u)))
    worst = step_growth(rows, dt, u_values)
    if worst.growth > STABLE_GROWTH:
        stable = largest_stable_step(rows, u_values, dt)
        raise UserError(
            f"{where(source, field_)}: a step of {dt:g} s is unstable for this plant: the model's step "
            f"multiplies a disturbance by {worst.growth:.3g} at each step (at u = {worst.u:g} V), so the run "
            f"would diverge; the largest stable step is {stable * 1e3:.3g} ms (the paper's is 1 ms)")


def load_mass_profile(table, t, source, field_: str = "load") -> dict[str, np.ndarray]:
    """The ``[load]`` table: ``m_L_kg = ...`` or a profile of m_L [kg]; {"m_L": (n_steps,)} or {}.
    ``field_``: where the table is in its file, for messages."""
    load = dict(_table(table, "load", source))
    if not load:
        return {}
    for key in ("m_L_kg", "after_kg", "before_kg"):  # renamed below: checked under the user's own name
        if key in load and (isinstance(load[key], bool) or not isinstance(load[key], (int, float))):
            raise UserError(f"{where(source, f'{field_}.{key}')}: expected a number of kg, got {load[key]!r}")
    if "m_L_kg" in load:
        if len(load) > 1:
            raise UserError(f"{where(source, field_)}: give either m_L_kg or a profile (kind = ...), not both")
        load = {"kind": "constant", "value": load["m_L_kg"]}
    spec = {("value" if k == "after_kg" else "before" if k == "before_kg" else k): v for k, v in load.items()}
    m_L = evaluate(PROFILE_KINDS, spec, t, source, field_)
    if np.any(m_L < 0):
        raise UserError(f"{where(source, field_)}: the load mass cannot be negative")
    return {"m_L": m_L}


def _sensors(table, source) -> Sensors:
    spec = _table(table, "sensors", source)
    known = {f.name: f for f in dataclasses.fields(Sensors)}
    for key, value in spec.items():
        if key not in known:
            raise UserError(f"{where(source, f'sensors.{key}')}: unknown key; allowed: {sorted(known)}")
        if isinstance(known[key].default, bool) != isinstance(value, bool):
            raise UserError(f"{where(source, f'sensors.{key}')}: wrong type {value!r}")
        if not isinstance(value, bool) and value < 0:
            raise UserError(f"{where(source, f'sensors.{key}')}: must be >= 0, got {value}")
    return Sensors(**spec)


def _numerics(table, source) -> dict:
    spec = _table(table, "numerics", source)
    for key in spec:
        if key not in ("substeps", "scheme"):
            raise UserError(f"{where(source, f'numerics.{key}')}: unknown key; allowed: ['scheme', 'substeps']")
    substeps, scheme = spec.get("substeps", 1), spec.get("scheme", "euler")
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise UserError(f"{where(source, 'numerics.substeps')}: expected a whole number >= 1, got {substeps!r}")
    if scheme not in SCHEMES:
        raise UserError(f"{where(source, 'numerics.scheme')}: expected one of {sorted(SCHEMES)}, got {scheme!r}")
    return {"substeps": substeps, "scheme": scheme}


def _initial(table, source, plant) -> float:
    spec = _table(table, "initial", source)
    for key in spec:
        if key != "x_m":
            raise UserError(f"{where(source, f'initial.{key}')}: unknown key; allowed: ['x_m']")
    x0 = spec.get("x_m", 0.0)
    if isinstance(x0, bool) or not isinstance(x0, (int, float)) or not 0 <= x0 < plant.cylinder.x_max:
        raise UserError(f"{where(source, 'initial.x_m')}: must be within the stroke [0, {plant.cylinder.x_max}) m")
    return float(x0)


def run_scenario(sc: Scenario) -> Recording:
    """Simulate a scenario and measure it: a recording with ``true_*`` ground truth."""
    if sc.control is not None:
        raise UserError(f"{where(sc.source, 'control')}: closed-loop control runs on the rig simulator "
                        f"(samfdi simulate ... --engine rig); sam's simulator takes an open-loop [input]")
    params = sc.plant.vector()
    result = simulate_batch(
        params, sc.u, sc.dt, x0=sc.initial_state(), time_varying=sc.time_varying,
        record_every=sc.output_every, substeps=sc.substeps, scheme=sc.scheme,
    )
    keep = np.arange(0, len(sc.t) + 1, sc.output_every)
    states = {name: values[0] for name, values in result.states.items()}
    bad = ~np.all([np.isfinite(v) for v in states.values()], axis=0)
    found = [diverged(states, params)] + ([(int(np.argmax(bad)), "a state is not finite")] if bad.any() else [])
    if any(found):  # never hand a user NaN or nonsense silently
        k, what = min(f for f in found if f)
        raise UserError(f"{where(sc.source, 'dt_s')}: the simulation diverged at t = {result.t[k]:.4g} s "
                        f"({what}); nothing was written. Check dt_s and the plant parameters")
    rng = np.random.default_rng(sc.seed)
    signals = measure(states, params, sc.dt, sc.sensors, rng)
    signals["u"] = _at(sc.u, keep)
    truth = {col: _at(sc.time_varying.get(name, np.full(len(sc.t), params[P[name]])), keep)
             for col, name in _TRUE_PARAMS.items()}
    truth.update({col: states[name] for col, name in _TRUE_STATES.items()})
    metadata = {"plant": sc.plant.name, "scenario": sc.name, "generator": "samfdi simulate",
                "seed": str(sc.seed), "model_step": f"{sc.scheme}, {sc.substeps} x {sc.dt / sc.substeps:g} s"}
    if sc.description:
        metadata["description"] = sc.description
    if result.cavitated[0]:
        metadata["warning"] = "a chamber pressure reached the cavitation floor"
    return Recording(t=result.t, signals=signals, truth=truth, metadata=metadata)


def _at(values: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Per-step values at the recorded instants; the final instant repeats the last step's value."""
    return values[np.minimum(keep, len(values) - 1)]
