"""The filter's state vector and measurement vector: names, indices and internal units.

State (12 base states, SI)::

    [p_A, p_B, x_s, dx_s, x, v, z,  K_int, K_extA, K_extB, offset, F_d]
     --- the model state sam.S ---  --- slowly varying parameters ----

then one relative error per calibration state and one absolute value per unknown input
(:class:`fdi.config.FilterConfig`). Each augmented state drives the parameter column of
:data:`sam.P` of its name. Inside the filter every state is divided by its internal unit
(:data:`SCALE`: pressures in MPa, leaks in L/min at 10 MPa, ...) so that the covariance is well
conditioned; the measurements likewise (pressures in MPa, x in cm, theta in mrad).
"""

from __future__ import annotations

import math

import numpy as np

from sam import P, S
from sam.hydraulics import leak_coefficient
from sam.hydraulics import leak_lpm as _leak_lpm
from sam.measurement import ENCODER_RESOLUTION_RAD

#: The model states advanced by sam's step (Eq. (22)), first in the state vector.
N_MODEL = 7
#: Augmented states beyond the model state; each drives the parameter of its name.
AUG_PARAMS = ("K_int", "K_extA", "K_extB", "offset", "F_d")
#: The base states in order: the model states, then the augmented ones.
STATE_NAMES = tuple(S.__members__) + AUG_PARAMS
N_AUG = len(STATE_NAMES)
I_KINT, I_KEXTA, I_KEXTB, I_OFFSET, I_FD = 7, 8, 9, 10, 11
LEAK_STATES = (I_KINT, I_KEXTA, I_KEXTB)
FAULT_STATES = (I_KINT, I_KEXTA, I_KEXTB, I_OFFSET)
#: The state the position measurement reads (the piston position x).
I_X = int(S.x)
PARAM_COLS = np.array([int(P[name]) for name in AUG_PARAMS], dtype=np.int64)
P_S_COL = int(P.p_S)
L1_COL, L2_COL, L3_COL = int(P.L_1), int(P.L_2), int(P.L_3)

#: m^3/(s Pa^0.5) per "L/min at 10 MPa": L/min = K * sqrt(10 MPa) * 60000.
K_PER_LPM = leak_coefficient(1.0)

#: Internal unit of each base state (SI per internal unit).
SCALE = np.array([
    1e6, 1e6,          # p_A, p_B: MPa
    1e-2, 1.0,         # x_s: % of travel; dx_s: 1/s
    1e-2, 1e-2,        # x: cm; v: cm/s
    1e-4,              # z: 0.1 mm (bristle deflection ~ F_C / sigma_0 = 0.25 mm)
    K_PER_LPM, K_PER_LPM, K_PER_LPM,  # leaks: L/min at 10 MPa
    1e-2,              # offset: % of travel
    1e3,               # F_d: kN
])
#: Internal unit of a calibration state (a relative error): 1 %.
CALIBRATION_SCALE = 1e-2
#: Internal unit of each unknown-input state (m^3/s): 1 L/min.
UNKNOWN_INPUT_SCALE = {"Q_dA": 1e-3 / 60, "Q_dB": 1e-3 / 60}

#: Measurement kinds of the position channel.
POS_X, POS_THETA = 0, 1
#: Internal unit of each measurement: pressures MPa, x cm, theta mrad.
MEAS_SCALE_P = 1e6
MEAS_SCALE_X = 1e-2
MEAS_SCALE_THETA = 1e-3
#: Gain of the scaled pressure measurement on the scaled pressure state.
H_P = 1e6 / MEAS_SCALE_P
#: Cholesky columns the update's closed-form transform needs: the measurement reads states 0..I_X.
N_READ = I_X + 1
THETA_PULSE = ENCODER_RESOLUTION_RAD  #: rad per encoder pulse (the SAM's encoder, Appendix 1)
LOG_2PI = math.log(2.0 * math.pi)  #: constant of the Gaussian log-density


def leak_lpm(K: np.ndarray) -> np.ndarray:
    """Leak coefficients K [m^3/(s Pa^0.5)] -> L/min at 10 MPa (sam.hydraulics.leak_lpm, on arrays)."""
    return _leak_lpm(np.asarray(K))
