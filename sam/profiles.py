"""Time profiles: control signals (inputs) and time-varying parameters (faults, load).

A profile is described by a small table (from a scenario TOML) with a ``kind``
and its own keys, and evaluated on the simulation's time grid ``t`` [s]. Every
kind validates its keys once, here, and says which key is wrong.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any, Callable

import numpy as np
from scipy.signal import chirp as _chirp

from .errors import UserError, where

U_LIMIT_V = 10.0  #: V, the valve's control range (docs/recordings.md)


# --- control signals u(t) [V] ----------------------------------------------------------

def step_input(t, amplitude_V, t0_s=0.0, initial_V=0.0):
    """A step to ``amplitude_V`` at ``t0_s`` (the paper's test: 2.5 V, i.e. 25 % opening, at t = 0)."""
    return np.where(t >= t0_s, amplitude_V, initial_V)


def ramp_input(t, start_V, end_V, t0_s, t1_s):
    """Linear from ``start_V`` at ``t0_s`` to ``end_V`` at ``t1_s``, constant outside."""
    return np.interp(t, [t0_s, t1_s], [start_V, end_V])


def sine_input(t, amplitude_V, frequency_Hz, offset_V=0.0, phase_rad=0.0):
    """``offset_V + amplitude_V sin(2 pi f t + phase)``: alternates extension and retraction."""
    return offset_V + amplitude_V * np.sin(2 * np.pi * frequency_Hz * t + phase_rad)


def chirp_input(t, amplitude_V, f0_Hz, f1_Hz, offset_V=0.0):
    """A linear frequency sweep from ``f0_Hz`` to ``f1_Hz`` over the whole run."""
    return offset_V + amplitude_V * _chirp(t, f0=f0_Hz, t1=t[-1], f1=f1_Hz)


def prbs_input(t, amplitude_V, hold_s, seed=0, offset_V=0.0):
    """Pseudo-random binary sequence: +-amplitude, switching at random multiples of ``hold_s``."""
    rng = np.random.default_rng(seed)
    n_slots = int(np.ceil((t[-1] - t[0]) / hold_s)) + 1
    levels = rng.choice([-1.0, 1.0], size=n_slots)
    slot = ((t - t[0]) / hold_s).astype(int)
    return offset_V + amplitude_V * levels[slot]


def cycle_input(t, amplitude_V, period_s, ramp_s=0.0, offset_V=0.0, dwell_fraction=0.0):
    """Extend/retract cycles: +amplitude for half a period, then -amplitude.

    Each half starts with a linear ramp of ``ramp_s`` (a trapezoid) and ends with
    ``dwell_fraction`` of the half at rest (u = offset), e.g. 0.5 gives
    extend, hold, retract, hold.
    """
    half = period_s / 2
    tau = np.mod(t, half)
    direction = np.where(np.mod(t, period_s) < half, 1.0, -1.0)
    moving = tau < (1.0 - dwell_fraction) * half
    rising = np.clip(tau / ramp_s, 0.0, 1.0) if ramp_s > 0 else 1.0
    return offset_V + amplitude_V * direction * rising * moving


def pwl_csv_input(t, file, base_dir="."):
    """Piecewise-linear u(t) from a CSV with header ``t,u`` (s, V); held constant outside."""
    path = Path(base_dir) / file
    try:
        data = np.genfromtxt(path, delimiter=",", names=True)
    except OSError:
        raise UserError(f"{path}: file not found (input.file)") from None
    if data.dtype.names is None or not {"t", "u"} <= set(data.dtype.names):
        raise UserError(f"{path}: needs a header with columns 't' and 'u'")
    if not np.all(np.isfinite(data["t"])) or np.any(np.diff(data["t"]) <= 0):
        raise UserError(f"{where(path, 't')}: times must be finite and strictly increasing")
    if not np.all(np.isfinite(data["u"])):
        raise UserError(f"{where(path, 'u')}: non-numeric or missing value")
    return np.interp(t, data["t"], data["u"])


INPUT_KINDS: dict[str, Callable[..., np.ndarray]] = {
    "step": step_input, "ramp": ramp_input, "sine": sine_input, "chirp": chirp_input,
    "prbs": prbs_input, "cycle": cycle_input, "pwl_csv": pwl_csv_input,
}


# --- time-varying parameters (faults, load) --------------------------------------------

def constant_profile(t, value):
    """``value`` for the whole run."""
    return np.full_like(t, value, dtype=float)


def step_profile(t, value, t0_s, before=0.0):
    """``before`` until ``t0_s``, then ``value`` (an abrupt fault, or a load picked up)."""
    return np.where(t >= t0_s, value, before)


def ramp_profile(t, value, t0_s, t1_s, before=0.0):
    """From ``before`` at ``t0_s`` linearly to ``value`` at ``t1_s`` (an incipient fault)."""
    return np.interp(t, [t0_s, t1_s], [before, value])


def intermittent_profile(t, value, t0_s, on_s, off_s, before=0.0):
    """From ``t0_s`` on: ``value`` for ``on_s``, ``before`` for ``off_s``, repeating."""
    phase = np.mod(t - t0_s, on_s + off_s)
    return np.where((t >= t0_s) & (phase < on_s), value, before)


def pwl_profile(t, points):
    """Piecewise linear through ``points = [[t0, v0], [t1, v1], ...]``."""
    pts = np.asarray(points, dtype=float)
    return np.interp(t, pts[:, 0], pts[:, 1])


PROFILE_KINDS: dict[str, Callable[..., np.ndarray]] = {
    "constant": constant_profile, "step": step_profile, "ramp": ramp_profile,
    "intermittent": intermittent_profile, "pwl": pwl_profile,
}


def evaluate(kinds: dict[str, Callable], spec: dict[str, Any], t: np.ndarray, source, field: str,
             **extra) -> np.ndarray:
    """Evaluate the profile ``spec`` (a table with ``kind`` and its keys) on ``t``.

    Errors name the file, the field (e.g. ``faults.K_extA.t0_s``) and what is wrong.
    """
    spec = dict(spec)
    kind = spec.pop("kind", None)
    if kind not in kinds:
        raise UserError(f"{where(source, field + '.kind')}: expected one of {sorted(kinds)}, got {kind!r}")
    func = kinds[kind]
    sig = inspect.signature(func)
    allowed = [n for n in sig.parameters if n not in ("t", *extra)]
    required = [n for n in allowed if sig.parameters[n].default is inspect.Parameter.empty]
    for key, value in spec.items():
        if key not in allowed:
            raise UserError(f"{where(source, f'{field}.{key}')}: unknown key for kind '{kind}'; allowed: {allowed}")
        if key not in ("file", "points", "seed") and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise UserError(f"{where(source, f'{field}.{key}')}: expected a number, got {value!r}")
    missing = [n for n in required if n not in spec]
    if missing:
        raise UserError(f"{where(source, field)}: kind '{kind}' needs keys {missing}")
    _check_times(spec, source, field)
    values = func(t, **spec, **extra)
    if not np.all(np.isfinite(values)):
        raise UserError(f"{where(source, field)}: the profile is not finite everywhere")
    return np.asarray(values, dtype=float)


def _check_times(spec: dict, source, field: str) -> None:
    if not 0 <= spec.get("dwell_fraction", 0) < 1:
        raise UserError(f"{where(source, f'{field}.dwell_fraction')}: must be in [0, 1)")
    for key in ("hold_s", "period_s", "on_s", "frequency_Hz"):
        if key in spec and not spec[key] > 0:
            raise UserError(f"{where(source, f'{field}.{key}')}: must be > 0, got {spec[key]}")
    if "t1_s" in spec and "t0_s" in spec and not spec["t1_s"] > spec["t0_s"]:
        raise UserError(f"{where(source, f'{field}.t1_s')}: must be after t0_s ({spec['t0_s']} s)")
    if "off_s" in spec and spec["off_s"] < 0:
        raise UserError(f"{where(source, f'{field}.off_s')}: must be >= 0")
    if "points" in spec:
        pts = np.asarray(spec["points"], dtype=float) if _is_numeric_table(spec["points"]) else None
        if pts is None or pts.ndim != 2 or pts.shape[1] != 2 or np.any(np.diff(pts[:, 0]) <= 0):
            raise UserError(f"{where(source, f'{field}.points')}: expected [[t, value], ...] with increasing t")


def _is_numeric_table(points) -> bool:
    try:
        np.asarray(points, dtype=float)
        return True
    except (TypeError, ValueError):
        return False
