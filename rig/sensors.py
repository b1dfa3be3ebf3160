"""The lab's sensors and logger (Appendix 1): pressure transmitters read through an ADC, and the
joint's incremental encoder.

A transmitter's lag is integrated with the rig's state (:data:`rig.layout.R.y_A`); here follow its
transport delay, zero offset and noise, and the ADC's range and quantisation: readings below 0
or above full scale are clipped, as a 0-25 MPa transmitter's are. The encoder counts whole pulses
from its zero mark, the retracted angle as the lab's drawing has it, and the logger computes the
piston position from the count through Eq. (3) with the drawing's lengths: the machine's own
lengths (geometry tolerances) are not known to it.
"""

from __future__ import annotations

import numba
import numpy as np

from .settings import Sensors

#: Layout of the encoder's settings vector: count [rad], its zero [rad], the lab's L_1, L_2, L_3 [m].
ENC_COUNT, ENC_ZERO, ENC_L1, ENC_L2, ENC_L3 = range(5)


@numba.njit(cache=True, error_model="numpy")
def encoder_reading(theta, enc):
    """The joint angle [rad] (a float or an array) an incremental encoder reports: whole counts
    from its zero, floored."""
    q = enc[ENC_COUNT]
    if q == 0.0:
        return theta + 0.0
    return enc[ENC_ZERO] + q * np.floor((theta - enc[ENC_ZERO]) / q)


def pressure_reading(p: np.ndarray, t: np.ndarray, sensors: Sensors, offset: float,
                     rng: np.random.Generator) -> np.ndarray:
    """What the logger reads [Pa] of a transmitter's output p (n,) at the instants t (n,) [s]."""
    delayed = np.interp(t - sensors.delay_s, t, p) if sensors.delay_s > 0 else p
    y = delayed + offset + sensors.pressure_noise_Pa * rng.standard_normal(p.shape)
    y = np.clip(y, 0.0, sensors.pressure_full_scale_Pa)
    bits = int(sensors.adc_bits)
    if bits > 0:
        q = sensors.pressure_full_scale_Pa / (2**bits - 1)
        y = np.round(y / q) * q
    return y
