"""Unknown-input estimation for the generic route: the UKF of :mod:`fdi` with disturbance states.

The filter (``fdi.run_filter``, sigma points through ``sam.step_batch``, the
calibrated plant vector) estimates three unknown inputs as random-walk states:
a disturbance flow into chamber A (``Q_dA``) and B (``Q_dB``) [m^3/s] and a
disturbance force on the piston (``F_d``) [N]. The leak-fault and offset states
are pinned (zero walk, tiny prior) so that they cannot take a flow instead.

Time alignment. A filtered random walk lags what it tracks: for a random-walk
state with walk density q [unit/sqrt(s)] and posterior std s(t), the filter acts
on it like a first-order low-pass of time constant tau(t) = s(t)^2 / q^2
(the steady-state scalar Kalman filter). Measured on the outside_library case
(K_extA = 4e-9, nominal plant): tau(t) has a median of 11 ms and the best
constant lag of the truth against the estimate is 10 ms; the residual of the
estimate against the truth lagged by tau(t) is the smallest of all lags tried
(0.1057 L/min rms against 0.1062 unlagged and 0.110 at 80 ms). For fast features it
matters: a concealed F_d = 3000 v + 1500 tanh(v / 2 mm) (nominal plant; F_d's tau
median 23 ms) regressed on v and tanh(v / 2 mm) gives, over seeds 31-33 at 10 and
20 s, 1415-3003 N s/m and 1511-1592 N with features lagged by tau(t), but
7499-12757 N s/m and 950-1183 N unlagged (seed 31, 20 s, lagged by 2 tau(t): 1952
and 1589). The viscous part stays uncertain (velocity is small most of the time);
the simulation-error re-fit sets the final value. The regression features are therefore passed
through the same time-varying low-pass
(:func:`lag_like_estimate`) rather than the estimate being shifted or smoothed:
a true RTS smoother would need the filter's cross-time covariances, which
``fdi.run_filter`` does not return.

Calibration nuisance. The plant vector passed in is already calibrated on the
recording, and the calibration absorbs part of any missing flow (a leak out of A
looks partly like a spool offset and a smaller notch flow). What the calibration
parameters could still change is expressed as an *equivalent* unknown input
(:func:`calibration_nuisance`, from the model's own ``rhs``: linearised at the
calibrated point and at the box centre, plus the exact move between the two) and
regressed along with every candidate term, so that the sparse regression chooses
terms the calibration cannot explain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from fdi import (
    POS_THETA, CalibrationStates, Constraints, FilterConfig, FilterInput, FormNoise, Sensors, StopRules,
    UnknownInputStates, run_filter,
)
from sam import P, S
from sam.dynamics import N_DERIVED, N_STATES, derive, rhs
from sam.geometry import joint_angle

from .data import Prepared

#: The unknown inputs and their units.
TARGETS = {"Q_dA": "m^3/s", "Q_dB": "m^3/s", "F_d": "N"}
#: Filter state of each unknown input, and the model-state column it drives (dp_A/dt, dp_B/dt, dv/dt).
STATE_COL = {"Q_dA": S.p_A, "Q_dB": S.p_B, "F_d": S.v}
#: Fault states of the filter held fixed (fdi.STATE_NAMES). The calibrated offset is in the plant
#: vector; a free leak state would take a chamber flow.
PINNED_STATES = ("K_int", "K_extA", "K_extB", "offset")
#: Prior std factor of a pinned state (tiny, not zero: the sigma-point covariance must stay positive definite).
PINNED_PRIOR = 1e-6
#: Finite-difference steps of the model's sensitivity to each unknown input (SI; far below any term fitted).
SENS_STEP = {"Q_dA": 1e-6, "Q_dB": 1e-6, "F_d": 100.0}
#: Relative finite-difference step of a calibration parameter's equivalent input (log-scaled
#: parameters), and the absolute one of a linear parameter (spool offset, fraction of travel).
CAL_REL_STEP = 1e-3
CAL_ABS_STEP = 1e-4


@dataclass
class UnknownInputs:
    """The filter's estimates on the recording's sample grid (T samples).

    ``est``/``sd``: mean and posterior std of each unknown input (T,) [SI];
    ``tau``: the effective lag (T,) [s] of each estimate (s^2 / q^2);
    ``states``: the filtered model state (T, 7) (sam.S order), where features are evaluated;
    ``q``: the random-walk density of each input [SI/sqrt(s)].
    """

    dt: float
    est: dict[str, np.ndarray]
    sd: dict[str, np.ndarray]
    tau: dict[str, np.ndarray]
    states: np.ndarray
    q: dict[str, float]


#: The filter settings this route was measured with, spelled out so that it does not follow the FDI
#: defaults (tuned for fault detection, and free to change for it): no calibration states (the plant
#: vector passed in is already calibrated; a random-walk notch flow or B_eff would trade off with Q_dA,
#: Q_dB), plain mean projection of the (pinned) leak states, and the 2e-5 rad encoder noise floor.
# The model's form taken as exact (no FormNoise): the route exists to find where it errs, and
# pressure noise at the null band's edge would let the pressures absorb the very flows it estimates.
# The plant's own end stops (rigid unless its file says otherwise), not the FDI's contact.
ROUTE_FILTER = dict(calibration=CalibrationStates(states=()), constraints=Constraints(projection="leak"),
                    sensors=Sensors(theta_noise_floor=2e-5), form_noise=FormNoise(band_share=0.0, low_share=0.0),
                    stops=StopRules.rigid())


def filter_config(base: FilterConfig | None = None) -> FilterConfig:
    """The fdi filter with Q_dA, Q_dB as unknown-input states and the fault states pinned.

    F_d is already a state of the filter (its walk ``process_noise["F_d"]``, 1e4 N/sqrt(s) by default)."""
    base = base or FilterConfig().with_(**ROUTE_FILTER)
    return (base.with_process_noise(**{s: 0.0 for s in PINNED_STATES})
            .with_initial_sd(**{s: PINNED_PRIOR * base.initial_sd[s] for s in PINNED_STATES})
            .with_(unknown_inputs=UnknownInputStates(states=("Q_dA", "Q_dB"))))


def _walk_density(cfg: FilterConfig) -> dict[str, float]:
    noise = cfg.unknown_inputs.noise
    return {"Q_dA": noise["Q_dA"][1], "Q_dB": noise["Q_dB"][1], "F_d": float(cfg.process_noise["F_d"])}


def filter_input(data: Prepared, params: np.ndarray) -> FilterInput:
    """The recording as one filter run: pressures [Pa] and the joint angle [rad] (NaN where not measured).

    The position goes in as the joint angle (the SAM's encoder; ``Prepared`` holds x converted from it)."""
    theta = joint_angle(data.y["x"], params[P.L_1], params[P.L_2], params[P.L_3])
    pA = np.where(data.valid["pA"], data.y["pA"], np.nan)
    pB = np.where(data.valid["pB"], data.y["pB"], np.nan)
    pos = np.where(data.valid["x"], theta, np.nan)
    return FilterInput(dt=data.dt, u=data.u[None, :], pA=pA[None, :], pB=pB[None, :], pos=pos[None, :],
                       pos_kind=POS_THETA, params=np.asarray(params, float)[None, :])


def estimate_unknown_inputs(data: Prepared, params: np.ndarray, cfg: FilterConfig | None = None) -> UnknownInputs:
    """Run the augmented UKF over the recording with the (calibrated) plant vector ``params`` (len(P),)."""
    cfg = cfg or filter_config()
    out = run_filter(filter_input(data, params), cfg)
    q = _walk_density(cfg)
    est, sd, tau = {}, {}, {}
    for name in TARGETS:
        m, s = out.estimate(name)
        est[name], sd[name] = m[0], s[0]
        tau[name] = s[0] ** 2 / q[name] ** 2
    return UnknownInputs(data.dt, est, sd, tau, out.mean[0, :, :N_STATES].copy(), q)


@numba.njit(cache=True)
def lag_like_estimate(y, tau, dt):
    """First-order causal low-pass of y (T,) with a time-varying time constant tau (T,) [s]."""
    out = np.empty_like(y)
    s = y[0]
    for k in range(y.shape[0]):
        a = dt / (tau[k] + dt)
        s += a * (y[k] - s)
        out[k] = s
    return out


@numba.njit(cache=True)
def model_rate(states, u, p, col):
    """d state[col]/dt (T,) of the model (:func:`sam.dynamics.rhs`) at each state (T, 7), input u (T,) [V]."""
    d = np.empty(N_DERIVED)
    derive(p, d)
    ds = np.empty(N_STATES)
    out = np.empty(states.shape[0])
    for k in range(states.shape[0]):
        rhs(states[k], u[k], p, d, ds)
        out[k] = ds[col]
    return out


def _rate_changes(states, u, p, q, col):
    """Change of d state[col]/dt (T,) between parameter vectors p and q at each state (T, 7)."""
    return model_rate(states, u, q, col) - model_rate(states, u, p, col)


def _changed(params: np.ndarray, name: str, step: float) -> np.ndarray:
    q = params.copy()
    q[P[name]] += step
    return q


def input_sensitivity(states: np.ndarray, u: np.ndarray, params: np.ndarray, target: str) -> np.ndarray:
    """d(state rate)/d(unknown input) (T,) at each state: 1/C_A for Q_dA [Pa/m^3], -1/m_red for F_d, ..."""
    step = SENS_STEP[target]
    return _rate_changes(states, u, params, _changed(params, target, step), STATE_COL[target]) / step


def calibration_equivalents(states: np.ndarray, u: np.ndarray, params: np.ndarray, names, linear,
                            target: str, sens: np.ndarray) -> np.ndarray:
    """(T, len(names)) unknown input ``target`` equivalent to a unit step of each calibration parameter.

    ``linear[i]``: the parameter is scaled linearly (step CAL_ABS_STEP), else relatively (CAL_REL_STEP).
    Columns are per unit of the step, so only their span matters to a regression."""
    cols = []
    safe = np.where(sens == 0, 1.0, sens)
    for name, lin in zip(names, linear):
        step = CAL_ABS_STEP if lin else CAL_REL_STEP * params[P[name]]
        d = _rate_changes(states, u, params, _changed(params, name, step), STATE_COL[target])
        cols.append(np.where(sens == 0, 0.0, d / safe))
    return np.column_stack(cols) if cols else np.zeros((len(u), 0))


def box_centre(params: np.ndarray, calib) -> np.ndarray:
    """``params`` with every calibration parameter at the centre of its box (log-centre when log-scaled).

    ``library.calibration_params`` sets the boxes around the plant's nominal values (Q_N: /3..x3, offset
    +-0.05: centre = nominal; B_eff /5..x4: centre 0.89 x nominal, and the pressure rate is linear in it)."""
    ref = np.asarray(params, float).copy()
    for f in calib:
        if f.name in P.__members__:
            ref[P[f.name]] = f.to_value(0.5 * (f.theta_bounds[0] + f.theta_bounds[1]))
    return ref


def calibration_nuisance(states: np.ndarray, u: np.ndarray, params: np.ndarray, calib, target: str,
                         sens: np.ndarray) -> np.ndarray:
    """(T, 2 k + 1) what the calibration could still absorb, as equivalent unknown inputs ``target``.

    The calibration may have moved far to absorb part of an effect (a leak out of A looks partly like
    a spool offset of a few %), and the valve flow is not linear in the offset near null: a linearisation
    at the calibrated point alone predicted the change of the estimates between the calibrated and the
    nominal plant with a correlation of only 0.45-0.80 (outside_lam_leak_B), while the exact change of
    the model's rate predicted it to 0.99-1.00. So the columns are: the linear equivalents at the
    calibrated point, the same at the box centre (:func:`box_centre`), and the exact equivalent of the
    whole move from the calibrated point to the box centre."""
    names = [f.name for f in calib if f.name in P.__members__]
    linear = [not f.log for f in calib if f.name in P.__members__]
    ref = box_centre(params, calib)
    safe = np.where(sens == 0, 1.0, sens)
    shift = np.where(sens == 0, 0.0, _rate_changes(states, u, params, ref, STATE_COL[target]) / safe)
    return np.column_stack([calibration_equivalents(states, u, params, names, linear, target, sens),
                            calibration_equivalents(states, u, ref, names, linear, target, sens), shift])


# ---------------------------------------------------------------- sparse regression


#: Relative singular-value floor of the nuisance basis: the calibration columns at the calibrated point
#: and at the box centre are nearly collinear, and F_d's are zero.
NUISANCE_RANK_TOL = 1e-9


def _orthonormal_basis(X: np.ndarray) -> np.ndarray:
    """(n, r) orthonormal basis of the column space of X (n, k), rank-revealing (SVD)."""
    if X.shape[1] == 0:
        return np.zeros((X.shape[0], 0))
    U, sv, _ = np.linalg.svd(X, full_matrices=False)
    return U[:, sv > NUISANCE_RANK_TOL * max(float(sv[0]), 1e-300)]


def _residual_of(B: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Y (n,) or (n, m) with its projection on the orthonormal basis B (n, r) removed."""
    return Y - B @ (B.T @ Y)


@dataclass
class Regression:
    """Sparse regression of one unknown input on candidate terms, the calibration nuisance included.

    ``single``: per candidate name, (delta BIC of adding it alone, its coefficient [SI per feature unit]);
    ``selected``: the BIC-best forward selection, [(name, coefficient)]; ``n_eff``: effective samples
    of the selected model's residual."""

    target: str
    single: dict[str, tuple[float, float]]
    selected: list[tuple[str, float]]
    n_eff: float


def estimate_n_eff(n: int, step_s: float, tau: np.ndarray) -> float:
    """Effective independent samples of n estimates taken every step_s [s]: a first-order low-pass of
    time constant tau has an integrated autocorrelation time of 2 tau, so n_eff = n step_s / (2 tau)."""
    return float(max(min(n, n * step_s / (2.0 * float(np.median(tau)))), 10.0))


def sparse_regression(target: str, y: np.ndarray, w: np.ndarray, feats: dict[str, np.ndarray],
                      nuisance: np.ndarray, max_terms: int, bic_strong: float, n_eff: float) -> Regression:
    """Weighted forward selection of terms for ``y`` (n,) [SI], weights w (n,) = 1/std.

    The nuisance columns (n, k) are always in the model (and the penalty of all candidates alike): they
    are projected out once, and every candidate is judged in what is left (Frisch-Waugh-Lovell: the same
    coefficients as one least-squares fit with the nuisance, at a fraction of the cost: 144 lstsq calls
    took 4.9 s on the shared machine). A term enters only while it lowers the BIC (with ``n_eff``
    effective samples) by more than ``bic_strong``. n_eff comes from the filter's lag
    (:func:`estimate_n_eff`), not from a residual: taken from the nuisance-only residual it under-rated
    the one input that carries the effect (outside_library: n_eff 50 for Q_dA, whose residual holds the
    leak, against 2100 for Q_dB, so a spurious Q_dB term ranked first), and taken from each candidate's
    own residual no term passed."""
    names = [k for k, v in feats.items() if np.any(v != 0)]
    if not names:
        return Regression(target, {}, [], n_eff)
    V = np.column_stack([feats[k] * w for k in names])
    norms = np.linalg.norm(V, axis=0)
    B = _orthonormal_basis(nuisance * w[:, None])
    r0 = _residual_of(B, y * w)
    Vp = _residual_of(B, V)
    rss0 = float(r0 @ r0)

    def dbic(rss, k):
        return n_eff * math.log(max(rss, 1e-300) / max(rss0, 1e-300)) + k * math.log(n_eff)

    vv = np.sum(Vp * Vp, axis=0)
    ok = vv > NUISANCE_RANK_TOL * norms ** 2
    vr = Vp.T @ r0
    single = {}
    for j, k in enumerate(names):
        if ok[j]:
            single[k] = (dbic(rss0 - vr[j] ** 2 / vv[j], 1), float(vr[j] / vv[j]))
    chosen: list[int] = []
    best: tuple[float, list] = (0.0, [])
    r, W = r0.copy(), Vp.copy()
    for _ in range(max_terms):
        ww = np.sum(W * W, axis=0)
        gain = np.where(ok & (ww > NUISANCE_RANK_TOL * norms ** 2), (W.T @ r) ** 2 / np.where(ww > 0, ww, 1), -1.0)
        gain[chosen] = -1.0
        j = int(np.argmax(gain))
        if gain[j] <= 0:
            break
        chosen.append(j)
        q = W[:, j] / math.sqrt(ww[j])
        r = r - q * (q @ r)
        W = W - np.outer(q, q @ W)
        d = dbic(float(r @ r), len(chosen))
        if d >= best[0] - bic_strong:
            break
        X = Vp[:, chosen]
        c, *_ = np.linalg.lstsq(X, r0, rcond=None)
        best = (d, [(names[i], float(ci)) for i, ci in zip(chosen, c)])
    return Regression(target, single, best[1], n_eff)
