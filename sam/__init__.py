"""sam: the shared discrete-time model of the Single Axis Mock-up (SAM).

Nurmi & Mattila (2011), Section 2: a servo valve, an asymmetric cylinder, a boom
with loads, LuGre friction and leakage faults, advanced by forward Euler
(Eq. (22); a chamber pressure semi-implicit where it is stiff, against a rail through an open
edge) or, when asked, by sub-steps of a higher-order scheme. One step function
(:func:`sam.dynamics.step_lanes`, which advances a block of runs in one vectorised loop) serves
the batch simulator, the global sensitivity analysis and the Unscented Kalman Filter;
:func:`step` is the same step of one state.

Public face:

* parameters: :class:`Plant` and its groups, :func:`load_plant`, the flat
  vector layout :data:`P` / :data:`PARAM_NAMES`; what of a plant is uncertain,
  :class:`Uncertain` (``plant.uncertain``);
* the model: :data:`S` (state layout), :func:`step` (:data:`SCHEMES`), :func:`step_batch`
  (:func:`step_batch_inplace`), :func:`rhs`,
  :func:`stroke_ends` (the end stops); rows kept in the step's lanes from step to step (the
  filter's sigma points): :func:`lane_blocks`, :func:`block_lane`, :func:`derived_parts`,
  :func:`step_blocks`;
* simulation: :func:`simulate_batch`, :func:`initial_state`, :func:`run_scenario`;
* recordings: :class:`Recording`, :func:`read_recording`, :func:`write_recording`, and the white
  noise on a recorded signal, :func:`white_noise_std`.
"""

from . import jitcache  # noqa: F401  (before the first cached kernel is compiled)
from .constants import DT_DEFAULT, LEAK_REFERENCE_DP, LPM
from .dynamics import D, N_SCRATCH, N_STATES, SCHEMES, S, Scheme, derive, euler_step, rhs, step, stroke_ends
from .errors import UserError
from .params import (
    P, PARAM_NAMES, Boom, Cylinder, Disturbances, Effects, EndStops, Faults, Fluid, Friction, Plant,
    Supply, Uncertain, Valve,
)
from .plant import default_plant_path, load_plant
from .measurement import white_noise_std
from .recording import Recording, RecordingError, read_recording, write_recording
from .row_step import block_lane, derived_parts, lane_blocks, step_batch, step_batch_inplace, step_blocks
from .scenario import Scenario, load_scenario, run_scenario
from .simulate import BatchResult, initial_state, simulate_batch

__all__ = [
    "DT_DEFAULT", "LEAK_REFERENCE_DP", "LPM", "D", "N_SCRATCH", "N_STATES", "SCHEMES", "S", "Scheme", "derive",
    "euler_step", "step",
    "rhs", "step_batch", "step_batch_inplace", "block_lane", "derived_parts", "lane_blocks", "step_blocks",
    "stroke_ends", "UserError", "P", "PARAM_NAMES", "Boom", "Cylinder", "Disturbances",
    "Effects", "EndStops", "Faults", "Fluid", "Friction", "Plant", "Supply", "Uncertain", "Valve", "default_plant_path",
    "load_plant", "Recording", "RecordingError", "read_recording", "white_noise_std", "write_recording",
    "BatchResult", "initial_state", "simulate_batch", "Scenario", "load_scenario", "run_scenario",
]
