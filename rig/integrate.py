"""The rig's clock: fixed-step RK4 on the continuous equations, a logger's sample grid, and the
lab's controller sampling the encoder.

Three rates nest: the internal step h (0.1 ms by default) divides the scenario's sample period
dt (the grid of the open-loop input, the fault and load profiles, and the logger), and the
controller runs every ``ctrl_every`` samples. Within a sample everything the RHS reads is held:
a zero-order hold, as a DAQ card outputs. The spool's sticking is an event between internal
steps (a Karnopp-style switch), and the valve's hysteresis a play between the command and the
spool, updated with the command.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .layout import N_STATE, C, R
from .mechanics import piston_position, spool_pull
from .model import derivatives, observe
from .sensors import ENC_L1, ENC_L2, ENC_L3, encoder_reading

jit = numba.njit(cache=True, error_model="numpy")

#: Layout of the controller's settings vector (see :func:`run`).
CTRL_CLOSED, CTRL_KP, CTRL_KI, CTRL_LIMIT, CTRL_DITHER_V, CTRL_DITHER_HZ, CTRL_EVERY, CTRL_HYSTERESIS = range(8)
N_CTRL = 8


@jit
def rk4_step(y, u, c, h, k):
    """One classical Runge-Kutta step of h [s] on ``y`` (N_STATE,) in place, input u held;
    ``k`` (5, N_STATE) is scratch (four stages and the stage state)."""
    n = N_STATE
    derivatives(y, u, c, k[0])
    for stage in range(1, 4):
        frac = 1.0 if stage == 3 else 0.5
        for j in range(n):
            k[4, j] = y[j] + frac * h * k[stage - 1, j]
        derivatives(k[4], u, c, k[stage])
    for j in range(n):
        y[j] += h / 6.0 * (k[0, j] + 2.0 * k[1, j] + 2.0 * k[2, j] + k[3, j])


@jit
def controller(theta_count, x_ref, integral, t, ctrl, enc, period):
    """The lab's position controller at one sample: (u [V], the new integral [m s]).

    The position is the encoder's angle ``theta_count`` [rad] through Eq. (3) with the lab's
    lengths; ``u = kp e + ki integral(e) + dither``, saturated at the limit; the integral grows
    only while that leaves the output unsaturated (anti-windup). ``period`` [s] between samples."""
    x_meas = piston_position(theta_count, enc[ENC_L1], enc[ENC_L2], enc[ENC_L3])
    e = x_ref - x_meas
    limit = ctrl[CTRL_LIMIT]
    if abs(ctrl[CTRL_KP] * e + ctrl[CTRL_KI] * (integral + e * period)) <= limit:
        integral += e * period
    u = ctrl[CTRL_KP] * e + ctrl[CTRL_KI] * integral
    u += ctrl[CTRL_DITHER_V] * math.sin(2.0 * math.pi * ctrl[CTRL_DITHER_HZ] * t)
    return min(max(u, -limit), limit), integral


@jit
def play(u, held, width):
    """A play (backlash) of ``width`` [V] between the command u and what the valve follows:
    the output moves only once the command pulls it by half the width."""
    return min(max(held, u - 0.5 * width), u + 0.5 * width)


@jit
def run(y, c, u_open, tv_idx, tv, setpoint, ctrl, enc, h, sub, dt, record_every, out, u_log):
    """Advance the rig over len(u_open) samples of dt [s], each in ``sub`` RK4 steps of h [s].

    y (N_STATE,): the initial state, advanced in place. c (N_CONSTANTS,): the machine; its
    entries ``tv_idx`` (m,) follow ``tv`` (m, n) sample by sample. u_open (n,) [V]: the open-loop
    input (unused in closed loop). setpoint (n,) [m]. ctrl (N_CTRL,): closed (1/0), kp [V/m],
    ki [V/(m s)], the output limit [V], dither [V] and [Hz], samples per controller period, the
    valve's hysteresis [V]. enc: the encoder (see ENC_*). out (n_rec, len(CHANNELS)): the true
    quantities at samples 0, record_every, ... (:func:`rig.model.observe`). u_log (n,): the
    command over each sample [V].
    """
    n = u_open.shape[0]
    k = np.empty((5, N_STATE))
    integral, u_cmd, u_valve = 0.0, 0.0, 0.0
    w_prev = 0.0
    closed = ctrl[CTRL_CLOSED] != 0.0
    every = int(ctrl[CTRL_EVERY])
    t_ctrl = every * dt  # the controller's period [s]
    threshold = c[C.omega_n] ** 2 * c[C.stiction]
    c[C.spool_stuck] = 1.0 if threshold > 0.0 else 0.0  # a spool at rest sticks
    for i in range(n + 1):
        if i % record_every == 0:
            observe(y, c, out[i // record_every])
        if i == n:
            break
        for j in range(tv_idx.shape[0]):
            c[tv_idx[j]] = tv[j, i]
        if closed:
            if i % every == 0:
                u_cmd, integral = controller(encoder_reading(y[R.theta], enc), setpoint[i], integral, i * dt,
                                             ctrl, enc, t_ctrl)
        else:
            u_cmd = u_open[i]
        u_log[i] = u_cmd
        u_valve = play(u_cmd, u_valve, ctrl[CTRL_HYSTERESIS])
        for _ in range(sub):
            if threshold > 0.0:  # a sticking spool: stick as it stops, break free when pulled hard enough
                pull = abs(spool_pull(y[R.x_s], u_valve, c))
                if c[C.spool_stuck] != 0.0 and pull > threshold:
                    c[C.spool_stuck] = 0.0
                elif c[C.spool_stuck] == 0.0 and y[R.w_s] * w_prev < 0.0 and pull <= threshold:
                    c[C.spool_stuck] = 1.0
                    y[R.w_s] = 0.0
                w_prev = y[R.w_s]
            rk4_step(y, u_valve, c, h, k)


