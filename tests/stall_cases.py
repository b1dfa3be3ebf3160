"""The former default plant, for the tests whose examples were found on it, and a stalled
cylinder for the tests of what the detector does with pinned pressures.

The default plant lifts 800 kg from x = 0.05 m (docs/model.md, "Loads and lifting"); the former
default, ``sam_level_at_pi2_minus_alpha_cog_below.toml``, does not (it lifts 719 kg), so its
800 kg scenarios stall with p_A at the supply and p_B at the tank. These are the shipped 800 kg
scenarios as they were written for it: its plant, from x = 0.05 m, the valve at +-3 V.
"""

from __future__ import annotations

from pathlib import Path

from sam import Plant, Recording, load_plant
from sam.plant import read_toml
from sam.scenario import run_scenario, scenario_from_table

ROOT = Path(__file__).resolve().parents[1] / "scenarios"
FORMER_PLANT = ROOT / "plants" / "sam_level_at_pi2_minus_alpha_cog_below.toml"


def stalled_800kg(name: str) -> tuple[Recording, Plant]:
    """The shipped 800 kg scenario ``name`` (a file of scenarios/faults) run on the former default
    plant, from x = 0.05 m at +-3 V: the recording and that plant."""
    path = ROOT / "faults" / name
    table = read_toml(path)
    table.update(plant=str(FORMER_PLANT), initial={"x_m": 0.05})
    table["input"] = {**table["input"], "amplitude_V": 3.0}
    return run_scenario(scenario_from_table(table, path)), load_plant(FORMER_PLANT)
