"""rig: a test-rig simulator of the SAM, written apart from ``sam``.

A lab's independent simulator of the same machine: the paper's continuous equations (3)-(21),
(41)-(43) in a formulation of its own (the boom in its joint angle, the chambers in the oil they
hold), integrated by fixed-step RK4 at 0.1 ms; end stops as contacts; the lab's closed position
loop at 1 kHz or an open-loop input; transmitters, ADC and encoder; and the effects a real
machine has that the plant file does not say. It reads the same plant file as ``sam`` (through
sam's loader) and the same scenarios, and shares no dynamics code with it: the two check each
other. Nothing in ``sam``, ``gsa``, ``fdi`` or ``discrepancy`` imports it. See docs/rig.md.

Public face:

* settings: :class:`RigSettings` and its groups, :func:`parse_rig`, :func:`load_rig_scenario`;
* running: :func:`simulate` (the true trajectory, :class:`RigRun`), :func:`record` (a recording
  in the shared format, with ``true_*`` columns);
* the model: :data:`R` (state layout), :data:`C` (machine layout), :func:`build`,
  :func:`initial_state`, :func:`derivatives`, :func:`rk4_step`.
"""

import sam.jitcache  # noqa: F401  (numba's cache keyed by the project's sources: sam/jitcache.py)
from .integrate import rk4_step
from .layout import C, R
from .machine import build
from .model import derivatives, initial_state
from .scenario import load_rig_scenario
from .settings import Effects, Numerics, RigSettings, Sensors, Stops, Tolerances, parse_rig
from .simulate import RigRun, record, simulate

__all__ = [
    "rk4_step", "C", "R", "build", "derivatives", "initial_state", "load_rig_scenario", "Effects", "Numerics",
    "RigSettings", "Sensors", "Stops", "Tolerances", "parse_rig", "RigRun", "record", "simulate",
]
