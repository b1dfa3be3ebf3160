"""A scenario on the rig: from a parsed scenario and the rig's settings to the true trajectory
(:func:`simulate`) and to a recording in the shared format (:func:`record`).

The scenario is sam's (:class:`sam.scenario.Scenario`: plant, input or ``[control]``, load and
fault profiles, duration, seed); what only the rig reads is in :class:`rig.settings.RigSettings`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sam.errors import UserError, where
from sam.recording import Recording
from sam.scenario import Scenario

from .integrate import (
    CTRL_CLOSED, CTRL_DITHER_HZ, CTRL_DITHER_V, CTRL_EVERY, CTRL_HYSTERESIS, CTRL_KI, CTRL_KP, CTRL_LIMIT, N_CTRL, run,
)
from .layout import P_VAPOUR, TIME_VARYING
from .machine import build
from .mechanics import joint_angle, piston_position
from .model import CHANNELS, initial_state
from .sensors import ENC_COUNT, ENC_L1, ENC_L2, ENC_L3, ENC_ZERO, encoder_reading, pressure_reading
from .settings import RigSettings


@dataclass(frozen=True, eq=False)
class RigRun:
    """The rig's true trajectory at the logged instants.

    Attributes:
        t: (n_rec,) [s].
        truth: channel -> (n_rec,), the channels of :data:`rig.model.CHANNELS` (theta [rad],
            omega [rad/s], x [m], v [m/s], p_A, p_B, p_S [Pa], x_s [1], z [m], y_A, y_B [Pa]:
            the transmitters' outputs before delay, noise and ADC).
        u: (n_rec,) [V], the valve command at each instant (held over the sample after it).
        setpoint: (n_rec,) [m], the position reference (None in open loop).
        params: parameter name -> (n_rec,), the fault and load profiles at each instant.
        machine: (N_CONSTANTS,) the rig's machine vector (:mod:`rig.machine`), at the start.
        encoder: the encoder's settings vector (:mod:`rig.sensors`).
    """

    t: np.ndarray
    truth: dict[str, np.ndarray]
    u: np.ndarray
    setpoint: np.ndarray | None
    params: dict[str, np.ndarray]
    machine: np.ndarray
    encoder: np.ndarray


def simulate(sc: Scenario, settings: RigSettings) -> RigRun:
    """Run the scenario ``sc`` on the rig: RK4 at ``settings.numerics.step_s``, logged every
    ``sc.output_every`` samples of ``sc.dt``."""
    h = settings.numerics.step_s
    sub = int(round(sc.dt / h))
    if sub < 1 or abs(sub * h - sc.dt) > 1e-9 * sc.dt:
        raise UserError(f"{where(sc.source, 'rig.numerics.step_s')}: {h:g} s must divide dt_s = {sc.dt:g} s")
    unknown = set(sc.time_varying) - set(TIME_VARYING)
    if unknown:
        raise UserError(f"{where(sc.source, sorted(unknown)[0])}: the rig cannot vary this parameter in time")
    geometry_rng, _ = _streams(sc.seed)
    c = build(sc.plant, settings, geometry_rng, sc.source)
    names = list(sc.time_varying)
    tv_idx = np.array([TIME_VARYING[name] for name in names], dtype=np.int64)
    tv = np.array([sc.time_varying[name] for name in names]).reshape(len(names), len(sc.t))
    c[tv_idx] = tv[:, 0]
    y = initial_state(c, sc.x0_m)
    n = len(sc.t)
    out = np.empty((n // sc.output_every + 1, len(CHANNELS)))
    u_log = np.empty(n)
    enc = encoder_settings(sc, settings)
    setpoint = sc.control.setpoint if sc.control is not None else np.zeros(n)
    run(y, c.copy(), np.nan_to_num(sc.u), tv_idx, tv, setpoint, controller_settings(sc, settings), enc, h, sub,
        sc.dt, sc.output_every, out, u_log)
    if not np.all(np.isfinite(out)):
        bad = np.argmax(~np.all(np.isfinite(out), axis=1))
        raise UserError(f"{where(sc.source, 'plant')}: the rig left the finite range at t = "
                        f"{bad * sc.output_every * sc.dt:.4g} s; check the plant and [rig] values")
    keep = np.arange(out.shape[0]) * sc.output_every
    at = np.minimum(keep, n - 1)  # the last instant repeats the last sample's value
    return RigRun(
        t=keep * sc.dt, truth={name: out[:, j] for j, name in enumerate(CHANNELS)}, u=u_log[at],
        setpoint=None if sc.control is None else sc.control.setpoint[at],
        params={name: sc.time_varying.get(name, np.full(n, c[index]))[at] for name, index in TIME_VARYING.items()},
        machine=c, encoder=enc,
    )


def record(sc: Scenario, settings: RigSettings) -> Recording:
    """Run the scenario on the rig and log it as the lab's logger would: a recording in the shared
    format, with the truth in ``true_*`` columns."""
    res = simulate(sc, settings)
    s = settings.sensors
    _, noise_rng = _streams(sc.seed)
    tr = res.truth
    theta = encoder_reading(tr["theta"], res.encoder)
    enc = res.encoder
    signals = {
        "u": res.u,
        "pA": pressure_reading(tr["y_A"], res.t, s, s.offset_A_Pa, noise_rng),
        "pB": pressure_reading(tr["y_B"], res.t, s, s.offset_B_Pa, noise_rng),
        "theta": theta,
        "x": piston_position(theta, enc[ENC_L1], enc[ENC_L2], enc[ENC_L3]),
    }
    if s.measure_pS:
        signals["pS"] = pressure_reading(tr["p_S"], res.t, s, 0.0, noise_rng)
    if s.measure_v:
        signals["v"] = tr["v"].copy()
    if s.measure_xs:
        signals["xs"] = tr["x_s"].copy()
    truth = {"true_pA": tr["p_A"], "true_pB": tr["p_B"], "true_pS": tr["p_S"], "true_x": tr["x"],
             "true_v": tr["v"], "true_xs": tr["x_s"], "true_theta": tr["theta"],
             "true_K_int": res.params["K_int"], "true_K_extA": res.params["K_extA"],
             "true_K_extB": res.params["K_extB"], "true_offset": res.params["offset"], "true_mL": res.params["m_L"]}
    if res.setpoint is not None:
        truth["true_x_ref"] = res.setpoint
    metadata = {"plant": sc.plant.name, "scenario": sc.name, "generator": "samfdi simulate --engine rig",
                "seed": str(sc.seed), "rig_step": f"RK4, {settings.numerics.step_s:g} s",
                "control": "open loop" if sc.control is None else
                f"closed loop, P{'I' if sc.control.ki_V_per_m_s else ''} at {sc.control.rate_Hz:g} Hz"}
    if sc.description:
        metadata["description"] = sc.description
    if min(tr["p_A"].min(), tr["p_B"].min()) <= P_VAPOUR:
        metadata["warning"] = "a chamber pressure reached the vapour pressure (cavitation)"
    return Recording(t=res.t, signals=signals, truth=truth, metadata=metadata)


def _streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent seeded streams: the geometry's draws, and the sensors' noise."""
    return tuple(np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))


