"""Sigma points and unscented transforms, as filterpy's ``MerweScaledSigmaPoints`` and
``unscented_transform`` compute them, on preallocated work arrays (the filter's loop allocates
nothing). Compiled with numba and inlined into the kernel (:mod:`fdi.kernel`).

All arrays are in the filter's internal units (:mod:`fdi.states`). A filter whose states
``act[:na]`` are free and the rest held (known constants) draws 2 na + 1 points over the free ones.
"""

from __future__ import annotations

import math

import numpy as np

from sam.views import jit_inline

from .states import H_P, I_X, MEAS_SCALE_THETA, MEAS_SCALE_X, POS_X, SCALE


def merwe_weights(n: int, alpha: float, beta: float, kappa: float):
    """Merwe's weights of 2n + 1 sigma points (Wm, Wc) and lambda = alpha^2 (n + kappa) - n."""
    lam = alpha**2 * (n + kappa) - n
    c = 0.5 / (n + lam)
    Wm = np.full(2 * n + 1, c)
    Wc = np.full(2 * n + 1, c)
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + (1.0 - alpha**2 + beta)
    return Wm, Wc, lam


@jit_inline
def cholesky_columns(A, c, L, n, ncol):
    """The first ncol columns of the lower Cholesky factor of c * A[:n, :n] into L[:n, :ncol]
    (above the diagonal 0); False if the leading ncol x ncol block is not positive definite.
    Left-looking: column k needs only the columns before it, and one division per column."""
    for k in range(ncol):
        s = c * A[k, k]
        for q in range(k):
            s -= L[k, q] * L[k, q]
        if not s > 0.0:
            return False
        L[k, k] = math.sqrt(s)
        inv = 1.0 / L[k, k]
        for j in range(k):
            L[j, k] = 0.0
        for j in range(k + 1, n):
            s = c * A[j, k]
            for q in range(k):
                s -= L[j, q] * L[k, q]
            L[j, k] = s * inv
    return True


@jit_inline
def cholesky(A, L, n):
    """Lower Cholesky factor of the leading n x n block of A into L; False if not positive definite."""
    return cholesky_columns(A, 1.0, L, n, n)


@jit_inline
def cholesky_solve(L, b, out, y, n):
    """Solve (L L^T) out = b over the leading n entries; y is work space."""
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * out[k]
        out[i] = s / L[i, i]


@jit_inline
def robust_sqrt(P, c, jitter, L, A, act, na):
    """Cholesky factor of c P[act, act] (the states act[:na]) into L[:na, :na], retried with a
    diagonal jitter growing tenfold from ``jitter`` x the largest variance; returns the number
    of jitter tries (-1: no factor). A is work space."""
    n = na
    if na == P.shape[0]:
        if cholesky_columns(P, c, L, n, n):  # the common case: no copy of c P
            return 0
        for i in range(n):
            for j in range(n):
                A[i, j] = c * P[i, j]
    else:
        for i in range(n):
            for j in range(n):
                A[i, j] = c * P[act[i], act[j]]
        if cholesky(A, L, n):
            return 0
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(A[i, i]))
    if scale == 0.0 or not math.isfinite(scale):
        return -1
    eps = jitter
    for tries in range(1, 12):
        B = A.copy()
        for i in range(n):
            B[i, i] += eps * scale
        if cholesky(B, L, n):
            return tries
        eps *= 10.0
    return -1


@jit_inline
def sigma_points(z, L, act, na, sig):
    """Merwe sigma points z, z + L[:, i], z - L[:, i] into sig[:2 na + 1] (filterpy: sigmas[k+1]
    = x + U[k], U = L^T), over the free states act[:na]; the held states sit at their mean."""
    n = z.shape[0]
    for j in range(n):
        sig[0, j] = z[j]
    if na == n:  # nothing held (act is the identity): the direct loop
        for i in range(n):
            for j in range(n):
                sig[1 + i, j] = z[j] + L[j, i]
                sig[1 + n + i, j] = z[j] - L[j, i]
        return
    for i in range(na):
        for j in range(n):
            sig[1 + i, j] = z[j]
            sig[1 + na + i, j] = z[j]
        for a in range(na):
            sig[1 + i, act[a]] = z[act[a]] + L[a, i]
            sig[1 + na + i, act[a]] = z[act[a]] - L[a, i]


@jit_inline
def position_reading(s_x, pos_kind, L1, L2, L3):
    """Scaled position measurement of the scaled piston state s_x: x, or the joint angle theta
    (Eq. (3) solved for theta with the boom lengths L1, L2, L3)."""
    x = s_x * SCALE[I_X]
    if pos_kind == POS_X:
        return x / MEAS_SCALE_X
    c = (L1 * L1 + L2 * L2 - (x + L3) ** 2) / (2.0 * L1 * L2)
    c = min(1.0, max(-1.0, c))
    return math.acos(c) / MEAS_SCALE_THETA


