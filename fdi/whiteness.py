"""How many independent samples an innovation sequence holds: the evidence's honest size.

The bank's evidence (:mod:`fdi.bank`) sums log N(nu_k; 0, S_k) over a window as if every
sample were independent, which holds for the innovations of a filter whose model is the one that
made the data (the Kalman innovations are then white). Where the model's *form* errs (a flow
law, a stop, a band edge the model draws otherwise), the innovations of every hypothesis are
coloured, and the summed log-likelihood ratio grows like the window's length with nothing real
behind it. Its honest size is the composite-likelihood one: the sum divided by the variance
inflation of the innovations (the magnitude adjustment of a misspecified likelihood, whose score
has the variance tau times its white value),

    tau = 1 + 2 sum_{j=1}^{M} (1 - j / (M + 1)) rho_j,        rho_j = sum_t nu_t nu_{t-j} / sum_t nu_t^2,

the integrated autocorrelation time with Bartlett weights up to lag M (Newey-West). rho is taken
about zero, not about the window's mean: a mean left in a normalised innovation is model error
too. White innovations give tau ~ 1 (the evidence is unchanged), an AR(1) sequence of
coefficient r gives (1 + r) / (1 - r) for M well beyond its correlation length.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def bartlett(max_lag: int) -> np.ndarray:
    """(max_lag,) the Bartlett weights w_j = 1 - j / (M + 1), j = 1..M."""
    return 1.0 - np.arange(1, max_lag + 1) / (max_lag + 1.0)


def running_iat(nu: np.ndarray, max_lag: int) -> np.ndarray:
    """Causal Bartlett-weighted integrated autocorrelation time of ``nu`` (..., L) along its
    last axis: element k uses nu[..., :k + 1] only (the formula of the module docstring, sums
    up to t = k; the lag products sum_t nu_t sum_j w_j nu_{t-j} as one FIR filter). NaN (not
    measured) counts as 0. Shape (..., L); 1 before any energy."""
    x = np.nan_to_num(np.asarray(nu, dtype=float))
    s0 = np.cumsum(x * x, axis=-1)
    if max_lag <= 0:
        return np.ones_like(x)
    lagged = lfilter(np.r_[0.0, bartlett(max_lag)], 1.0, x, axis=-1)  # sum_j w_j x_{t-j}
    acc = np.cumsum(x * lagged, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = 1.0 + 2.0 * acc / s0
    return np.where(s0 > 0, tau, 1.0)


def white_spread(n: np.ndarray, max_lag: int) -> np.ndarray:
    """The standard deviation of :func:`running_iat` of n white samples (n large against the
    lag window): 2 sqrt(sum_j w_j^2 / n), each rho_j of white noise having variance 1 / n."""
    return 2.0 * np.sqrt(np.sum(bartlett(max_lag) ** 2) / np.maximum(n, 1))


def evidence_factor(nu: np.ndarray, max_lag: int, channels: tuple, z: float) -> np.ndarray:
    """(..., L) the factor a hypothesis' cumulative log-likelihood is divided by, per sample:
    the mean :func:`running_iat` of the innovation ``channels`` (indices into the last axis of
    ``nu`` (..., L, n_channels); the log-likelihood adds their terms), less ``z`` times what
    white innovations show by chance (:func:`white_spread` of that mean): only colour that
    white noise would not show counts. At least 1 (anti-correlated innovations add no
    evidence; at most 1 + max_lag, every rho = 1); 1 everywhere for max_lag 0."""
    if max_lag <= 0:
        return np.ones(nu.shape[:-1])
    tau = np.mean([running_iat(nu[..., c], max_lag) for c in channels], axis=0)
    n = np.cumsum(np.isfinite(nu[..., channels[0]]), axis=-1)
    return np.maximum(tau - z * white_spread(n, max_lag) / np.sqrt(len(channels)), 1.0)
