"""Loading and validating plant files (TOML).

A plant file has one table per parameter group (``[valve]``, ``[supply]``,
``[cylinder]``, ``[fluid]``, ``[friction]``, ``[boom]``, optionally
``[effects]``, ``[equations]`` and ``[stops]``), with SI values under the field names of :mod:`sam.params`,
and optionally ``[uncertain]``: the parameters the owner does not know exactly, each with its range
``name = [low, high]`` (:class:`sam.params.Uncertain`).
A user's file needs only the keys it changes: everything else comes from the
shipped default, ``scenarios/plants/sam.toml`` (Appendix 2 of the paper).
Values are validated once, here; the model itself does not check them.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from .errors import UserError, did_you_mean, where
from .params import (
    PARAM_NAMES, Boom, Cylinder, Effects, EndStops, Equations, Fluid, Friction, Plant, Supply, Uncertain, Valve,
)

_GROUPS = {
    "valve": Valve, "supply": Supply, "cylinder": Cylinder, "fluid": Fluid,
    "friction": Friction, "boom": Boom, "effects": Effects, "equations": Equations,
    "stops": EndStops,
}

#: Parameters that must be strictly positive (areas, volumes, masses, lengths, gains...).
_POSITIVE = {
    "Q_N_PA", "Q_N_AT", "Q_N_PB", "Q_N_BT", "dp_N_PA", "dp_N_AT", "dp_N_PB", "dp_N_BT",
    "leak_band", "K_u", "omega_n", "zeta", "p_S", "D_piston", "D_rod", "x_max",
    "V_0A", "V_0B", "B_eff", "F_C", "F_S", "v_s", "sigma_0", "L_1", "L_2", "L_3", "L",
    "L_B", "m_B", "theta_max", "Q_sat", "x_open", "Q_pump",
}
#: Parameters that must be >= 0.
_NON_NEGATIVE = {
    "K_leak_PA", "K_leak_AT", "K_leak_PB", "K_leak_BT", "b", "r_B", "m_L", "m_R",
    "air_fraction", "R_supply", "K_bypass", "C_hose", "k_fric_p", "k_fric_dp", "k_fric_rod",
    "k_stop", "zeta_stop",
}
#: Limits whose neutral value is inf (no limit): the only parameters a plant file may give as inf.
_UNLIMITED = {"Q_sat", "x_open", "Q_pump"}
#: The table of uncertain parameters, and the groups whose parameters it may name: a machine's
#: physical values (the spool offset is a fault input, estimated by the FDI, so it is not among them).
UNCERTAIN = "uncertain"
_UNCERTAIN_GROUPS = ("valve", "supply", "cylinder", "fluid", "friction", "boom")
_NOT_UNCERTAIN = {"offset": "the spool offset is a fault input (the FDI estimates it), not a plant uncertainty"}
#: Model settings that are switched on or off: true or false in a plant file.
_SWITCHES = {"arm_rate_torque"}
#: Angles [rad] read as radians within one turn either way: a larger value was meant in degrees.
_ANGLES = {"theta_level", "cog_angle"}
#: Settings that plant files no longer take -> the one line that says what to give instead.
_RETIRED = {
    ("boom", "alpha"): lambda v: (
        f"no longer a setting: give theta_level, the joint angle at which the boom is level "
        f"(= pi/2 - alpha = {math.pi / 2 - v:.10g} rad for the old convention phi = theta + alpha - pi/2), "
        f"and cog_angle (-pi/2 puts the centre of gravity below the joint, as before); see docs/model.md"),
}


def default_plant_path() -> Path:
    """The shipped plant file of the paper's SAM (Appendix 2)."""
    return Path(str(resources.files("scenarios") / "plants" / "sam.toml"))


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning every I/O or syntax problem into a one-line UserError."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise UserError(f"{path}: file not found") from None
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise UserError(f"{path}: cannot read TOML: {exc}") from None


#: keys that only one kind of project file has: how a file given to the wrong command is recognised
FILE_KINDS = {
    "a plant file": frozenset(_GROUPS) - {"effects", "equations", "stops"},
    "a scenario file": frozenset({"duration_s", "dt_s", "output_dt_s", "input", "load", "faults", "sensors",
                                  "initial", "plant_overrides"}),
    "a GSA study file": frozenset({"parameters", "model", "N", "simulation", "n_bootstrap"}),
}


