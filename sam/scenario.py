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
    [faults.K_extA]                # K_int, K_extA, K_extB [m^3/(s Pa^0.5)], offset [1]
    kind = "step"
    value = 2.6e-9
    t0_s = 1.0
    [sensors]                      # see sam.measurement.Sensors
    pressure_noise_Pa = 20e3
    [initial]
    x_m = 0.0
    [plant_overrides.effects]      # optional: any plant table, on top of the plant file
    air_fraction = 0.01
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .constants import DT_DEFAULT
from .errors import UserError, did_you_mean, where
from .measurement import Sensors, measure
from .params import P, Plant
from .plant import load_plant, read_toml, refuse_other_kind
from .profiles import INPUT_KINDS, PROFILE_KINDS, U_LIMIT_V, evaluate
from .recording import Recording
from .simulate import initial_state, simulate_batch

FAULT_NAMES = ("K_int", "K_extA", "K_extB", "offset")
_TOP_KEYS = {"description", "plant", "duration_s", "dt_s", "output_dt_s", "seed", "input", "load",
             "faults", "sensors", "initial", "plant_overrides", "name"}
#: Ground-truth columns: recording name -> model parameter or state.
_TRUE_PARAMS = {"true_K_int": "K_int", "true_K_extA": "K_extA", "true_K_extB": "K_extB",
                "true_offset": "offset", "true_mL": "m_L"}
_TRUE_STATES = {"true_pA": "p_A", "true_pB": "p_B", "true_x": "x", "true_v": "v", "true_xs": "x_s"}


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
    u = _input(table, t, source, base, seed)
    time_varying = {**_faults(table, t, source, plant), **load_mass_profile(table, t, source)}
    return Scenario(
        name=str(table.get("name", source.stem)),
        description=str(table.get("description", "")),
        plant=plant, dt=dt, output_every=output_every, t=t, u=u, time_varying=time_varying,
        sensors=_sensors(table, source), seed=seed, x0_m=_initial(table, source, plant),
        source=source,
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
        if name not in FAULT_NAMES:
            raise UserError(f"{where(source, f'faults.{name}')}: unknown fault; expected one of {list(FAULT_NAMES)}")
        if not isinstance(spec, dict):
            raise UserError(f"{where(source, f'faults.{name}')}: expected a table with a 'kind'")
        values = evaluate(PROFILE_KINDS, spec, t, source, f"faults.{name}")
        if name != "offset" and np.any(values < 0):
            raise UserError(f"{where(source, f'faults.{name}')}: a leak coefficient cannot be negative")
        if name == "offset" and np.any(np.abs(values) >= 1):
            raise UserError(f"{where(source, 'faults.offset')}: offset is a fraction of travel, |offset| < 1")
        out[name] = values
    return out


def load_mass_profile(table, t, source) -> dict[str, np.ndarray]:
    """The ``[load]`` table: ``m_L_kg = ...`` or a profile of m_L [kg]; {"m_L": (n_steps,)} or {}."""
    load = dict(_table(table, "load", source))
    if not load:
        return {}
    if "m_L_kg" in load:
        if len(load) > 1:
            raise UserError(f"{where(source, 'load')}: give either m_L_kg or a profile (kind = ...), not both")
        load = {"kind": "constant", "value": load["m_L_kg"]}
    spec = {("value" if k == "after_kg" else "before" if k == "before_kg" else k): v for k, v in load.items()}
    m_L = evaluate(PROFILE_KINDS, spec, t, source, "load")
    if np.any(m_L < 0):
        raise UserError(f"{where(source, 'load')}: the load mass cannot be negative")
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
    params = sc.plant.vector()
    result = simulate_batch(
        params, sc.u, sc.dt, x0=initial_state(params, sc.x0_m), time_varying=sc.time_varying,
        record_every=sc.output_every,
    )
    keep = np.arange(0, len(sc.t) + 1, sc.output_every)
    states = {name: values[0] for name, values in result.states.items()}
    bad = ~np.all([np.isfinite(v) for v in states.values()], axis=0)
    if bad.any():  # never hand a user NaN silently
        raise UserError(f"{where(sc.source, 'plant')}: the simulation left the finite range at "
                        f"t = {result.t[np.argmax(bad)]:.4g} s; check the plant parameters and dt_s")
    rng = np.random.default_rng(sc.seed)
    signals = measure(states, params, sc.dt, sc.sensors, rng)
    signals["u"] = _at(sc.u, keep)
    truth = {col: _at(sc.time_varying.get(name, np.full(len(sc.t), params[P[name]])), keep)
             for col, name in _TRUE_PARAMS.items()}
    truth.update({col: states[name] for col, name in _TRUE_STATES.items()})
    metadata = {"plant": sc.plant.name, "scenario": sc.name, "generator": "samfdi simulate",
                "seed": str(sc.seed)}
    if sc.description:
        metadata["description"] = sc.description
    if result.cavitated[0]:
        metadata["warning"] = "a chamber pressure reached the cavitation floor"
    return Recording(t=result.t, signals=signals, truth=truth, metadata=metadata)


def _at(values: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Per-step values at the recorded instants; the final instant repeats the last step's value."""
    return values[np.minimum(keep, len(values) - 1)]
