"""The measurement model: what the test bed's sensors report of the model's states.

Appendix 1: two pressure transmitters (0-25 MPa) on chambers A and B, and an
angle encoder of 0.007 deg/pulse on the boom joint. The piston position x is
computed from the quantised angle through Eq. (3), as a logger would.

Optional sensor effects (each seeded): white pressure noise (default 20 kPa),
encoder quantisation, a first-order lag and a pure time delay; and the reverse, the white noise
read back off a recorded signal (:func:`white_noise_std`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from .geometry import joint_angle, piston_position
from .hydraulics import flow_coefficient, limited_openings, supply_flow_array
from .params import P
from .supply import supply_pressure as static_supply_pressure

ENCODER_RESOLUTION_RAD = np.deg2rad(0.007)  #: rad/pulse, Heidenhain 376 886-0B (Appendix 1)
PRESSURE_SENSOR_RANGE_PA = (0.0, 25e6)  #: Pa, Trafag 8891.74 / Druck PTX 1400 (Appendix 1)


@dataclass(frozen=True)
class Sensors:
    """Sensor settings for a simulated recording."""

    pressure_noise_Pa: float = 20e3  #: Pa, standard deviation of white noise on p_A, p_B, p_S
    encoder_quantisation: bool = True  #: quantise theta to the encoder's 0.007 deg/pulse
    lag_s: float = 0.0  #: s, first-order lag of every measured signal
    delay_s: float = 0.0  #: s, pure time delay of every measured signal
    measure_pS: bool = False  #: also record the supply pressure
    measure_v: bool = False  #: also record the piston velocity
    measure_xs: bool = False  #: also record the spool position


def first_order_lag(y: np.ndarray, dt: float, tau_s: float) -> np.ndarray:
    """A sensor's first-order lag ``tau dy_m/dt = y - y_m`` along the last axis of ``y``
    (exact for a sampled hold), started at rest at the first sample; y (..., n)."""
    if tau_s <= 0:
        return y
    a = np.exp(-dt / tau_s)
    out, _ = lfilter([1 - a], [1, -a], y, axis=-1, zi=a * y[..., :1])
    return out


def time_delay(y: np.ndarray, dt: float, delay_s: float) -> np.ndarray:
    """``y(t - delay)`` along the last axis, holding the first sample before the start;
    fractional delays by linear interpolation; y (..., n)."""
    if delay_s <= 0:
        return y
    n = y.shape[-1]
    tq = np.arange(n) - delay_s / dt
    i0 = np.clip(np.floor(tq).astype(int), 0, n - 1)
    i1 = np.clip(i0 + 1, 0, n - 1)
    w = np.where(tq < 0, 0.0, np.clip(tq - np.floor(tq), 0, 1))
    return y[..., i0] * (1 - w) + y[..., i1] * w


def quantise_angle(theta: np.ndarray) -> np.ndarray:
    """The encoder's reading of theta [rad]: the middle of the 0.007 deg pulse interval
    it is in (an incremental encoder knows only which interval; error within +-q/2)."""
    q = ENCODER_RESOLUTION_RAD
    return (np.floor(theta / q) + 0.5) * q


def measure(states: dict[str, np.ndarray], params: np.ndarray, dt: float, sensors: Sensors,
            rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Sensor signals of one run, named as in docs/recordings.md.

    Args:
        states: state name -> (n,) trajectory (from :class:`sam.simulate.BatchResult`), at step ``dt``.
        params: (len(P),) the run's parameter vector (geometry, supply).
        sensors: what to measure and how imperfectly.
        rng: the seeded source of noise.
    """
    L = params[P.L_1], params[P.L_2], params[P.L_3]
    theta = joint_angle(states["x"], *L)
    if sensors.encoder_quantisation:
        theta = quantise_angle(theta)
    signals = {
        "pA": states["p_A"] + sensors.pressure_noise_Pa * rng.standard_normal(theta.shape),
        "pB": states["p_B"] + sensors.pressure_noise_Pa * rng.standard_normal(theta.shape),
        "theta": theta,
        "x": piston_position(theta, *L),
    }
    if sensors.measure_pS:
        signals["pS"] = supply_pressure(states, params) + sensors.pressure_noise_Pa * rng.standard_normal(theta.shape)
    if sensors.measure_v:
        signals["v"] = states["v"].copy()
    if sensors.measure_xs:
        signals["xs"] = states["x_s"].copy()
    return {k: time_delay(first_order_lag(y, dt, sensors.lag_s), dt, sensors.delay_s) for k, y in signals.items()}


