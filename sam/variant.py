"""Which compiled variant of the model's step (:func:`sam.dynamics.step_lanes`) a batch needs.

The lane loops are compiled four times, with and without the leak paths and the optional effects
(:class:`sam.params.Effects`, Eq. (7)'s R-dot term), so that a batch without them runs
straight-line arithmetic without the terms that would give zeros. The test here is the one place
that says what "without" means: every term that ``leaks=False`` or ``effects=False`` leaves out
of :func:`sam.dynamics.rates` must be listed, or a batch that has it would silently lose it.
"""

from __future__ import annotations

import numba
import numpy as np

from .params import P

# error_model="numpy": IEEE results (inf, nan) instead of a zero-division check per division
jit = numba.njit(cache=True, error_model="numpy")

#: Columns whose non-zero values need the ``leaks`` variant of the step, and those whose
#: values other than neutral need the ``effects`` variant (:func:`kernel_variant`).
LEAK_COLS = np.array([P.K_int, P.K_extA, P.K_extB, P.K_bypass], dtype=np.int64)


@jit
def kernel_variant(params):
    """(leaks, effects) of :func:`sam.dynamics.step_lanes` for a batch of parameter rows (n, len(P)): whether
    any row has a leak path (K_int, K_extA, K_extB, K_bypass non-zero), and whether any has an
    underlapped valve, supply droop, a pump limit, a flow or opening limit, entrained air, seal friction on the
    pressure difference or the rod pressure, Eq. (7)'s R-dot term, or an elastic end stop."""
    leaks, effects = False, False
    for i in range(params.shape[0]):
        for c in LEAK_COLS:
            leaks |= params[i, c] != 0.0
        effects |= ((params[i, P.lap] < 0.0) | (params[i, P.R_supply] != 0.0) | (params[i, P.Q_sat] != np.inf)
                    | (params[i, P.air_fraction] != 0.0) | (params[i, P.arm_rate_torque] != 0.0)
                    | (params[i, P.x_open] != np.inf) | (params[i, P.k_fric_dp] != 0.0)
                    | (params[i, P.k_fric_rod] != 0.0) | (params[i, P.Q_pump] != np.inf)
                    | (params[i, P.k_stop] != 0.0))
    return leaks, effects