def refuse_other_kind(table: dict[str, Any], source: str | Path, expected: str, hint: str) -> None:
    """A UserError when ``table`` is plainly another kind of project file than ``expected`` (one of
    :data:`FILE_KINDS`): it has keys of that kind and none of the expected kind's."""
    if FILE_KINDS[expected] & set(table):
        return
    for kind, keys in FILE_KINDS.items():
        found = sorted(keys & set(table))
        if kind != expected and found:
            raise UserError(f"{source}: this is {kind} (it has {', '.join(found)}), not {expected}; {hint}")


def load_plant(path: str | Path | None = None, overrides: dict[str, Any] | None = None,
               overrides_source: str | Path | None = None) -> Plant:
    """Load a plant file over the shipped defaults, then validate it.

    Args:
        path: a user plant TOML; None for the paper's SAM.
        overrides: further ``{group: {key: value}}`` on top (e.g. a scenario's
            ``[plant_overrides]``), validated the same way.
        overrides_source: where the overrides come from, for error messages (default: the
            plant file's name), e.g. ``"study.toml: 'candidates.B.plant'"``.
    """
    table = read_toml(default_plant_path())
    source = default_plant_path()
    if path is not None:
        source = Path(path)
        user = read_toml(source)
        refuse_other_kind(user, source, "a plant file", "give a plant file such as scenarios/plants/sam.toml")
        _merge(table, user, source)
    if overrides:
        own = overrides_source or source
        _merge(table, overrides, own)
        for group, values in overrides.items():
            if group == UNCERTAIN:
                _checked_ranges(values, own)
            elif group != "name":
                _checked_group(group, values, own)
    return plant_from_table(table, source)


def _merge(base: dict, extra: dict, source: Path) -> None:
    for key, value in extra.items():
        if key == "name":
            base["name"] = value
            continue
        if key not in _GROUPS and key != UNCERTAIN:
            raise UserError(f"{where(source, key)}: unknown table; expected one of {sorted([*_GROUPS, UNCERTAIN])}")
        if not isinstance(value, dict):
            raise UserError(f"{where(source, key)}: expected a table [{key}]")
        base.setdefault(key, {}).update(value)


def plant_from_table(table: dict[str, Any], source: str | Path = "<plant>") -> Plant:
    """Build and validate a :class:`Plant` from a complete ``{group: {key: value}}`` table."""
    groups = {}
    for group, cls in _GROUPS.items():
        values = _checked_group(group, table.get(group, {}), source)
        missing = [f.name for f in dataclasses.fields(cls)
                   if f.name not in values and f.default is dataclasses.MISSING]
        if missing:
            raise UserError(f"{where(source, group)}: missing keys {missing}")
        groups[group] = cls(**values)
    plant = Plant(name=str(table.get("name", "plant")), **groups)
    _check_relations(plant, source)
    return dataclasses.replace(plant, uncertain=_uncertain(table.get(UNCERTAIN, {}), plant, source))


def _checked_ranges(values: Any, source) -> dict[str, tuple[float, float, bool]]:
    """The ``[uncertain]`` table, name -> (low, high, relative): each key a machine parameter, each
    value ``[low, high]`` in SI units valid for that parameter, or ``{ factor = [low, high] }``, factors
    of the plant's own value (so a range follows a user's nominal value); low <= high. One-line
    UserError otherwise."""
    if not isinstance(values, dict):
        raise UserError(f"{where(source, UNCERTAIN)}: expected a table [{UNCERTAIN}] of name = [low, high]")
    known = {f.name: g for g in _UNCERTAIN_GROUPS for f in dataclasses.fields(_GROUPS[g])}
    out = {}
    for key, value in values.items():
        field = f"{UNCERTAIN}.{key}"
        if key in _NOT_UNCERTAIN:
            raise UserError(f"{where(source, field)}: {_NOT_UNCERTAIN[key]}")
        if key not in known:
            raise UserError(f"{where(source, field)}: not a parameter of the machine{did_you_mean(key, known)}")
        relative = isinstance(value, dict)
        if relative:
            if set(value) != {"factor"}:
                raise UserError(f"{where(source, field)}: expected {{ factor = [low, high] }}, got {value!r}")
            value, field = value["factor"], f"{field}.factor"
        if not isinstance(value, list) or len(value) != 2:
            raise UserError(f"{where(source, field)}: expected [low, high] "
                            f"{'factors' if relative else 'in SI units'}, got {value!r}")
        if relative:
            lo, hi = (_check_value(source, UNCERTAIN, "factor", v) for v in value)
            if not lo > 0:
                raise UserError(f"{where(source, field)}: factors must be > 0, got {lo:g}")
        else:
            lo, hi = (_check_value(source, known[key], key, v) for v in value)
        if not lo <= hi:
            raise UserError(f"{where(source, field)}: low {lo:g} is above high {hi:g}")
        out[key] = (lo, hi, relative)
    return out


