"""The ``[control]`` section of a scenario: closed-loop position control, as a lab runs its rig.

A P or PI controller on the piston position (computed from the encoder angle through Eq. (3)),
sampled at ``rate_Hz``, its output saturated at ``u_limit_V`` and held between samples, with
an optional sine dither::

    [control]
    rate_Hz = 1000.0            # controller sample rate
    kp_V_per_m = 150.0          # proportional gain [V/m]
    ki_V_per_m_s = 0.0          # integral gain [V/(m s)]
    u_limit_V = 10.0            # output saturation (<= 10 V, the valve's range)
    dither_V = 0.0              # optional dither amplitude
    dither_Hz = 0.0             # ... and frequency
    [control.setpoint]          # the position reference [m], see SETPOINT_KINDS
    kind = "steps"
    points = [[0.0, 0.05], [2.0, 0.20], [8.0, 0.10]]

This module parses and validates the section; the rig simulator (``rig/``) runs the loop.
``sam``'s own simulator takes an open-loop ``[input]`` and refuses a closed loop
(:func:`sam.scenario.run_scenario`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import UserError, did_you_mean, where
from .profiles import U_LIMIT_V, evaluate


@dataclass(frozen=True, eq=False)  # eq=False: the setpoint is an array
class Control:
    """A closed position loop. The setpoint is sampled on the scenario's grid (n_steps,) [m]."""

    setpoint: np.ndarray  #: m, piston position reference on the scenario's time grid
    kp_V_per_m: float  #: V/m, proportional gain on the position error
    ki_V_per_m_s: float = 0.0  #: V/(m s), integral gain (0: a P controller)
    rate_Hz: float = 1000.0  #: Hz, the controller's sample rate; its output is held between samples
    u_limit_V: float = U_LIMIT_V  #: V, output saturation (the integrator stops while saturated)
    dither_V: float = 0.0  #: V, amplitude of a sine dither added to the output
    dither_Hz: float = 0.0  #: Hz, its frequency


#: The gains and settings of [control] (the setpoint is a table of its own).
_KNOBS = {f.name: f for f in dataclasses.fields(Control) if f.name != "setpoint"}


# --- setpoint profiles x_ref(t) [m] -------------------------------------------------------

def constant_setpoint(t, value_m):
    """Hold ``value_m``."""
    return np.full_like(t, value_m, dtype=float)


def steps_setpoint(t, points):
    """Steps: ``points = [[t0, x0], [t1, x1], ...]``, each position held from its time on (the first
    also before it)."""
    pts = np.asarray(points, dtype=float)
    return pts[np.maximum(np.searchsorted(pts[:, 0], t, side="right") - 1, 0), 1]


def ramps_setpoint(t, points):
    """Ramps with holds: piecewise linear through ``points = [[t0, x0], [t1, x1], ...]``; a hold is two
    points at the same position."""
    pts = np.asarray(points, dtype=float)
    return np.interp(t, pts[:, 0], pts[:, 1])


def sine_setpoint(t, mean_m, amplitude_m, frequency_Hz, phase_rad=0.0):
    """``mean_m + amplitude_m sin(2 pi f t + phase)``."""
    return mean_m + amplitude_m * np.sin(2 * np.pi * frequency_Hz * t + phase_rad)


def cycle_setpoint(t, low_m, high_m, period_s, ramp_s, t0_s=0.0):
    """A work cycle repeated every ``period_s`` from ``t0_s``: from ``low_m`` up to ``high_m`` in
    ``ramp_s``, hold, back down in ``ramp_s``, hold (each hold half a period less a ramp)."""
    half = period_s / 2
    tau = np.mod(np.maximum(t - t0_s, 0.0), period_s)
    up = np.clip(tau / ramp_s, 0.0, 1.0)
    down = np.clip((tau - half) / ramp_s, 0.0, 1.0)
    return low_m + (high_m - low_m) * np.where(tau < half, up, 1.0 - down)


SETPOINT_KINDS = {
    "constant": constant_setpoint, "steps": steps_setpoint, "ramps": ramps_setpoint,
    "sine": sine_setpoint, "cycle": cycle_setpoint,
}


def parse_control(table: dict[str, Any], t: np.ndarray, source, x_max: float) -> Control | None:
    """The ``[control]`` table of a scenario on the grid ``t`` (n_steps,) [s]; None without one.
    Every error names the file and the key; the setpoint must stay within the stroke [0, x_max]."""
    spec = table.get("control")
    if spec is None:
        return None
    if not isinstance(spec, dict):
        raise UserError(f"{where(source, 'control')}: expected a table [control]")
    allowed = {*_KNOBS, "setpoint"}
    for key in spec:
        if key not in allowed:
            raise UserError(f"{where(source, f'control.{key}')}: unknown key{did_you_mean(key, allowed)}; "
                            f"allowed: {sorted(allowed)}")
    values = {key: _number(spec, key, source) for key in _KNOBS if key in spec}
    for key, f in _KNOBS.items():
        if key not in values and f.default is dataclasses.MISSING:
            raise UserError(f"{where(source, f'control.{key}')}: missing (the controller's gain)")
    control = Control(setpoint=_setpoint(spec, t, source, x_max), **values)
    _check(control, t, source)
    return control


def _number(spec, key, source) -> float:
    value = spec[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UserError(f"{where(source, f'control.{key}')}: expected a finite number, got {value!r}")
    return float(value)


def _setpoint(spec, t, source, x_max) -> np.ndarray:
    setpoint = spec.get("setpoint")
    if not isinstance(setpoint, dict):
        raise UserError(f"{where(source, 'control.setpoint')}: missing table [control.setpoint] with a 'kind'")
    if setpoint.get("kind") == "cycle":
        _check_cycle(setpoint, source)
    x_ref = evaluate(SETPOINT_KINDS, setpoint, t, source, "control.setpoint")
    if np.any(x_ref < 0) or np.any(x_ref > x_max):
        raise UserError(f"{where(source, 'control.setpoint')}: leaves the stroke [0, {x_max}] m "
                        f"(from {x_ref.min():.4g} to {x_ref.max():.4g} m)")
    return x_ref


def _check_cycle(setpoint, source) -> None:
    ramp, period = setpoint.get("ramp_s"), setpoint.get("period_s")
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (ramp, period))
    if numbers and not 0 < ramp <= period / 2:
        raise UserError(f"{where(source, 'control.setpoint.ramp_s')}: must be in (0, period_s / 2], got {ramp!r}")


def _check(c: Control, t: np.ndarray, source) -> None:
    dt = t[1] - t[0]
    checks = [
        ("kp_V_per_m", c.kp_V_per_m > 0, "must be > 0"),
        ("ki_V_per_m_s", c.ki_V_per_m_s >= 0, "must be >= 0"),
        ("u_limit_V", 0 < c.u_limit_V <= U_LIMIT_V, f"must be in (0, {U_LIMIT_V}] V"),
        ("rate_Hz", c.rate_Hz > 0 and abs(round(1 / (c.rate_Hz * dt)) * c.rate_Hz * dt - 1) < 1e-9,
         f"must be > 0 with a period that is a whole multiple of dt_s = {dt:g} s"),
        ("dither_V", c.dither_V >= 0, "must be >= 0"),
        ("dither_Hz", c.dither_Hz >= 0 and (c.dither_V == 0 or c.dither_Hz > 0), "must be > 0 with a dither"),
    ]
    for key, ok, message in checks:
        if not ok:
            raise UserError(f"{where(source, f'control.{key}')}: {message}, got {getattr(c, key)!r}")
