"""Simulate a recording with many candidate parameter sets at once.

The recording is cut into segments (1 s by default); each segment is simulated
from the measured state at its start (pressures, position, velocity from the
smoothed recording; spool from the model's own spool dynamics) with the
recorded input. All segments of all candidates form one batch of
:func:`sam.simulate_batch`, so a finite-difference Jacobian or a grid of
starting values costs one compiled call. Segments keep an open-loop integrator
(the piston position) from drifting away over a long recording, which would
otherwise dominate every comparison.

Measurement-side effects (a transmitter lag, a delay of the pressure signals) are applied to the
simulated pressures, never to the model: they are what the transmitters do. The position comes
from an encoder or a linear transducer, which neither lags nor delays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import numba

from sam import P, S, simulate_batch
from sam.measurement import first_order_lag, time_delay
from sam.capability import held_state, jacobian
from sam.dynamics import N_DERIVED, N_STATES, derive, rhs, stroke_ends
from sam.friction import seal_loaded, seal_pressure_rise, stribeck


@numba.njit(cache=True)
def _bristle_for_balance(x0, u0, params, a_meas, z_max):
    """Bristle deflection z that makes the model's acceleration match the measured one at each start state.

    The model's acceleration is affine in z (LuGre), so two evaluations of the model's own
    right-hand side give it; z is kept within the bristles' reach |z| <= z_max.
    """
    n = x0.shape[0]
    d = np.empty(N_DERIVED)
    ds = np.empty(N_STATES)
    s = np.empty(N_STATES)
    for i in range(n):
        derive(params[i], d)
        for j in range(N_STATES):
            s[j] = x0[i, j]
        s[6] = 0.0
        rhs(s, u0[i], params[i], d, ds)
        a0 = ds[5]
        s[6] = 1e-6
        rhs(s, u0[i], params[i], d, ds)
        slope = (ds[5] - a0) / 1e-6
        if slope != 0.0:
            z = (a_meas[i] - a0) / slope
            x0[i, 6] = min(max(z, -z_max[i]), z_max[i])

from .data import Prepared


#: The hydraulic-mechanical states (the spool's modes are driven by the input only and separate).
_MODE = np.array([S.p_A, S.p_B, S.x, S.v, S.z])


def hydraulic_decay_rate(params: np.ndarray, n: int = 5) -> float:
    """1/s: the slowest decay rate -Re(lambda) of the model's hydraulic mode over the stroke, lambda
    the oscillatory eigenvalue of the linearised model (the oil columns against the reduced mass,
    Eq. (20), valve centred, load at rest: :func:`sam.capability.natural_frequency`'s mode) at ``n``
    positions. A start-state error rings with this mode and has decayed by 1/e after 1 / rate."""
    ends = float(stroke_ends(params))
    rates = []
    for x in np.linspace(0.05 * ends, 0.95 * ends, n):
        ev = np.linalg.eigvals(jacobian(params, held_state(params, x))[np.ix_(_MODE, _MODE)])
        ev = ev[np.abs(ev.imag) > 1e-6 * np.abs(ev)]
        if ev.size:
            rates.append(-float(np.max(ev.real)))
    return max(min(rates), 1e-3) if rates else 1.0

SIGNALS = ("pA", "pB", "x")
#: The signals the measurement-side parameters act on: the pressure transmitters.
TRANSMITTED = ("pA", "pB")
#: Measurement-side parameters: not plant parameters, applied to the simulated pressures.
MEAS_PARAMS = ("tau_sensor", "delay_sensor")
#: Steps of the start state for :meth:`SegmentSimulator.settled_states`' finite differences (Pa, Pa, m/s, m):
#: small against the transmitters' and the velocity estimate's errors, large against round-off.
START_STEP = {"pA": 1e4, "pB": 1e4, "v": 1e-3, "z": 1e-6}
#: Floors of the per-signal scales (a signal that barely moves is weighted by its noise, not by zero).
SCALE_FLOOR = {"pA": 1e5, "pB": 1e5, "x": 2e-3}


@dataclass
class Segments:
    starts: np.ndarray  # sample index of each segment start
    length: int  # samples per segment
    held_out: np.ndarray  # bool per segment
    eval_idx: np.ndarray  # sample offsets within a segment that enter residuals


class SegmentSimulator:
    """Simulates :class:`Prepared` data segment by segment for batches of parameter vectors."""

    def __init__(self, data: Prepared, seg_s: float = 1.0, skip_s: float = 0.03, max_eval: int = 5000,
                 held_out_every: int = 3, all_held_out: bool = False, scheme: str = "heun"):
        self.data = data
        self.scheme = scheme
        n = data.n
        L = max(10, int(round(seg_s / data.dt)))
        n_seg = max(1, n // L)
        if n_seg < 3 and not all_held_out:
            L = n // 3
            n_seg = 3
        starts = np.arange(n_seg) * L
        if all_held_out:
            held = np.ones(n_seg, bool)
        else:
            held = (np.arange(n_seg) % held_out_every) == held_out_every - 1
        skip = min(L // 4, int(round(skip_s / data.dt)))
        total = n_seg * (L - skip)
        stride = max(1, int(np.ceil(total / max_eval)))
        self.seg = Segments(starts, L, held, np.arange(skip, L, stride))
        self.scale = {
            k: max(float(np.std(data.y[k])), SCALE_FLOOR[k]) for k in SIGNALS
        }
        # measured signals at the evaluation points: (n_seg, n_eval)
        idx = self.sample_index()
        self.meas = {k: data.y[k][idx] for k in SIGNALS}
        self.mask = {k: data.scored[k][idx] for k in SIGNALS}
        # input per segment, with sub-steps
        uu = np.stack([data.u[s:s + L] for s in starts])
        self.u_seg = np.repeat(uu, data.n_sub, axis=1)
        self.record_at = np.arange(0, L * data.n_sub, data.n_sub)

    # ------------------------------------------------------------------ helpers
    def sample_index(self) -> np.ndarray:
        """(n_seg, n_eval) sample indices of the evaluation points."""
        return self.seg.starts[:, None] + self.seg.eval_idx[None, :]

    def segment_mask(self, part: str) -> np.ndarray:
        if part == "fit":
            return ~self.seg.held_out
        if part == "held":
            return self.seg.held_out
        return np.ones_like(self.seg.held_out)

    def _measured_start(self, meas: np.ndarray | None, m: int) -> dict[str, np.ndarray]:
        """Smoothed measured pA, pB, x, v, a at each segment start, (m * n_seg,) each.

        Under a measurement-side hypothesis the measured pressure at the start is not the state: with a
        delay d the state at t is what the transmitters show at t + d; with a first-order lag tau it is
        y_m + tau dy_m/dt. Starting each segment from the state the hypothesis implies keeps the segment
        start-up from being mistaken for (or credited to) another effect.
        """
        d, st = self.data, self.seg.starts
        sm = d.smooth
        keys = ("pA", "pB", "x", "v", "a")
        if meas is None or not np.any(meas):
            return {k: np.tile(sm[k][st], m) for k in keys}
        idx = np.arange(d.n, dtype=float)
        out = {k: np.tile(sm[k][st], (m, 1)) for k in keys}
        rates = {"pA": "dpA", "pB": "dpB"}
        for i in range(m):
            tau, delay = meas[i]
            pos = np.minimum(st + max(delay, 0.0) / d.dt, d.n - 1)
            for k in TRANSMITTED:
                val = np.interp(pos, idx, sm[k])
                if tau > 0:
                    val = val + tau * np.interp(pos, idx, sm[rates[k]])
                out[k][i] = val
        return {k: v.reshape(-1) for k, v in out.items()}

    def initial_states(self, params: np.ndarray, meas: np.ndarray | None = None) -> np.ndarray:
        """(m * n_seg, 7) initial states for m parameter vectors (and measurement-side settings)."""
        d, st = self.data, self.seg.starts
        m = params.shape[0]
        ms = self._measured_start(meas, m)
        x0 = np.zeros((m * len(st), 7))
        x0[:, S.p_A] = ms["pA"]
        x0[:, S.p_B] = ms["pB"]
        x0[:, S.x] = ms["x"]
        x0[:, S.v] = ms["v"]
        x0[:, S.x_s] = np.tile(d.x_s[st], m)
        x0[:, S.dx_s] = np.tile(d.dx_s[st], m)
        # bristle deflection at its steady state for the segment's velocity
        pr = np.repeat(params, len(st), axis=0)
        v = x0[:, S.v]
        pA0, pB0 = x0[:, S.p_A], x0[:, S.p_B]
        rise = seal_pressure_rise(pA0, pB0, pr[:, P.k_fric_dp], pr[:, P.k_fric_rod])  # the model's friction levels
        FC = seal_loaded(pr[:, P.F_C] + rise, pA0, pB0, pr[:, P.k_fric_p])
        FS = seal_loaded(pr[:, P.F_S] + rise, pA0, pB0, pr[:, P.k_fric_p])
        g = stribeck(v, FC, FS, pr[:, P.v_s])
        x0[:, S.z] = np.sign(v) * g / pr[:, P.sigma_0]
        # where the piston is (nearly) still the bristles hold whatever the force balance needs
        still = np.abs(v) < 5 * pr[:, P.v_s]
        if np.any(still):
            a = ms["a"]
            u0 = np.tile(d.u[st], m)
            z_max = np.maximum(FC, FS) / pr[:, P.sigma_0]
            xs = np.ascontiguousarray(x0[still])
            _bristle_for_balance(xs, np.ascontiguousarray(u0[still]), np.ascontiguousarray(pr[still]),
                                 np.ascontiguousarray(a[still]), np.ascontiguousarray(z_max[still]))
            x0[still] = xs
        return x0

    # ------------------------------------------------------------------ simulate
    def simulate(self, params: np.ndarray, meas: np.ndarray | None = None, *, full: bool = False,
                 time_varying: dict[str, np.ndarray] | None = None,
                 channels: tuple[str, ...] = ("p_A", "p_B", "x"), settle: float = 0.0) -> dict[str, np.ndarray]:
        """Simulated signals for m parameter vectors.

        Args:
            params: (m, len(P)).
            meas: (m, 2) sensor lag tau [s] and delay [s] per candidate, or None.
            full: return every sample of each segment rather than the evaluation points.
            time_varying: name -> (m, n_samples) values on the recording's sample grid.
            settle: 0, or the decay times of the model's hydraulic mode over which each segment's start
                state is estimated under ``params`` (:meth:`settled_states`).
        Returns: signal -> (m, n_seg, n_eval or L).
        """
        params = np.atleast_2d(params)
        x0 = self.initial_states(params, meas)
        if settle > 0.0:
            x0 = self.settled_states(params, meas, x0, settle, time_varying)
        out = self._run(params, meas, x0, self.seg.length, time_varying, channels)
        return out if full else {k: y[:, :, self.seg.eval_idx] for k, y in out.items()}

    def settled_states(self, params: np.ndarray, meas: np.ndarray | None, x0: np.ndarray, decay_times: float,
                       time_varying: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """(m * n_seg, 7) start states consistent with each parameter vector: the measured start ``x0``
        corrected in p_A, p_B, v and the bristle deflection z (LuGre, Eq. (17)) by one Gauss-Newton step of the segment's weighted error over its
        first ``decay_times`` / sigma seconds, sigma [1/s] the decay rate of the model's hydraulic mode
        (:func:`hydraulic_decay_rate`, its slowest over the stroke).

        A start state a few kPa or mm/s off, or a start in stick-slip whose bristles hold another force
        than the measured acceleration says, rings the lightly damped hydraulic mode for about 1 / sigma,
        and differently under each hypothesis (entrained air softens the oil spring); estimating it
        under each model, as system identification's model comparisons estimate initial conditions,
        keeps that ringing from being scored as the model's error. Its effect has decayed after the
        window, so the estimate cannot absorb what a parameter does over the rest of the segment.
        """
        m, n_seg = params.shape[0], len(self.seg.starts)
        sigma = min(hydraulic_decay_rate(p) for p in params)
        W = int(min(self.seg.length, max(10, round(decay_times / sigma / self.data.dt))))
        # the window is scored from the start's own sample (the scoring skips the first samples: they are the
        # start's, and here the start is what is estimated), at the scoring's stride
        stride = int(self.seg.eval_idx[1] - self.seg.eval_idx[0]) if self.seg.eval_idx.size > 1 else 1
        ev = np.arange(0, W, stride)
        idx = self.seg.starts[:, None] + ev[None, :]
        meas_w = {k: self.data.y[k][idx] for k in SIGNALS}
        mask_w = {k: self.data.scored[k][idx] & self.mask[k].any(axis=1)[:, None] for k in SIGNALS}
        steps = ((S.p_A, START_STEP["pA"]), (S.p_B, START_STEP["pB"]), (S.v, START_STEP["v"]), (S.z, START_STEP["z"]))
        X = np.concatenate([x0] + [x0 + np.eye(7)[j] * h for j, h in steps])
        k = len(steps) + 1
        tv = {n: np.tile(np.atleast_2d(v), (k, 1)) for n, v in time_varying.items()} if time_varying else None
        out = self._run(np.tile(params, (k, 1)), None if meas is None else np.tile(meas, (k, 1)), X, W, tv,
                        ("p_A", "p_B", "x"))

        def window_residual(out):  # (k', m, n_seg, N) weighted residuals over the window
            r = np.concatenate([np.where(mask_w[s][None], (out[s][:, :, ev] - meas_w[s][None]) / self.scale[s], 0.0)
                                for s in SIGNALS], axis=2)
            return np.nan_to_num(r.reshape(-1, m, n_seg, r.shape[-1]), nan=1e3, posinf=1e3, neginf=-1e3)

        r = window_residual(out)
        r0 = r[0]
        J = (r[1:] - r[:1]) / np.array([h for _, h in steps])[:, None, None, None]  # (4, m, n_seg, N)
        # the measured start is one more observation of each chamber pressure (one sample's weight): where the
        # window cannot see a pressure (a chamber at tank, not scored) the estimate stays at the measurement
        A = np.einsum("imsn,jmsn->msij", J, J) + np.diag([1 / self.scale["pA"] ** 2, 1 / self.scale["pB"] ** 2, 0.0, 0.0])
        b = -np.einsum("imsn,msn->msi", J, r0)
        delta = np.zeros((m, n_seg, len(steps)))
        for i in range(m):
            for s in range(n_seg):
                d = np.sqrt(A[i, s].diagonal())
                if np.all(d > 0):  # Jacobi-scaled least-norm solve of the normal equations
                    delta[i, s] = np.linalg.lstsq(A[i, s] / np.outer(d, d), b[i, s] / d, rcond=1e-8)[0] / d
        # the model is not linear in its start (stick-slip, a valve edge): the full step and a quarter of it
        # are tried, and each segment keeps whichever of them and the measured start fits its window best
        tries = [x0] + [self._moved(x0, f * delta, steps) for f in (1.0, 0.25)]
        tv = {n: np.tile(np.atleast_2d(v), (2, 1)) for n, v in time_varying.items()} if time_varying else None
        out = self._run(np.tile(params, (2, 1)), None if meas is None else np.tile(meas, (2, 1)),
                        np.concatenate(tries[1:]), W, tv, ("p_A", "p_B", "x"))
        cost = np.sum(np.concatenate([r0[None], window_residual(out)]) ** 2, axis=-1)  # (3, m, n_seg)
        best = np.argmin(cost, axis=0).reshape(-1)
        return np.stack(tries)[best, np.arange(m * n_seg)]

    @staticmethod
    def _moved(x0: np.ndarray, delta: np.ndarray, steps) -> np.ndarray:
        """x0 moved by ``delta`` (m, n_seg, len(steps)) in the states of ``steps``; pressures kept >= 0."""
        x1 = x0.copy()
        for c, (j, _) in enumerate(steps):
            x1[:, j] += delta[..., c].reshape(-1)
        x1[:, S.p_A] = np.maximum(x1[:, S.p_A], 0.0)
        x1[:, S.p_B] = np.maximum(x1[:, S.p_B], 0.0)
        return x1

    def _run(self, params: np.ndarray, meas: np.ndarray | None, x0: np.ndarray, L: int,
             time_varying: dict[str, np.ndarray] | None, channels: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Every sample of the first L of each segment from the start states x0: signal -> (m, n_seg, L)."""
        m = params.shape[0]
        n_seg = len(self.seg.starts)
        P_all = np.repeat(params, n_seg, axis=0)
        u = np.tile(self.u_seg[:, :L * self.data.n_sub], (m, 1))
        tv = None
        if time_varying:
            tv = {}
            for k, vals in time_varying.items():
                vals = np.atleast_2d(vals)
                segs = np.stack([vals[:, s:s + L] for s in self.seg.starts], axis=1)  # (m', n_seg, L)
                segs = np.broadcast_to(segs, (m, n_seg, L)).reshape(m * n_seg, L)
                tv[k] = np.repeat(segs, self.data.n_sub, axis=1)
        res = simulate_batch(P_all, u, self.data.dt / self.data.n_sub, x0=x0, time_varying=tv,
                             record_at=self.record_at[:L], channels=channels, scheme=self.scheme)
        out = {}
        names = {"p_A": "pA", "p_B": "pB", "x": "x"}
        for ch in channels:
            y = res[ch].reshape(m, n_seg, L)
            key = names.get(ch, ch)
            if meas is not None and key in TRANSMITTED:
                y = y.copy()
                for i in range(m):
                    tau, delay = meas[i]
                    if tau > 0:
                        y0 = y[i][:, :1].copy()
                        y[i] = first_order_lag(y[i], self.data.dt, tau)
                        # the sensor starts where the measurement is, not at the state (superposition of
                        # the filter's initial-condition response)
                        m0 = self.data.smooth[key][self.seg.starts][:, None]
                        y[i] += (m0 - y0) * np.exp(-np.arange(L) * self.data.dt / tau)[None, :]
                    if delay > 0:
                        y[i] = time_delay(y[i], self.data.dt, delay)
            out[key] = y
        self.last_cavitated = res.cavitated.reshape(m, n_seg).any(axis=1)
        return out

    def unscore(self, segments: np.ndarray) -> None:
        """Score nothing of these segments (bool, (n_seg,)): their error is not the model's."""
        for k in SIGNALS:
            self.mask[k][segments, :] = False

    # ------------------------------------------------------------------ residuals
    def residuals(self, sim: dict[str, np.ndarray], part: str = "fit") -> np.ndarray:
        """Weighted residuals (m, n_res): (simulated - measured) / scale, stacked over signals."""
        segs = self.segment_mask(part)
        parts = []
        for k in SIGNALS:
            r = (sim[k][:, segs, :] - self.meas[k][None, segs, :]) / self.scale[k]
            r = np.where(self.mask[k][None, segs, :], r, 0.0)
            parts.append(r.reshape(r.shape[0], -1))
        return np.concatenate(parts, axis=1)


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """MATLAB's NRMSE fit: 100 (1 - ||y - yhat|| / ||y - mean(y)||)."""
    y, yhat = np.ravel(y), np.ravel(yhat)
    den = np.linalg.norm(y - y.mean())
    if den == 0:
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den))


def fits(simulator: SegmentSimulator, sim: dict[str, np.ndarray], part: str, i: int = 0) -> dict[str, float]:
    """Per-signal fit % of candidate i on a part ('fit', 'held', 'all')."""
    segs = simulator.segment_mask(part)
    out = {}
    for k in SIGNALS:
        msk = simulator.mask[k][segs]
        out[k] = fit_percent(simulator.meas[k][segs][msk], sim[k][i][segs][msk])
    out["mean"] = float(np.mean([out[k] for k in SIGNALS]))
    return out