def _uncertain(values: Any, plant: Plant, source) -> Uncertain:
    """The checked ranges in SI units, each holding the plant's own (nominal) value; a range of zero
    width marks the parameter as known and is dropped."""
    ranges = []
    nominal = dict(zip(PARAM_NAMES, plant.vector()))
    for key, (lo, hi, relative) in _checked_ranges(values, source).items():
        if relative:
            lo, hi = sorted((float(lo * nominal[key]), float(hi * nominal[key])))
        if not lo <= nominal[key] <= hi:
            raise UserError(f"{where(source, f'{UNCERTAIN}.{key}')}: the plant's {key} = {nominal[key]:g} lies "
                            f"outside its range [{lo:g}, {hi:g}]; widen the range or change the value")
        if lo < hi:
            ranges.append((key, lo, hi))
    return Uncertain(tuple(ranges))


def _checked_group(group: str, values: dict[str, Any], source) -> dict[str, float]:
    """The keys of one table, each known and its value valid; one-line UserError otherwise."""
    known = {f.name for f in dataclasses.fields(_GROUPS[group])}
    for key, value in values.items():
        if (group, key) in _RETIRED:
            raise UserError(f"{where(source, f'{group}.{key}')}: "
                            f"{_RETIRED[group, key](value if isinstance(value, (int, float)) else math.nan)}")
        if key not in known:
            raise UserError(f"{where(source, f'{group}.{key}')}: unknown key{did_you_mean(key, known)}")
    return {key: _check_value(source, group, key, value) for key, value in values.items()}


def _check_value(source, group: str, key: str, value: Any) -> float | bool:
    field = f"{group}.{key}"
    if key in _SWITCHES:
        if not isinstance(value, bool):
            raise UserError(f"{where(source, field)}: expected true or false, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UserError(f"{where(source, field)}: expected a number in SI units, got {value!r}")
    value = float(value)
    if math.isnan(value) or (math.isinf(value) and key not in _UNLIMITED):
        raise UserError(f"{where(source, field)}: must be finite, got {value}")
    if key in _POSITIVE and not value > 0:
        raise UserError(f"{where(source, field)}: must be > 0, got {value}")
    if key in _NON_NEGATIVE and value < 0:
        raise UserError(f"{where(source, field)}: must be >= 0, got {value}")
    if key in _ANGLES and not abs(value) <= 2 * math.pi:
        raise UserError(f"{where(source, field)}: an angle in radians within [-2 pi, 2 pi], got {value} "
                        f"(degrees? {value:g} deg = {math.radians(value):.6g} rad)")
    return value


def _check_relations(plant: Plant, source) -> None:
    s, c, f, b, v = plant.supply, plant.cylinder, plant.friction, plant.boom, plant.valve
    checks = [
        (s.p_S > s.p_T, "supply.p_S", f"supply pressure {s.p_S} Pa must be above tank pressure {s.p_T} Pa"),
        (c.D_rod < c.D_piston, "cylinder.D_rod", f"rod diameter {c.D_rod} m must be below piston diameter {c.D_piston} m"),
        (f.F_S >= f.F_C, "friction.F_S", f"static friction {f.F_S} N must be >= Coulomb friction {f.F_C} N"),
        (abs(b.L_1 - b.L_2) < b.L_3 < b.L_1 + b.L_2, "boom.L_3",
         f"L_3 = {b.L_3} m cannot close the triangle with L_1 = {b.L_1} m and L_2 = {b.L_2} m"),
        (0 < b.theta_max < math.pi, "boom.theta_max", f"must be in (0, pi) rad, got {b.theta_max}"),
        (abs(v.offset) < 1, "valve.offset", f"must be a fraction of travel in (-1, 1), got {v.offset}"),
        (plant.effects.air_fraction < 1, "effects.air_fraction", f"must be below 1, got {plant.effects.air_fraction}"),
        (abs(plant.effects.lap) < 1, "effects.lap", f"must be a fraction of travel in (-1, 1), got {plant.effects.lap}"),
    ]
    for ok, field, message in checks:
        if not ok:
            raise UserError(f"{where(source, field)}: {message}")
