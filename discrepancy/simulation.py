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
from sam.dynamics import N_DERIVED, N_STATES, derive, rhs
from sam.friction import seal_loaded, stribeck


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

SIGNALS = ("pA", "pB", "x")
#: The signals the measurement-side parameters act on: the pressure transmitters.
TRANSMITTED = ("pA", "pB")
#: Measurement-side parameters: not plant parameters, applied to the simulated pressures.
MEAS_PARAMS = ("tau_sensor", "delay_sensor")
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
        FC = seal_loaded(pr[:, P.F_C], x0[:, S.p_A], x0[:, S.p_B], pr[:, P.k_fric_p])
        FS = seal_loaded(pr[:, P.F_S], x0[:, S.p_A], x0[:, S.p_B], pr[:, P.k_fric_p])
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
                 channels: tuple[str, ...] = ("p_A", "p_B", "x")) -> dict[str, np.ndarray]:
        """Simulated signals for m parameter vectors.

        Args:
            params: (m, len(P)).
            meas: (m, 2) sensor lag tau [s] and delay [s] per candidate, or None.
            full: return every sample of each segment rather than the evaluation points.
            time_varying: name -> (m, n_samples) values on the recording's sample grid.
        Returns: signal -> (m, n_seg, n_eval or L).
        """
        params = np.atleast_2d(params)
        m = params.shape[0]
        n_seg, L = len(self.seg.starts), self.seg.length
        P_all = np.repeat(params, n_seg, axis=0)
        x0 = self.initial_states(params, meas)
        u = np.tile(self.u_seg, (m, 1))
        tv = None
        if time_varying:
            tv = {}
            for k, vals in time_varying.items():
                vals = np.atleast_2d(vals)
                segs = np.stack([vals[:, s:s + L] for s in self.seg.starts], axis=1)  # (m', n_seg, L)
                segs = np.broadcast_to(segs, (m, n_seg, L)).reshape(m * n_seg, L)
                tv[k] = np.repeat(segs, self.data.n_sub, axis=1)
        res = simulate_batch(P_all, u, self.data.dt / self.data.n_sub, x0=x0, time_varying=tv,
                             record_at=self.record_at, channels=channels, scheme=self.scheme)
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
            out[key] = y if full else y[:, :, self.seg.eval_idx]
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
