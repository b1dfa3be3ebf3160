"""SECOND held-out set for the mismatch diagnosis: never used to tune it.

Made before a change to the acceptance rule and run once before and once after
it, as a check that the change generalised (docs/mismatch.md). The cases are the
same physics as the development set (:mod:`discrepancy.cases`) at other
magnitudes, in other pairs, and with other seeds (default seed 3; the dev set
uses 1, the first held-out set 2). Everything is produced by ``sam`` through
:func:`discrepancy.cases.make_recording`, as in :mod:`discrepancy.heldout`.

    python -m discrepancy.proof --set heldout2 [--duration 20]
"""

from __future__ import annotations

from .cases import Case

#: The default seed of this set (dev: 1, heldout: 2).
SEED = 3

HELDOUT2: tuple[Case, ...] = (
    # --- two effects at once, other magnitudes and other pairs
    Case("two_air_bypass", ("entrained_air", "bypass_leakage"), {"air_fraction": 0.008, "K_bypass": 2e-12},
         note="0.8 % air + bypass 2e-12 m^3/(s Pa)"),
    Case("two_air_mass", ("entrained_air", "load_mass"), {"air_fraction": 0.01, "m_L": 700.0},
         note="1 % air + 700 kg for 494 kg"),
    Case("two_overlap_delay", ("spool_lap", "time_delay"), {"lap": 0.02}, sensors={"delay_s": 0.008},
         note="2 % overlap + 8 ms delay"),
    # --- single effects, other magnitudes
    Case("friction_shift", ("friction_level",), {"F_C": 2000.0, "F_S": 3000.0, "b": 5000.0},
         note="F_C 2 kN, F_S 3 kN, b 5000 N s/m"),
    Case("friction_low", ("friction_level",), {"F_C": 300.0, "F_S": 1500.0, "b": 800.0},
         note="F_C 0.3 kN, F_S 1.5 kN, b 800 N s/m"),
    Case("hose_mid", ("hose_compliance",), {"C_hose": 1e-12}, note="1e-12 m^3/Pa per chamber"),
    Case("droop_mid", ("supply_droop",), {"R_supply": 3e9}, note="3e9 Pa s/m^3"),
    Case("air_mid", ("entrained_air",), {"air_fraction": 0.015}, note="1.5 % air"),
    Case("bypass_high", ("bypass_leakage",), {"K_bypass": 5e-12}, note="5e-12 m^3/(s Pa)"),
    Case("pfric_mid", ("pressure_friction",), {"k_fric_p": 1e-4}, note="1e-4 m^2"),
    Case("mass_mid", ("load_mass",), {"m_L": 620.0}, note="620 kg for 494 kg"),
    Case("lag_short", ("sensor_lag",), sensors={"lag_s": 0.006}, note="6 ms"),
    # --- no new physics
    Case("nominal_AT_PB", (), {"Q_N_AT": 2.8e-4, "Q_N_PB": 5.0e-4}, note="Q_N_AT 17 L/min, Q_N_PB 30 L/min"),
    Case("no_mismatch_5", (), note="the nominal plant, seed 5", seed_offset=2),
)
