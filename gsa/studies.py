"""Study files (TOML): a Problem, a model and its outputs, as a person writes them.

A study names its model (``sam`` or an analytic test function), its uncertain
parameters with bounds, distribution and unit, the base sample size N, the
seed and, for ``sam``, the simulated experiment and its outputs. See
``scenarios/gsa/*.toml``. Every error names the file and the key.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import sam
from gsa.bootstrap import CI_METHODS
from gsa.problem import DISTRIBUTIONS, SALIB_NAMES, Problem
from gsa.runner import Study
from gsa.sam_model import OUTPUT_WORDS, SamModel
from gsa.testfunctions import ishigami, ishigami_indices, sobol_g, sobol_g_indices
from sam.constants import LPM
from sam.errors import UserError, did_you_mean, where
from sam.params import P
from sam.plant import load_plant, read_toml, refuse_other_kind
from sam.profiles import INPUT_KINDS, evaluate
from sam.scenario import check_step, load_mass_profile
from sam.simulate import PRECISIONS

#: Units a study may give bounds in, and their factor to SI.
UNITS = {"1": 1.0, "SI": 1.0, "%": 0.01, "L/min": LPM, "bar": 1e5, "MPa": 1e6, "Pa": 1.0,
         "m^3/s": 1.0, "m^3/(s Pa^0.5)": 1.0, "N s/m": 1.0, "N": 1.0, "kg": 1.0, "m": 1.0}
MODELS = ("sam", "ishigami", "sobol_g")
#: fewest bootstrap resamples: the report states each index with its 95 % interval and ranks
#: only as far as the intervals separate, and a percentile interval needs at least one
#: replicate beyond each of its 2.5 % points: 2 / (1 - 0.95) = 40
MIN_BOOTSTRAP = 40
_TOP = {"name", "description", "model", "N", "seed", "estimator", "n_bootstrap", "ci",
        "parameters", "simulation", "model_options", "steady_state"}
_PARAM_KEYS = {"bounds", "distribution", "unit", "description", "group"}
_SIM_KEYS = {"duration_s", "dt_s", "outputs", "every_s", "instants_s", "steady_from_s", "input",
             "load", "plant", "precision"}


@dataclass(frozen=True)
class StudySpec:
    """A parsed study file."""

    study: Study
    N: int
    seed: int
    estimator: str | None
    n_bootstrap: int
    ci: str
    units: tuple[str, ...]
    instants_s: tuple[float, ...] = ()
    steady_definition: str = ""
    description: str = ""
    source: Path | None = None
    analytic: tuple[np.ndarray, np.ndarray] | None = None  #: exact (S1, ST) of test functions
    extra: dict[str, Any] = field(default_factory=dict)
    #: factor -> what it is in words (the parameter's ``description``), for tables and legends
    factor_words: dict[str, str] = field(default_factory=dict)
    #: output base name -> what it is in words ("piston-side chamber pressure p_A")
    output_words: dict[str, str] = field(default_factory=dict)


def load_study(path: str | Path) -> StudySpec:
    path = Path(path)
    return study_from_table(read_toml(path), path)


def study_from_table(table: dict[str, Any], source: Path) -> StudySpec:
    refuse_other_kind(table, source, "a GSA study file", "`samfdi gsa run` takes a study such as "
                      "scenarios/gsa/paper_parameters.toml (a scenario runs with `samfdi simulate`)")
    _no_unknown(table, _TOP, source, "")
    model = table.get("model")
    if model not in MODELS:
        raise UserError(f"{where(source, 'model')}: expected one of {list(MODELS)}, got {model!r}")
    N = table.get("N")
    if isinstance(N, bool) or not isinstance(N, int) or N < 2:
        raise UserError(f"{where(source, 'N')}: the base sample size must be an integer >= 2, got {N!r}")
    seed = table.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise UserError(f"{where(source, 'seed')}: expected a non-negative integer, got {seed!r}")
    n_boot = table.get("n_bootstrap", 1000)
    if isinstance(n_boot, bool) or not isinstance(n_boot, int) or n_boot < MIN_BOOTSTRAP:
        raise UserError(f"{where(source, 'n_bootstrap')}: expected an integer >= {MIN_BOOTSTRAP} (resamples "
                        f"for the 95 % intervals), got {n_boot!r}")
    ci = table.get("ci", "percentile")
    if ci not in CI_METHODS:
        raise UserError(f"{where(source, 'ci')}: expected one of {list(CI_METHODS)}, got {ci!r}")
    problem, units = _problem(table, source)
    name = str(table.get("name", source.stem))
    common = dict(N=N, seed=seed, estimator=table.get("estimator"), n_bootstrap=n_boot,
                  ci=ci, units=units,
                  description=str(table.get("description", "")), source=source,
                  factor_words=_factor_words(table["parameters"], problem))
    if model == "sam":
        return _sam_study(table, source, name, problem, units, common)
    return _analytic_study(table, source, name, model, problem, common)


def _no_unknown(table: dict, allowed: set, source, prefix: str) -> None:
    for key in table:
        if key not in allowed:
            raise UserError(f"{where(source, prefix + key)}: unknown key{did_you_mean(key, allowed)}")


def _problem(table, source) -> tuple[Problem, tuple[str, ...]]:
    params = table.get("parameters")
    if not isinstance(params, dict) or not params:
        raise UserError(f"{where(source, 'parameters')}: needs at least one [parameters.NAME] table")
    names, bounds, dists, units, groups = [], [], [], [], []
    for name, spec in params.items():
        field_ = f"parameters.{name}"
        if not isinstance(spec, dict):
            raise UserError(f"{where(source, field_)}: expected a table")
        _no_unknown(spec, _PARAM_KEYS, source, field_ + ".")
        dist = spec.get("distribution", "uniform")
        if dist not in DISTRIBUTIONS and dist not in SALIB_NAMES:
            raise UserError(f"{where(source, field_ + '.distribution')}: unknown distribution {dist!r}; "
                            f"expected one of {list(DISTRIBUTIONS)} (or SALib's {list(SALIB_NAMES)})")
        b = spec.get("bounds")
        if not isinstance(b, list) or not all(_is_number(v) for v in b):
            raise UserError(f"{where(source, field_ + '.bounds')}: expected a list of finite numbers, got {b!r}")
        try:  # the layout each distribution takes is the engine's (gsa.problem), said once there
            Problem(names=(name,), bounds=(b,), dists=(dist,))
        except ValueError as exc:
            raise UserError(f"{where(source, field_ + '.bounds')}: {exc}") from None
        unit = spec.get("unit", "1")
        if unit not in UNITS:
            raise UserError(f"{where(source, field_ + '.unit')}: unknown unit {unit!r}; expected one of {list(UNITS)}")
        names.append(name)
        bounds.append(tuple(float(v) for v in b))
        dists.append(dist)
        units.append(unit)
        groups.append(spec.get("group", name))
    grouped = len(set(groups)) < len(groups)
    try:
        problem = Problem(names=tuple(names), bounds=tuple(bounds), dists=tuple(dists),
                          groups=tuple(groups) if grouped else None)
    except ValueError as exc:
        raise UserError(f"{where(source, 'parameters')}: {exc}") from None
    return problem, tuple(units)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _seconds(sim: dict, key: str, default: float, source) -> float:
    """A time in the [simulation] table: a finite number >= 0 (> 0 for steps and durations)."""
    value = sim.get(key, default)
    if not _is_number(value) or value < 0 or (key != "steady_from_s" and value == 0):
        raise UserError(f"{where(source, f'simulation.{key}')}: expected a positive number of seconds, got {value!r}")
    return float(value)


def _corners(base: np.ndarray, problem: Problem, units: tuple[str, ...]) -> np.ndarray:
    """Parameter rows where a step's stability is checked: the plant's, and each sampled parameter
    alone at its 0.1 % and 99.9 % quantile (next to its bounds, for a uniform one), in SI."""
    q = problem.transform(np.array([[0.001] * problem.k, [0.999] * problem.k]))
    rows = [base]
    for i, (name, unit) in enumerate(zip(problem.names, units)):
        for value in q[:, i]:
            row = base.copy()
            row[P[name]] = value * UNITS[unit]
            rows.append(row)
    return np.array(rows)


def _factor_words(params: dict, problem: Problem) -> dict[str, str]:
    """Factor -> its description (a group: the descriptions of its parameters, joined)."""
    words: dict[str, list[str]] = {}
    for name, group in zip(problem.names, problem.groups or problem.names):
        text = str(params[name].get("description", "")).strip()
        if text:
            words.setdefault(group, []).append(text)
    return {factor: "; ".join(texts) for factor, texts in words.items()}


def _analytic_study(table, source, name, model, problem, common) -> StudySpec:
    options = table.get("model_options", {})
    k = len(problem.names)
    if model == "ishigami":
        _no_unknown(options, {"a", "b"}, source, "model_options.")
        if k != 3:
            raise UserError(f"{where(source, 'parameters')}: the Ishigami function has 3 parameters, got {k}")
        a, b = options.get("a", 7.0), options.get("b", 0.1)
        for key, value in (("a", a), ("b", b)):
            if not _is_number(value):
                raise UserError(f"{where(source, f'model_options.{key}')}: expected a number, got {value!r}")
        func, exact = functools.partial(ishigami, a=a, b=b), ishigami_indices(a, b)
    else:
        _no_unknown(options, {"a"}, source, "model_options.")
        a = options.get("a")
        if not isinstance(a, list) or len(a) != k or not all(_is_number(v) and v >= 0 for v in a):
            raise UserError(f"{where(source, 'model_options.a')}: needs one number a_i >= 0 per parameter ({k}), "
                            f"got {a!r}")
        func, exact = functools.partial(sobol_g, a=np.asarray(a, float)), sobol_g_indices(a)
    study = Study(name, problem, func, output_names=(model,))
    return StudySpec(study=study, analytic=exact, **common)


def _sam_study(table, source, name, problem, units, common) -> StudySpec:
    sim = table.get("simulation")
    if not isinstance(sim, dict):
        raise UserError(f"{where(source, 'simulation')}: model 'sam' needs a [simulation] table")
    _no_unknown(sim, _SIM_KEYS, source, "simulation.")
    for pname in problem.names:
        if pname not in sam.PARAM_NAMES:
            raise UserError(f"{where(source, f'parameters.{pname}')}: not a parameter of the SAM model; "
                            f"see sam.PARAM_NAMES")
    dt = _seconds(sim, "dt_s", 1e-3, source)
    duration = _seconds(sim, "duration_s", 4.0, source)
    every = _seconds(sim, "every_s", 0.01, source)
    n_steps = int(round(duration / dt))
    stride = int(round(every / dt))
    if stride < 1 or n_steps < stride:
        raise UserError(f"{where(source, 'simulation.every_s')}: must be a multiple of dt_s within the run")
    t = np.arange(n_steps) * dt
    plant = load_plant(source.parent / sim["plant"] if "plant" in sim else None)
    u = evaluate(INPUT_KINDS, sim.get("input", {"kind": "step", "amplitude_V": 2.5}), t, source,
                 "simulation.input")
    load = load_mass_profile({"load": sim.get("load", {})}, t, source, "simulation.load")
    base = plant.vector()
    time_varying = None
    if "m_L" in load:  # a constant load needs no per-step update
        m = load["m_L"]
        if np.all(m == m[0]):
            base[sam.P.m_L] = m[0]
        else:
            time_varying = {"m_L": m}
    check_step(_corners(base, problem, units), time_varying or {}, u, dt, source, "simulation.dt_s")
    outputs = sim.get("outputs", ["p_A", "p_B", "v"])
    if not isinstance(outputs, list) or not outputs:
        raise UserError(f"{where(source, 'simulation.outputs')}: expected a list of state names, got {outputs!r}")
    outputs = tuple(outputs)
    for o in outputs:
        if o not in sam.S.__members__:
            raise UserError(f"{where(source, 'simulation.outputs')}: unknown output {o!r}; "
                            f"expected states {list(sam.S.__members__)}")
    steady_from = _seconds(sim, "steady_from_s", duration - 1.0, source)
    if not steady_from < duration:
        raise UserError(f"{where(source, 'simulation.steady_from_s')}: must be before the end of the run "
                        f"({duration:g} s), got {steady_from:g}")
    precision = sim.get("precision", "float64")
    if precision not in PRECISIONS:
        raise UserError(f"{where(source, 'simulation.precision')}: expected one of {sorted(PRECISIONS)}, "
                        f"got {precision!r}")
    model = SamModel(
        base=base, columns=tuple(int(sam.P[n]) for n in problem.names),
        scales=np.array([UNITS[u_] for u_ in units]), u=u, dt=dt,
        record_at=np.arange(stride, n_steps + 1, stride), signals=outputs,
        steady_from=int(round(steady_from / dt)), time_varying=time_varying, precision=precision,
    )
    names, times = model.output_names_and_times()
    study = Study(name, problem, model, output_names=names, output_times=times)
    instants = sim.get("instants_s", [])
    if not isinstance(instants, list) or not all(_is_number(v) and 0 < v <= duration for v in instants):
        raise UserError(f"{where(source, 'simulation.instants_s')}: expected a list of times in (0, {duration:g}] s, "
                        f"got {instants!r}")
    instants = tuple(float(v) for v in instants)
    steady = (f"mean of the outputs recorded every {every * 1e3:g} ms from {steady_from:g} s "
              f"to {duration:g} s")
    return StudySpec(study=study, instants_s=instants, steady_definition=steady,
                     output_words={o: OUTPUT_WORDS.get(o, o) for o in outputs}, **common)
