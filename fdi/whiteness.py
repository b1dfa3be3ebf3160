"""How many independent samples a log-likelihood ratio holds: the evidence's honest size.

The bank's evidence (:mod:`fdi.bank`) sums the innovation log-likelihood log N(nu_k; 0, S_k)
over a window as if every sample were independent, which holds for a filter whose model is the
one that made the data (its innovations are then white, and so are the increments
d_k = l_H,k - l_G,k of the ratio of two hypotheses H and G). Where the model's *form* errs (a
flow law, a stop, a band edge the model draws otherwise), the increments are coloured, and the
summed ratio grows like the window's length with nothing real behind it. Its honest size is the
composite-likelihood one: the ratio divided by the variance inflation of its increments (the
magnitude adjustment of a misspecified likelihood, whose summed score has tau times the
variance of independent increments),

    tau = 1 + 2 sum_{j=1}^{M} (1 - j / (M + 1)) rho_j,     rho_j = sum_t (d_t - m)(d_{t-j} - m) / sum_t (d_t - m)^2,

the integrated autocorrelation time of d with Bartlett weights up to lag M (Newey-West), m the
increments' mean (a fault's steady gain is the signal, not colour). Independent increments give
tau ~ 1 (the evidence is unchanged), an AR(1) sequence of coefficient r gives (1 + r) / (1 - r)
for M well beyond its correlation length. Only the colour beyond what independent increments
show by chance counts (``z`` standard deviations of the estimate, :func:`white_spread`).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def bartlett(max_lag: int) -> np.ndarray:
    """(max_lag,) the Bartlett weights w_j = 1 - j / (M + 1), j = 1..M."""
    return 1.0 - np.arange(1, max_lag + 1) / (max_lag + 1.0)


def running_iat(x: np.ndarray, max_lag: int) -> np.ndarray:
    """Causal Bartlett-weighted integrated autocorrelation time of ``x`` (..., L) along its last
    axis, about its mean (the formula of the module docstring): element k uses x[..., :k + 1]
    only, with the mean of those. The lag products sum_t x_t sum_j w_j x_{t-j} are one FIR
    filter, so the cost is O(L M) in compiled code. NaN counts as 0. Shape (..., L); 1 where
    there is no variance yet."""
    x = np.nan_to_num(np.asarray(x, dtype=float))
    if max_lag <= 0:
        return np.ones_like(x)
    b = np.r_[0.0, bartlett(max_lag)]
    lagged = lfilter(b, 1.0, x, axis=-1)  # y_t = sum_{j <= min(M, t)} w_j x_{t-j}
    weights = lfilter(b, 1.0, np.ones(x.shape[-1]))  # c_t = sum_{j <= min(M, t)} w_j
    n = np.arange(1, x.shape[-1] + 1)
    m = np.cumsum(x, axis=-1) / n
    # sum_t sum_j w_j (x_t - m)(x_{t-j} - m) = C - m (Y + G) + m^2 W, from running sums
    lag_sum = (np.cumsum(x * lagged, axis=-1) - m * (np.cumsum(lagged, axis=-1) + np.cumsum(x * weights, axis=-1))
               + m * m * np.cumsum(weights))
    var_sum = np.cumsum(x * x, axis=-1) - n * m * m
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = 1.0 + 2.0 * lag_sum / var_sum
    return np.where(var_sum > 1e-12 * np.maximum(np.cumsum(x * x, axis=-1), 1e-300), tau, 1.0)


def white_spread(n, max_lag: int):
    """The standard deviation of :func:`running_iat` of n independent samples (n large against
    the lag window): 2 sqrt(sum_j w_j^2 / n), each rho_j then having variance 1 / n."""
    return 2.0 * np.sqrt(np.sum(bartlett(max_lag) ** 2) / np.maximum(n, 1))


def evidence_factor(evidence: np.ndarray, max_lag: int, z: float) -> np.ndarray:
    """(..., L) the factor a cumulative log-likelihood ratio ``evidence`` (..., L) [nats] is
    divided by at each sample: the :func:`running_iat` of its increments less ``z`` times
    :func:`white_spread`, at least 1 (anti-correlated increments add no evidence; at most
    1 + max_lag); 1 everywhere for max_lag 0."""
    if max_lag <= 0:
        return np.ones(np.shape(evidence))
    d = np.diff(np.nan_to_num(evidence), axis=-1, prepend=0.0)
    n = np.arange(1, d.shape[-1] + 1)
    return np.maximum(running_iat(d, max_lag) - z * white_spread(n, max_lag), 1.0)