@jit_inline
def measure(sig, pos_kind, L1, L2, L3, out):
    """Measurement function of one scaled state: [p_A, p_B, x or theta] (scaled). It reads the
    states 0, 1 (linearly, gain H_P) and I_X only: :func:`ut_measurement_closed_form` relies on it."""
    out[0] = sig[0] * H_P
    out[1] = sig[1] * H_P
    out[2] = position_reading(sig[I_X], pos_kind, L1, L2, L3)


@jit_inline
def ut_measurement_closed_form(Pm, z, n_pts, Lc, Wm0, Wc0, wc, pos_kind, L1, L2, L3, zf, Sf, Pf, fp, fm):
    """The unscented transform of the measurement through the sigma points z +- columns of
    L = chol((n + lambda) Pm), in closed form: mean zf (m,), covariance Sf (m, m) without R and
    cross-covariance Pf (n, m). Lc (n, N_READ): L's first N_READ columns; n_pts: the sigma-point
    pairs (free states); fp, fm (N_READ,): work space.

    Exact, not an approximation: the pressures are linear in states 0 and 1, so their transform
    returns H_P z and H_P^2 Pm (the weights reproduce mean and covariance); the position reads
    state I_X only, and row I_X of the lower-triangular L is zero beyond column I_X, so only the
    points z +- L[:, i], i < N_READ, differ from the centre in it."""
    n = z.shape[0]
    nr = Lc.shape[1]
    h0 = position_reading(z[I_X], pos_kind, L1, L2, L3)
    acc = Wm0 * h0 + wc * 2.0 * (n_pts - nr) * h0
    for i in range(nr):
        fp[i] = position_reading(z[I_X] + Lc[I_X, i], pos_kind, L1, L2, L3)
        fm[i] = position_reading(z[I_X] - Lc[I_X, i], pos_kind, L1, L2, L3)
        acc += wc * (fp[i] + fm[i])
    zx = acc
    zf[0] = H_P * z[0]
    zf[1] = H_P * z[1]
    zf[2] = zx
    s = Wc0 * (h0 - zx) ** 2 + wc * 2.0 * (n_pts - nr) * (h0 - zx) ** 2
    for i in range(nr):
        s += wc * ((fp[i] - zx) ** 2 + (fm[i] - zx) ** 2)
    for c in range(2):
        for e in range(2):
            Sf[c, e] = H_P * H_P * Pm[c, e]
    Sf[2, 2] = s
    for j in range(n):
        Pf[j, 0] = H_P * Pm[j, 0]
        Pf[j, 1] = H_P * Pm[j, 1]
        acc = 0.0
        for i in range(nr):
            acc += Lc[j, i] * (fp[i] - fm[i])
        Pf[j, 2] = wc * acc
    for c in range(2):
        Sf[c, 2] = H_P * Pf[c, 2]
        Sf[2, c] = Sf[c, 2]


@jit_inline
def ut_measurement(sig, z, Wm, Wc, pos_kind, L1, L2, L3, hs, col, zf, Sf, Pf):
    """The unscented transform of the measurement through the sigma points sig (2n+1, n): zf (m,),
    Sf (m, m) without R, Pf (n, m); the fallback of :func:`ut_measurement_closed_form`."""
    ns = sig.shape[0]
    m = zf.shape[0]
    for i in range(ns):
        measure(sig[i], pos_kind, L1, L2, L3, col)
        for c in range(m):
            hs[i, c] = col[c]
    for c in range(m):
        acc = 0.0
        for i in range(ns):
            acc += Wm[i] * hs[i, c]
        zf[c] = acc
    weighted_cross(hs[:ns], zf, hs[:ns], zf, Wc, Sf)
    weighted_cross(sig, z, hs[:ns], zf, Wc, Pf)


@jit_inline
def weighted_cross(X, x_mean, Y, y_mean, W, out):
    """out[j, c] = sum_i W[i] (X[i, j] - x_mean[j]) (Y[i, c] - y_mean[c]): the unscented
    transform's (cross-)covariance of the points X (ns, p) and Y (ns, q)."""
    for j in range(X.shape[1]):
        for c in range(Y.shape[1]):
            acc = 0.0
            for i in range(X.shape[0]):
                acc += W[i] * (X[i, j] - x_mean[j]) * (Y[i, c] - y_mean[c])
            out[j, c] = acc