def supply_pressure(states: dict[str, np.ndarray], params: np.ndarray) -> np.ndarray:
    """The supply pressure at the valve [Pa]: p_S less the droop R_supply times the flow drawn, and
    lower where a pump-limited supply's relief has shut (sam.supply)."""
    if params[P.R_supply] == 0 and np.isinf(params[P.Q_pump]):
        return np.full_like(states["p_A"], params[P.p_S])
    return supply_pressure_array(states["x_s"], states["p_A"], states["p_B"], params)


def supply_pressure_array(x_s, p_A, p_B, p) -> np.ndarray:
    """:func:`sam.supply.supply_pressure` over trajectories (n,) of one parameter vector ``p`` [Pa]. The open
    supply edge is the one the spool opens (Eqs. (10)-(11)); with both open (an underlap) their
    coefficients add and p_load is their coefficient-weighted chamber pressure."""
    q_open = supply_flow_array(x_s, p_A, p_B, p, pump=False)
    out = np.empty(len(q_open))
    K_PA = flow_coefficient(p[P.Q_N_PA], p[P.dp_N_PA])
    K_PB = flow_coefficient(p[P.Q_N_PB], p[P.dp_N_PB])
    for i in range(len(q_open)):
        a_A, a_B = limited_openings(x_s[i], p[P.offset], p[P.lap], p[P.x_open])
        k_A, k_B = K_PA * a_A, K_PB * a_B
        p_load = (k_A * p_A[i] + k_B * p_B[i]) / (k_A + k_B) if k_A + k_B > 0 else p[P.p_S]
        out[i] = static_supply_pressure(q_open[i], p[P.p_S], p[P.R_supply], p[P.Q_pump], k_A + k_B, p_load)
    return out


def white_noise_std(a: np.ndarray) -> float:
    """Std of the white noise on a uniformly sampled signal (its unit), from its second
    differences: white noise of std s gives y[k+1] - 2 y[k] + y[k-1] a std of s sqrt(6), and
    their median absolute value (x 1.4826, the normal distribution's MAD factor) ignores the
    samples where the signal itself bends (steps, transients), as long as those are fewer than
    half. NaN samples are skipped; nan when fewer than 10 differences are left."""
    d2 = np.diff(np.asarray(a, dtype=float), 2)
    d2 = d2[np.isfinite(d2)]
    if len(d2) < 10:
        return float("nan")
    return float(1.4826 * np.median(np.abs(d2)) / np.sqrt(6.0))


#: a transmitter's readings count as saturated when this many or more in a row sit at the
#: signal's largest value (and at least SATURATED_RUN_S): white noise of NOISY_PA never repeats
#: its top reading that often
SATURATED_RUN = 5
SATURATED_RUN_S = 0.01
NOISY_PA = 1e3


def at_ceiling(a: np.ndarray, dt: float) -> np.ndarray:
    """Bool mask of the samples of a noisy pressure signal that are a transmitter saturated at the
    top of its range: runs of at least max(SATURATED_RUN, SATURATED_RUN_S / dt) equal readings at
    the signal's largest value. Such a reading says only "at or above"; a signal without noise
    (a simulation) is never called saturated, its flat top is the model's."""
    a = np.asarray(a, dtype=float)
    mask = np.zeros(a.shape, dtype=bool)
    finite = np.isfinite(a)
    if not finite.any():
        return mask
    top = a == a[finite].max()
    if not white_noise_std(np.where(top, np.nan, a)) > NOISY_PA:  # the noise below the top, where it is not cut
        return mask
    edges = np.diff(np.r_[0, top.astype(np.int8), 0])
    need = max(SATURATED_RUN, round(SATURATED_RUN_S / dt))
    for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        if stop - start >= need:
            mask[start:stop] = True
    return mask