def encoder_settings(sc: Scenario, settings: RigSettings) -> np.ndarray:
    """The encoder's settings vector: counts of ``encoder_deg`` from the retracted angle of the
    drawing (the plant file's lengths), which the lab also uses to compute x from the count."""
    b = sc.plant.boom
    enc = np.zeros(5)
    enc[ENC_COUNT] = np.deg2rad(settings.sensors.encoder_deg)
    enc[ENC_ZERO] = joint_angle(0.0, b.L_1, b.L_2, b.L_3)
    enc[ENC_L1], enc[ENC_L2], enc[ENC_L3] = b.L_1, b.L_2, b.L_3
    return enc


def controller_settings(sc: Scenario, settings: RigSettings) -> np.ndarray:
    """The controller's settings vector (see :func:`rig.integrate.run`) of the scenario's
    ``[control]`` (open loop without one) and the valve's hysteresis."""
    ctrl = np.zeros(N_CTRL)
    ctrl[CTRL_HYSTERESIS] = settings.effects.hysteresis_V
    ctrl[CTRL_EVERY] = 1
    c = sc.control
    if c is not None:
        ctrl[CTRL_CLOSED], ctrl[CTRL_KP], ctrl[CTRL_KI], ctrl[CTRL_LIMIT] = 1.0, c.kp_V_per_m, c.ki_V_per_m_s, c.u_limit_V
        ctrl[CTRL_DITHER_V], ctrl[CTRL_DITHER_HZ] = c.dither_V, c.dither_Hz
        ctrl[CTRL_EVERY] = round(1.0 / (c.rate_Hz * sc.dt))
    return ctrl
