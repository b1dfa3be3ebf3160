"""Small builders shared by the rig's tests (tests/test_rig_*.py)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import rig
from sam.scenario import scenario_from_table

SOURCE = Path("case.toml")


def scenario(duration_s: float = 4.0, x0: float = 0.05, m_L: float = 494.0, dt_s: float = 1e-3, **tables):
    """A scenario from tables (``input`` or ``control``, ``faults``, ...), 494 kg from x0 [m]."""
    table = {"duration_s": duration_s, "dt_s": dt_s, "seed": 7, "initial": {"x_m": x0},
             "load": {"m_L_kg": m_L}, **tables}
    return scenario_from_table(table, SOURCE)


def settings(step_s: float = 1e-4, sensors: dict | None = None, stops: dict | None = None, **effects):
    """Rig settings: the integrator's step, sensor and stop overrides and effects by name."""
    return rig.RigSettings(numerics=rig.Numerics(step_s=step_s), sensors=rig.Sensors(**(sensors or {})),
                           stops=dataclasses.replace(rig.Stops(), **(stops or {})), effects=rig.Effects(**effects))
