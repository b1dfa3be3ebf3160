"""Reconstruction study files (TOML): candidate models of one experiment, and the evidence.

A reconstruction study (``scenarios/gsa/reconstruct.toml``) names two Sobol' study files (the
paper's parameter and leakage studies: the experiment, the sampled parameters), a list of
candidate models of the machine (plant overrides, initial condition, steady-state definition,
on top of ``[defaults]``) and the published evidence to score them against. Everything is
checked here, once; every error names the file and the key.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gsa.evidence import (
    INDEX_NAMES, STEADY, TRENDS, Condition, Evidence, Frequency, Interaction, Ranking, Statement, Values,
)
from gsa.sam_model import SamModel
from gsa.studies import StudySpec, load_study
from sam import Plant, load_plant, stroke_ends
from sam.errors import UserError, did_you_mean, where
from sam.plant import read_toml

PRESSURES = ("null_leak", "after_retraction", "tank")
_TOP = {"name", "description", "N", "seed", "n_bootstrap", "studies", "instants_s", "defaults",
        "factors", "candidates", "frequency", "lift", "evidence"}
_CANDIDATE = {"name", "description", "plant", "initial", "steady_from_s"}
_INITIAL = {"x_m", "pressures", "centred_s"}
_FREQUENCY = {"points"}
_LIFT = {"masses_kg", "x_from_m", "u_V", "duration_s"}
_EVIDENCE = {
    "ranking": {"study", "index", "instant", "negligible", "orders"},
    "values": {"study", "index", "signal", "instants_s", "values"},
    "interaction": {"study", "instant", "values"},
    "statement": {"conditions"},
    "frequency": {"target_hz", "reading_hz"},
}
_CONDITION = {"study", "index", "signal", "factor", "instants_s", "at_least", "at_most", "below", "above",
              "over_signals", "trend"}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
MAX_CENTRED_S = 10.0  #: s, a longer centred phase is indistinguishable from null_leak and costs runs


@dataclass(frozen=True)
class InitialCondition:
    """The state at t = 0 of every run of a candidate (see the study file's ``[defaults]``)."""

    x_m: float  #: m, piston position
    pressures: str  #: one of PRESSURES
    centred_s: float  #: s, valve held centred before the step, each run with its own parameters


@dataclass(frozen=True)
class Candidate:
    """One complete model of the paper's experiment."""

    name: str
    description: str
    plant: Plant
    initial: InitialCondition
    steady_from_s: float  #: s, steady state = mean of the recorded outputs from here to the end
    settings: dict  #: the candidate's table merged over [defaults], as written (for reports)
    levels: dict  #: {factor: option} for a candidate of [factors]; {} for a listed one


@dataclass(frozen=True)
class ReconstructionSpec:
    """A parsed reconstruction study file."""

    name: str
    description: str
    N: int
    seed: int
    n_bootstrap: int
    studies: dict[str, StudySpec]  #: e.g. {"parameters": ..., "leakage": ...}
    instants_s: tuple[float, ...]
    candidates: tuple[Candidate, ...]
    evidence: tuple[Evidence, ...]
    frequency_points: int
    lift_masses: tuple[float, ...]
    lift_from_m: float
    lift_u_V: float
    lift_duration_s: float
    source: Path
    table: dict  #: the file as read (its fingerprint makes a resumed run's results comparable)


def load_reconstruction(path: str | Path) -> ReconstructionSpec:
    path = Path(path)
    return reconstruction_from_table(read_toml(path), path)


def select_candidates(spec: ReconstructionSpec, names: list[str], option: str = "--candidates") -> ReconstructionSpec:
    """The study with only the candidates ``names``, in that order (the first is the reference)."""
    known = {c.name: c for c in spec.candidates}
    if not names:
        raise UserError(f"{option}: name one or more candidates of {spec.source}")
    for n in names:
        if n not in known:
            raise UserError(f"{option}: {spec.source} has no candidate {n!r}{did_you_mean(n, known)}")
    if len(set(names)) != len(names):
        raise UserError(f"{option}: a candidate is named twice in {names}")
    return dataclasses.replace(spec, candidates=tuple(known[n] for n in names))


def _unknown(table: dict, allowed, source, prefix: str) -> None:
    if not isinstance(table, dict):
        raise UserError(f"{where(source, prefix.rstrip('.'))}: expected a table")
    for key in table:
        if key not in allowed:
            raise UserError(f"{where(source, prefix + key)}: unknown key{did_you_mean(key, allowed)}")


def _number(table: dict, key: str, source, field: str, default=None, *, lo=-math.inf, hi=math.inf,
            integer: bool = False) -> float:
    value = table.get(key, default)
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if value is None or isinstance(value, bool) or not ok or not (lo <= value <= hi):
        kind = "an integer" if integer else "a number"
        raise UserError(f"{where(source, field)}: expected {kind} in [{lo:g}, {hi:g}], got {value!r}")
    return value


def reconstruction_from_table(table: dict[str, Any], source: Path) -> ReconstructionSpec:
    _unknown(table, _TOP, source, "")
    N = _number(table, "N", source, "N", lo=2, hi=2**20, integer=True)
    seed = _number(table, "seed", source, "seed", 0, lo=0, integer=True)
    n_boot = _number(table, "n_bootstrap", source, "n_bootstrap", 1000, lo=10, hi=100_000, integer=True)
    studies = _studies(table.get("studies"), source)
    instants = _instants(table.get("instants_s"), source, "instants_s", studies)
    candidates = _candidates(table, source, studies, instants)
    evidence = _evidence(table.get("evidence"), source, studies, instants)
    freq = table.get("frequency", {})
    _unknown(freq, _FREQUENCY, source, "frequency.")
    lift = table.get("lift", {})
    _unknown(lift, _LIFT, source, "lift.")
    masses = lift.get("masses_kg", [0.0, 250.0, 494.0, 800.0])
    if not isinstance(masses, list) or not masses or not all(
            isinstance(m, (int, float)) and not isinstance(m, bool) and 0 <= m <= 1e4 for m in masses):
        raise UserError(f"{where(source, 'lift.masses_kg')}: expected a list of loads in kg (0-10000), got {masses!r}")
    return ReconstructionSpec(
        name=str(table.get("name", source.stem)), description=str(table.get("description", "")),
        N=N, seed=seed, n_bootstrap=n_boot, studies=studies, instants_s=instants,
        candidates=candidates, evidence=evidence,
        frequency_points=_number(freq, "points", source, "frequency.points", 60, lo=2, hi=10_000, integer=True),
        lift_masses=tuple(float(m) for m in masses),
        lift_from_m=_number(lift, "x_from_m", source, "lift.x_from_m", 0.05, lo=0.0, hi=1.0),
        lift_u_V=_number(lift, "u_V", source, "lift.u_V", 10.0, lo=-10.0, hi=10.0),
        lift_duration_s=_number(lift, "duration_s", source, "lift.duration_s", 5.0, lo=0.01, hi=120.0),
        source=source, table=table,
    )


def _studies(studies, source) -> dict[str, StudySpec]:
    if not isinstance(studies, dict) or not studies:
        raise UserError(f"{where(source, 'studies')}: expected {{ name = \"study.toml\", ... }} naming "
                        f"the Sobol' study files of the experiment")
    out = {}
    for name, file in studies.items():
        if not isinstance(file, str):
            raise UserError(f"{where(source, f'studies.{name}')}: expected a file name, got {file!r}")
        spec = load_study(source.parent / file)
        model = spec.study.model
        if not isinstance(model, SamModel):
            raise UserError(f"{where(source, f'studies.{name}')}: {file} is not a study of the SAM model")
        if model.time_varying:
            raise UserError(f"{where(source, f'studies.{name}')}: {file} has a time-varying load; "
                            f"a reconstruction needs one experiment with a constant load")
        out[name] = spec
    first = next(iter(out.values())).study.model
    for name, spec in out.items():
        m = spec.study.model
        if m.dt != first.dt or len(m.u) != len(first.u) or m.signals != first.signals:
            raise UserError(f"{where(source, f'studies.{name}')}: the studies must share the experiment "
                            f"(Euler step, duration, outputs)")
    return out


def _instants(values, source, field: str, studies) -> tuple[float, ...]:
    model = next(iter(studies.values())).study.model
    duration = len(model.u) * model.dt
    if not isinstance(values, list) or not values:
        raise UserError(f"{where(source, field)}: expected a list of instants in s")
    out = []
    for v in values:
        steps = v / model.dt if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan
        if not (0 < v <= duration if not math.isnan(steps) else False) or abs(steps - round(steps)) > 1e-6:
            raise UserError(f"{where(source, field)}: {v!r} is not an instant of the experiment: a multiple "
                            f"of {model.dt:g} s in (0, {duration:g}] s")
        out.append(float(v))
    return tuple(out)


def factor_grid(factors, source) -> list[tuple[dict, dict]]:
    """The candidates of ``[factors]``: every combination of one option per factor, as
    (the options merged into one candidate table, {factor: option name}), in the order of the
    file (the last factor varies fastest). Each option is a partial candidate table."""
    if not isinstance(factors, dict):
        raise UserError(f"{where(source, 'factors')}: expected tables [factors.NAME] of options")
    grid = [({}, {})]
    for fname, options in factors.items():
        if not isinstance(options, dict) or not options:
            raise UserError(f"{where(source, f'factors.{fname}')}: expected one or more options "
                            f"{{ option = {{ plant = ..., initial = ... }} }}")
        for oname, option in options.items():
            _unknown(option, _CANDIDATE - {"name"}, source, f"factors.{fname}.{oname}.")
            if not _NAME.match(oname):
                raise UserError(f"{where(source, f'factors.{fname}.{oname}')}: an option name is letters, digits, "
                                f"'.', '_', '-'")
        grid = [(_deep_merge(table, opt), {**chosen, fname: oname})
                for table, chosen in grid for oname, opt in options.items()]
    for table, chosen in grid:
        table["name"] = "-".join(chosen.values())
        table["description"] = ", ".join(o["description"] for o in _chosen_options(factors, chosen)
                                         if o.get("description"))
    return grid


def _chosen_options(factors: dict, chosen: dict) -> list[dict]:
    return [factors[f][o] for f, o in chosen.items()]


def _candidates(table, source, studies, instants) -> tuple[Candidate, ...]:
    defaults = table.get("defaults", {})
    _unknown(defaults, _CANDIDATE - {"name", "description"}, source, "defaults.")
    grid = factor_grid(table.get("factors", {}), source) if "factors" in table else []
    listed = [t for t, _ in grid] + list(table.get("candidates", []))
    levels = [c for _, c in grid] + [{}] * len(table.get("candidates", []))
    if not listed or not isinstance(table.get("candidates", []), list):
        raise UserError(f"{where(source, 'candidates')}: needs [factors] or at least one [[candidates]] table")
    model = next(iter(studies.values())).study.model
    duration = len(model.u) * model.dt
    out, seen = [], set()
    for k, (cand, level) in enumerate(zip(listed, levels)):
        _unknown(cand, _CANDIDATE, source, f"candidates[{k}].")
        name = cand.get("name")
        if not isinstance(name, str) or not _NAME.match(name) or name in seen:
            raise UserError(f"{where(source, f'candidates[{k}].name')}: expected a new name of letters, digits, "
                            f"'.', '_', '-', got {name!r}")
        seen.add(name)
        field = f"factors ({name})" if level else f"candidates.{name}"
        plant_over = _deep_merge(defaults.get("plant", {}), cand.get("plant", {}))
        plant = load_plant(None, plant_over, overrides_source=where(source, f"{field}.plant"))
        initial = {**defaults.get("initial", {}), **cand.get("initial", {})}
        _unknown(initial, _INITIAL, source, f"{field}.initial.")
        pressures = initial.get("pressures", "null_leak")
        if pressures not in PRESSURES:
            raise UserError(f"{where(source, f'{field}.initial.pressures')}: expected one of {list(PRESSURES)}, "
                            f"got {pressures!r}")
        x_end = float(stroke_ends(plant.vector()))
        x_m = _number(initial, "x_m", source, f"{field}.initial.x_m", 0.0, lo=0.0, hi=x_end)
        if pressures == "after_retraction" and x_m != 0.0:
            raise UserError(f"{where(source, f'{field}.initial.x_m')}: \"after_retraction\" leaves the piston on "
                            f"the retracted stop, x_m = 0, got {x_m}")
        centred = _number(initial, "centred_s", source, f"{field}.initial.centred_s", 0.0, lo=0.0, hi=MAX_CENTRED_S)
        steady = _number({**defaults, **cand}, "steady_from_s", source, f"{field}.steady_from_s",
                         duration - 1.0, lo=model.dt, hi=duration)
        settings = {"plant": plant_over, "initial": {"x_m": x_m, "pressures": pressures, "centred_s": centred},
                    "steady_from_s": steady}
        out.append(Candidate(name, str(cand.get("description", "")), plant,
                             InitialCondition(float(x_m), pressures, float(centred)), float(steady), settings, level))
    return tuple(out)


def _deep_merge(base: dict, extra: dict) -> dict:
    """``extra`` over ``base``, tables merged key by key at every depth (copies, not views)."""
    out = {k: _deep_merge(v, {}) if isinstance(v, dict) else v for k, v in base.items()}
    for k, v in extra.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else \
            (_deep_merge(v, {}) if isinstance(v, dict) else v)
    return out


def _evidence(items, source, studies, instants) -> tuple[Evidence, ...]:
    if not isinstance(items, list) or not items:
        raise UserError(f"{where(source, 'evidence')}: needs at least one [[evidence]] table")
    out, seen = [], set()
    for k, item in enumerate(items):
        if not isinstance(item, dict):
            raise UserError(f"{where(source, f'evidence[{k}]')}: expected a table")
        id_ = item.get("id")
        if not isinstance(id_, str) or not _NAME.match(id_) or id_ in seen:
            raise UserError(f"{where(source, f'evidence[{k}].id')}: expected a new short name, got {id_!r}")
        seen.add(id_)
        kind = item.get("kind")
        if kind not in _EVIDENCE:
            raise UserError(f"{where(source, f'evidence.{id_}.kind')}: expected one of {list(_EVIDENCE)}, got {kind!r}")
        _unknown(item, {"id", "kind", "group", "text", "headline"} | _EVIDENCE[kind], source, f"evidence.{id_}.")
        headline = item.get("headline", True)
        if not isinstance(headline, bool):
            raise UserError(f"{where(source, f'evidence.{id_}.headline')}: expected true or false, got {headline!r}")
        common = dict(id=id_, group=str(item.get("group", kind)), text=str(item.get("text", "")), headline=headline)
        ctx = _Context(source, f"evidence.{id_}", studies, instants)
        out.append(_build_evidence(kind, item, common, ctx))
    return tuple(out)


@dataclass(frozen=True)
class _Context:
    source: Path
    field: str
    studies: dict
    instants: tuple

    def fail(self, key: str, message: str):
        raise UserError(f"{where(self.source, f'{self.field}.{key}')}: {message}")

    def study(self, item) -> str:
        name = item.get("study")
        if name not in self.studies:
            self.fail("study", f"expected one of {list(self.studies)}, got {name!r}")
        return name

    def index(self, item) -> str:
        index = item.get("index")
        if index not in INDEX_NAMES:
            self.fail("index", f"expected one of {list(INDEX_NAMES)}, got {index!r}")
        return index

    def factors(self, study: str, names, key: str) -> tuple[str, ...]:
        known = self.studies[study].study.problem.factor_names
        if not isinstance(names, list | tuple) or not names:
            self.fail(key, f"expected a list of the study's factors {list(known)}, got {names!r}")
        for n in names:
            if n not in known:
                self.fail(key, f"{n!r} is not a factor of study {study!r}{did_you_mean(str(n), known)}")
        return tuple(names)

    def signal(self, study: str, signal, key: str) -> str:
        signals = self.studies[study].study.model.signals
        if signal not in signals:
            self.fail(key, f"expected one of the outputs {list(signals)}, got {signal!r}")
        return signal

    def instant(self, value, key: str):
        if value == STEADY or value in self.instants:
            return value
        self.fail(key, f"{value!r} is not one of the study's instants_s {list(self.instants)} or \"steady\"")

    def value(self, v, key: str) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(key, f"expected a number, got {v!r}")
        return float(v)


def _build_evidence(kind: str, item: dict, common: dict, ctx: _Context) -> Evidence:
    if kind == "frequency":
        target = _number(item, "target_hz", ctx.source, f"{ctx.field}.target_hz", lo=1e-3, hi=1e3)
        reading = _number(item, "reading_hz", ctx.source, f"{ctx.field}.reading_hz", 0.0, lo=0.0, hi=target / 2)
        return Frequency(**common, target_hz=float(target), reading_hz=float(reading))
    if kind == "statement":
        conds = item.get("conditions")
        if not isinstance(conds, list) or not conds:
            ctx.fail("conditions", "expected a list of condition tables")
        return Statement(**common, conditions=tuple(_condition(c, k, ctx) for k, c in enumerate(conds)))
    study = ctx.study(item)
    if kind == "interaction":
        values = item.get("values")
        if not isinstance(values, dict) or not values:
            ctx.fail("values", "expected { signal = value, ... }")
        vals = {ctx.signal(study, s, f"values.{s}"): ctx.value(v, f"values.{s}") for s, v in values.items()}
        return Interaction(**common, study=study, instant=ctx.instant(item.get("instant", STEADY), "instant"),
                           values=vals)
    index = ctx.index(item)
    if kind == "ranking":
        orders = item.get("orders")
        if not isinstance(orders, dict) or not orders:
            ctx.fail("orders", "expected { signal = [factors, most influential first], ... }")
        parsed = {ctx.signal(study, s, f"orders.{s}"): ctx.factors(study, o, f"orders.{s}") for s, o in orders.items()}
        negligible = ctx.value(item.get("negligible", 0.01), "negligible")
        return Ranking(**common, study=study, index=index, orders=parsed, negligible=negligible,
                       instant=ctx.instant(item.get("instant", STEADY), "instant"))
    signal = ctx.signal(study, item.get("signal"), "signal")
    instants = tuple(ctx.instant(t, "instants_s") for t in _as_list(item.get("instants_s"), ctx, "instants_s"))
    values = item.get("values")
    if not isinstance(values, dict) or not values:
        ctx.fail("values", "expected { factor = [one value per instant], ... }")
    ctx.factors(study, list(values), "values")
    for f, v in values.items():
        if not isinstance(v, list) or len(v) != len(instants):
            ctx.fail(f"values.{f}", f"expected {len(instants)} values, one per instant, got {v!r}")
    vals = {f: tuple(ctx.value(x, f"values.{f}") for x in v) for f, v in values.items()}
    return Values(**common, study=study, index=index, signal=signal, instants=instants, values=vals)


def _as_list(v, ctx: _Context, key: str) -> list:
    if not isinstance(v, list) or not v:
        ctx.fail(key, f"expected a list, got {v!r}")
    return v


def _condition(c, k: int, outer: _Context) -> Condition:
    ctx = _Context(outer.source, f"{outer.field}.conditions[{k}]", outer.studies, outer.instants)
    if not isinstance(c, dict):
        ctx.fail("", "expected a table")
    _unknown(c, _CONDITION, ctx.source, ctx.field + ".")
    study = ctx.study(c)
    instants = c.get("instants_s", list(outer.instants) + [STEADY])
    at_least = ctx.value(c["at_least"], "at_least") if "at_least" in c else None
    at_most = ctx.value(c["at_most"], "at_most") if "at_most" in c else None
    below = ctx.factors(study, c["below"], "below") if "below" in c else ()
    above = ctx.factors(study, c["above"], "above") if "above" in c else ()
    over = tuple(ctx.signal(study, s, "over_signals") for s in _as_list(c["over_signals"], ctx, "over_signals")) \
        if "over_signals" in c else ()
    trend = c.get("trend")
    if trend is not None and trend not in TRENDS:
        ctx.fail("trend", f"expected one of {list(TRENDS)}, got {trend!r}")
    instants = tuple(ctx.instant(t, "instants_s") for t in _as_list(instants, ctx, "instants_s"))
    if trend is not None and len(instants) < 2:
        ctx.fail("instants_s", "a trend needs two instants or more (from the first to the last)")
    if at_least is None and at_most is None and not (below or above or over) and trend is None:
        ctx.fail("at_least", "a condition needs at_least, at_most, below, above, over_signals or trend")
    return Condition(study=study, index=ctx.index(c), signal=ctx.signal(study, c.get("signal"), "signal"),
                     factor=ctx.factors(study, [c.get("factor")], "factor")[0], instants=instants,
                     at_least=at_least, at_most=at_most, below=below, above=above, over_signals=over,
                     trend=trend)
