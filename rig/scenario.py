"""A rig scenario file: sam's scenario (plant, input or ``[control]``, load, faults, seed) and the
``[rig.*]`` tables that only the rig reads (:mod:`rig.settings`)."""

from __future__ import annotations

from pathlib import Path

from sam.plant import read_toml
from sam.scenario import Scenario, scenario_from_table

from .settings import RigSettings, parse_rig


def load_rig_scenario(path: str | Path) -> tuple[Scenario, RigSettings]:
    """Read and validate a scenario file for the rig; every error names the file and the key."""
    path = Path(path)
    table = read_toml(path)
    return scenario_from_table(table, path), parse_rig(table.get("rig"), path)
