"""The compiled filter loop: B unscented Kalman filters over T samples, all sigma points of all
filters through ONE ``sam.step_blocks`` call per sample.

The sigma points live, as the model sees them, in lane blocks (:mod:`sam.row_step`) laid out once
per run: filter b's points are the model's rows off[b], off[b] + 1, ..., each with its filter's
plant vector. Per sample k, for every active filter: :func:`draw` its sigma points,
:func:`to_model` (their states, the input and the parameters they drive written into their
lanes), one model step of all lanes, :func:`predicted_moments`
(the unscented transform of the propagated points plus the process noise), then
:func:`innovation`, :func:`kalman_update`, :func:`constrain`, :func:`guard` and :func:`write`.
Each step is a small function inlined into the loop, handed one filter's rows as borrowed
views (:mod:`sam.views`: no reference counting at every call).

The loop's inputs are one structure, :class:`KernelArgs`, its outputs another,
:class:`KernelOutputs`, both built by :func:`fdi.filter.run_filter`; its state and work arrays
are allocated once, inside. Values are in the internal units of :mod:`fdi.states`.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numba
import numpy as np

from sam import block_lane, derived_parts, lane_blocks, step_blocks
from sam.views import jit_inline, matrix, row, whole

from .sigma import (
    cholesky, cholesky_columns, cholesky_solve, robust_sqrt, sigma_points, ut_measurement,
    ut_measurement_closed_form,
)
from .states import L1_COL, L2_COL, L3_COL, LOG_2PI, N_MODEL, N_READ, P_S_COL

#: The kernel's inputs. Shapes: B filters, T samples, n states, m = 3 measured channels.
KernelArgs = namedtuple("KernelArgs", [
    "z0",          # (B, n) initial means
    "P0",          # (B, n, n) initial covariances (also what a reset restores)
    "Qd",          # (n, n) process noise per sample
    "Rd",          # (m,) measurement variances
    "u",           # (B, T) valve input [V]; the model steps from sample k - 1 to k with u[k - 1]
    "y",           # (B, T, m) measurements, NaN = missing
    "pS",          # (B, T) measured supply pressure [Pa] or NaN
    "params",      # (B, len(P)) nominal plant vectors
    "scale",       # (n,) internal unit of each state (SI per unit)
    "param_cols",  # (n - N_MODEL,) the parameter column each augmented state drives
    "param_rel",   # (n - N_MODEL,) 1: a relative error of that parameter (calibration state), 0: its value
    "pos_kind",    # POS_X or POS_THETA
    "Wm", "Wc",    # (B, 2n + 1) Merwe weights of each filter's free states
    "lam",         # (B,) Merwe lambda
    "act",         # (B, n) free states first (act[b, :n_act[b]]), then the held ones
    "n_act",       # (B,) number of free states
    "n_steps",     # (B,) samples to filter per run, non-increasing in b (the active runs are a prefix)
    "slot",        # (B,) output row of filter b
    "q_gate",      # (B, T, G) factor on the random walk of the states of gate group g
    "gate_group",  # (n,) gate group of each state (-1: always on)
    "stop_gate",   # (B, T) bool: a linear sensor reads the piston on an end stop
    "stop_learn",  # (n,) bool: the states that learn from the position on an end stop
    "clip_leaks", "project_mean", "project_internal", "joint", "symmetrise",  # constraints (bool)
    "nis_alpha",   # weight of a sample in the exponentially weighted NIS
    "nis_limit",   # weighted NIS above which the covariance is reset (inf: never)
    "jitter",      # first relative jitter of a failed Cholesky factorisation
    "max_state",   # largest |scaled state| of a sane mean
    "dt",          # s, sampling step
    "n_sub",       # model steps per sample
    "scheme",      # the model's integration scheme (sam.Scheme)
])
#: The kernel's outputs, rows in caller order (``slot``).
KernelOutputs = namedtuple("KernelOutputs", [
    "mean", "sd",  # (B, T, n) posterior mean and std
    "nu",          # (B, T, m) normalised innovations (NaN: not measured)
    "nis",         # (B, T) exponentially weighted NIS
    "ll",          # (B, T) log N(nu; 0, S) of each sample (0: nothing measured)
    "counts",      # (B, 4) [samples with a channel missing, jitter events, covariance resets, state resets]
])


@jit_inline
def borrow2(x):
    """The C-contiguous 2-D argument array x as a borrowed view (sam.views): no reference counting
    when it is handed to an inlined step (valid while x is alive: run()'s arguments are)."""
    return matrix(x.reshape((1, x.shape[0], x.shape[1])), 0)


@jit_inline
def draw(P, P0, z, c, jitter, L, A, act, na, sig, counts):
    """Sigma points of N(z, P) over the free states act[:na] into sig. A covariance that needs
    jitter is counted (counts[1]); one that cannot be factorised even then is reset to P0
    (counts[2]), the filter's last resort."""
    tries = robust_sqrt(P, c, jitter, L, A, act, na)
    if tries < 0:
        P[:, :] = P0
        counts[2] += 1
        if robust_sqrt(P, c, jitter, L, A, act, na) < 0:
            L[:, :] = 0.0  # run_filter refuses such a P0: never, but never an uninitialised factor
    elif tries > 0:
        counts[1] += 1
    sigma_points(z, L, act, na, sig)


@jit_inline
def to_model(sig, nsb, scale, cols, rel, clip_leaks, nominal, u, ps, off, s, uu, p):
    """The nsb sigma points sig into the model's rows off, off + 1, ... of the lane blocks (states
    s, inputs uu, parameters p): the model states in SI, each augmented state written into its
    parameter column (leaks clipped at 0, calibration states as nominal * (1 + c)), the input u
    and the measured supply pressure ps (if not NaN; else the last one measured stays)."""
    for i in range(nsb):
        blk, ln = block_lane(off + i)
        for j in range(N_MODEL):
            s[blk, j, ln] = sig[i, j] * scale[j]
        uu[blk, ln] = u
        for q in range(cols.shape[0]):
            v = sig[i, N_MODEL + q] * scale[N_MODEL + q]
            if clip_leaks and q < 3 and v < 0.0:
                v = 0.0
            if rel[q]:
                v = nominal[cols[q]] * (1.0 + max(v, -0.95))
            p[blk, cols[q], ln] = v
        if ps == ps:
            p[blk, P_S_COL, ln] = ps


@jit_inline
def predicted_moments(sig, nsb, off, s, inv_scale, Wm, Wc, Qd, gate, gate_group, dev, z, P):
    """The predicted mean z and covariance P: the unscented transform of the propagated points
    (model rows off, ... of the lane blocks' states s) plus the process noise Qd, each state's
    gated by gate[gate_group[j]].
    The parameter states are random walks the model leaves as drawn, so their mean stays z and
    their block of P stays as it was (the weights reproduce both): only the model states' rows
    are summed. A held state's points sit at its mean: its rows come out 0."""
    n = z.shape[0]
    for i in range(nsb):
        blk, ln = block_lane(off + i)
        for j in range(N_MODEL):
            sig[i, j] = s[blk, j, ln] * inv_scale[j]
    for j in range(N_MODEL):
        acc = 0.0
        for i in range(nsb):
            acc += Wm[i] * sig[i, j]
        z[j] = acc
    for i in range(nsb):  # deviations once, then rank-one sums (contiguous inner loop)
        for j in range(n):
            dev[i, j] = sig[i, j] - z[j]
    for j in range(n):
        for l in range(min(j + 1, N_MODEL)):
            P[j, l] = 0.0
    for i in range(nsb):
        wi = Wc[i]
        for j in range(n):
            d = wi * dev[i, j]
            for l in range(min(j + 1, N_MODEL)):
                P[j, l] += d * dev[i, l]
    for j in range(n):
        for l in range(j + 1):
            acc = P[j, l]
            qv = Qd[j, l]
            if gate_group[j] >= 0:
                qv *= gate[gate_group[j]]
            P[j, l] = acc + qv
            P[l, j] = acc + qv


@jit_inline
def restrict_stop_gain(K, Pxz, S, learn, Spp):
    """On an end stop, the gain K (n, 3) of [p_A, p_B, position] is replaced, for every state not
    in ``learn``, by the optimal gain of the pressures alone, with none from the position: the
    stop truncates the sigma points that cross it, so the predicted position is biased off the
    stop and its innovation would push every state that lowers the force lifting the piston.
    S (3, 3) with R; Spp (2, 2): work space. The covariance update must then take the general
    (Joseph) form."""
    det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    Spp[0, 0] = S[1, 1] / det
    Spp[1, 1] = S[0, 0] / det
    Spp[0, 1] = -S[0, 1] / det
    Spp[1, 0] = -S[1, 0] / det
    for j in range(K.shape[0]):
        if not learn[j]:
            k0 = Pxz[j, 0] * Spp[0, 0] + Pxz[j, 1] * Spp[1, 0]
            k1 = Pxz[j, 0] * Spp[0, 1] + Pxz[j, 1] * Spp[1, 1]
            K[j, 0] = k0
            K[j, 1] = k1
            K[j, 2] = 0.0


@jit_inline
def innovation(y, idx, mv, zf, Sf, Pf, Rd, zp, S, Pxz, innov):
    """The measured channels idx[:mv] of the predicted measurement (mean zf, covariance Sf,
    cross-covariance Pf): their mean zp, innovation covariance S = Sf + R, Pxz and the
    innovation y - zp."""
    n = Pf.shape[0]
    for c in range(mv):
        zp[c] = zf[idx[c]]
        for e in range(mv):
            S[c, e] = Sf[idx[c], idx[e]]
        S[c, c] += Rd[idx[c]]
    for j in range(n):
        for c in range(mv):
            Pxz[j, c] = Pf[j, idx[c]]
    for c in range(mv):
        innov[c] = y[idx[c]] - zp[c]


@jit_inline
def kalman_update(z, P, K, Pxz, S, Ls, innov, mv, Sinv, e, Sinv_col, ysol, restricted, learn, Spp):
    """z += K nu and P -= K S K^T with the gain K = Pxz S^-1 (Ls: the Cholesky factor of S); a gain
    restricted on an end stop (:func:`restrict_stop_gain`) needs P - K Pxz^T - Pxz K^T + K S K^T."""
    n = z.shape[0]
    for c2 in range(mv):  # S^-1 from mv solves (not one per state: n >> mv)
        for c in range(mv):
            e[c] = 1.0 if c == c2 else 0.0
        cholesky_solve(Ls, e, Sinv_col, ysol, mv)
        for c in range(mv):
            Sinv[c, c2] = Sinv_col[c]
    for j in range(n):
        for c in range(mv):
            acc = 0.0
            for c2 in range(mv):
                acc += Pxz[j, c2] * Sinv[c2, c]
            K[j, c] = acc
    if restricted:
        restrict_stop_gain(K, Pxz, S, learn, Spp)
    for j in range(n):
        acc = 0.0
        for c in range(mv):
            acc += K[j, c] * innov[c]
        z[j] += acc
    for j in range(n):  # the lower triangle, mirrored
        for l in range(j + 1):
            acc = 0.0
            for c in range(mv):
                acc += K[j, c] * Pxz[l, c]
            if restricted:
                for c in range(mv):
                    acc += Pxz[j, c] * K[l, c]
                    for c2 in range(mv):
                        acc -= K[j, c] * S[c, c2] * K[l, c2]
            P[j, l] -= acc
            P[l, j] = P[j, l]


@jit_inline
def constrain(z, P, symmetrise, project, joint):
    """Symmetrise P; with ``project`` keep the leak means (states N_MODEL..N_MODEL + 2) on K >= 0:
    a negative one is set to 0, with ``joint`` the other states moving along their regression
    on it (the minimum P^-1-distance projection; P untouched)."""
    n = z.shape[0]
    if symmetrise:
        for j in range(n):
            for l in range(j):
                s = 0.5 * (P[j, l] + P[l, j])
                P[j, l] = s
                P[l, j] = s
    if not project:
        return
    for j in range(N_MODEL, N_MODEL + 3):
        if joint:
            if z[j] < 0.0 and P[j, j] > 0.0:
                dz = -z[j] / P[j, j]
                for i in range(n):
                    z[i] += P[i, j] * dz
                z[j] = 0.0
        elif z[j] < 0.0:
            z[j] = 0.0


@jit_inline
def log_likelihood(innov, S, Ls, mv, idx, solved, ysol, nu):
    """(log N(innov; 0, S), innov^T S^-1 innov) of the mv measured channels (Ls: the Cholesky
    factor of S); their normalised innovations into nu[idx[c]]."""
    for c in range(mv):
        nu[idx[c]] = innov[c] / math.sqrt(S[c, c])
    cholesky_solve(Ls, innov, solved, ysol, mv)
    nis = 0.0
    for c in range(mv):
        nis += innov[c] * solved[c]
    logdet = 0.0
    for c in range(mv):
        logdet += 2.0 * math.log(Ls[c, c])
    return -0.5 * (nis + logdet + mv * LOG_2PI), nis


@jit_inline
def guard(z, P, z_good, P0, max_state, ewnis, b, nis_limit, m, counts):
    """Divergence. A mean that is not finite or beyond ``max_state`` (internal units) is restored
    to the last sane one with P0 (counts[3]); a weighted NIS ewnis[b] above ``nis_limit`` (the
    innovations far larger than the filter believes) raises the variances back to P0's
    (counts[2]). Either restarts the weighted NIS at its mean m."""
    n = z.shape[0]
    sane = True
    for j in range(n):
        if not abs(z[j]) <= max_state:
            sane = False
    if not sane:
        for j in range(n):
            z[j] = z_good[j]
        P[:, :] = P0
        counts[3] += 1
        ewnis[b] = float(m)
    else:
        for j in range(n):
            z_good[j] = z[j]
    if ewnis[b] > nis_limit:
        for j in range(n):
            P[j, j] = max(P[j, j], P0[j, j])
        counts[2] += 1
        ewnis[b] = float(m)


@jit_inline
def write(z, P, project_mean, mean, sd):
    """The posterior into one sample's output rows (SI scaling follows in run_filter); the
    reported leak means >= 0."""
    n = z.shape[0]
    for j in range(n):
        mean[j] = z[j]
        sd[j] = math.sqrt(max(P[j, j], 0.0))
    if project_mean:
        for j in range(N_MODEL, N_MODEL + 3):
            if mean[j] < 0.0:
                mean[j] = 0.0


@jit_inline
def retire(mean, sd, nu, nis, ll, k):
    """One output row NaN from sample k on (its run stopped there)."""
    for t in range(k, mean.shape[0]):
        nis[t] = np.nan
        ll[t] = np.nan
        for c in range(nu.shape[1]):
            nu[t, c] = np.nan
        for j in range(mean.shape[1]):
            mean[t, j] = np.nan
            sd[t, j] = np.nan


@numba.njit(cache=True)
def run(a, o):
    """Run the filters of ``a`` (:class:`KernelArgs`) into ``o`` (:class:`KernelOutputs`). Sample
    k: predict from the posterior at k - 1 with u[k - 1] (none at k = 0: the prior is z0, P0),
    then update with the channels measured at k."""
    # every field once into a local: a tuple's field read inside the loop costs reference counting
    # of the whole tuple; the work arrays are allocated here, once: handed in, the loop was slower
    B, n = a.z0.shape
    T = a.u.shape[1]
    m = a.Rd.shape[0]
    ns = 2 * n + 1
    P0, u, y, pS, params, Wm, Wc, lam, act, n_act = a.P0, a.u, a.y, a.pS, a.params, a.Wm, a.Wc, a.lam, a.act, a.n_act
    n_steps, slot, q_gate, stop_gate, pos_kind = a.n_steps, a.slot, a.q_gate, a.stop_gate, a.pos_kind
    clip_leaks, project_mean, symmetrise, joint = a.clip_leaks, a.project_mean, a.symmetrise, a.joint
    project = a.project_mean and a.project_internal
    nis_alpha, nis_limit, jitter, max_state, dt, n_sub = a.nis_alpha, a.nis_limit, a.jitter, a.max_state, a.dt, a.n_sub
    scheme = a.scheme
    Qd, Rd, scale, cols, rel = borrow2(a.Qd), whole(a.Rd), whole(a.scale), whole(a.param_cols), whole(a.param_rel)
    gate_group, learn = whole(a.gate_group), whole(a.stop_learn)
    mean, sd, nu_out, nis_out, ll, counts = o.mean, o.sd, o.nu, o.nis, o.ll, o.counts
    # the state: posterior means and covariances, the last sane means, the weighted NIS
    z, P, z_good, ewnis = a.z0.copy(), P0.copy(), a.z0.copy(), np.full(B, float(m))
    # filter b's sigma points are the model rows off[b]:off[b + 1]: states, inputs uu, parameters
    off = np.zeros(B + 1, dtype=np.int64)
    for b in range(B):
        off[b + 1] = off[b] + 2 * n_act[b] + 1
    rows = np.empty((off[B], params.shape[1]))
    for b in range(B):
        for i in range(off[b + 1] - off[b]):
            rows[off[b] + i, :] = params[b, :]
    bs, bu, bp, bd, bflags = lane_blocks(rows)
    # the constants the model derives from the parameters the filter writes (its augmented
    # states', the supply pressure) are derived again at each sample; the others once, here
    geometry, machine = derived_parts(np.append(a.param_cols, P_S_COL))
    sig = np.empty((B, ns, n))
    inv_scale = 1.0 / a.scale  # a multiplication per sigma point and state, not a division
    L, A, dev, hs, col = np.empty((n, n)), np.empty((n, n)), np.empty((ns, n)), np.empty((ns, m)), np.empty(m)
    Lc, fp, fm = np.empty((n, N_READ)), np.empty(N_READ), np.empty(N_READ)
    zf, Sf, Pf, idx, zp = np.empty(m), np.empty((m, m)), np.empty((n, m)), np.empty(m, np.int64), np.empty(m)
    S, Pxz, Ls, innov, solved, ysol = np.empty((m, m)), np.empty((n, m)), np.empty((m, m)), np.empty(m), \
        np.empty(m), np.empty(m)
    e, Sinv_col, Sinv, K, Spp = np.empty(m), np.empty(m), np.empty((m, m)), np.empty((n, m)), np.empty((2, 2))
    nA = B  # active filters: b < nA
    for k in range(T):
        while nA > 0 and n_steps[nA - 1] <= k:
            nA -= 1
            s = slot[nA]
            retire(matrix(mean, s), matrix(sd, s), matrix(nu_out, s), row(nis_out, s), row(ll, s), k)
        if nA == 0:
            break
        if k > 0:  # ---- predict
            for b in range(nA):
                nsb = 2 * n_act[b] + 1
                draw(matrix(P, b), matrix(P0, b), row(z, b), n_act[b] + lam[b], jitter, L, A, row(act, b), n_act[b],
                     matrix(sig, b), row(counts, b))
                to_model(matrix(sig, b), nsb, scale, cols, rel, clip_leaks, row(params, b), u[b, k - 1], pS[b, k - 1],
                         off[b], bs, bu, bp)
            # a coarse recording: n_sub model steps per sample, input held
            step_blocks(bs, bu, bp, bd, dt, bflags, off[nA], n_sub, scheme, geometry, machine)
            for b in range(nA):
                predicted_moments(matrix(sig, b), 2 * n_act[b] + 1, off[b], bs, inv_scale, row(Wm, b),
                                  row(Wc, b), Qd, row(matrix(q_gate, b), k), gate_group, dev, row(z, b), matrix(P, b))
        for b in range(nA):  # ---- update
            s = slot[b]
            zb, Pb, yk, nu = row(z, b), matrix(P, b), row(matrix(y, b), k), row(matrix(nu_out, s), k)
            mv = 0
            for c in range(m):
                nu[c] = np.nan
                if yk[c] == yk[c]:
                    idx[mv] = c
                    mv += 1
            if mv < m:
                counts[b, 0] += 1
            ll[s, k] = 0.0
            if mv > 0:
                L1, L2, L3 = params[b, L1_COL], params[b, L2_COL], params[b, L3_COL]
                c_pts = n_act[b] + lam[b]
                # filterpy redraws the sigma points from the prior for the update; the closed form
                # needs its first N_READ Cholesky columns only, the full redraw is the fallback
                if cholesky_columns(Pb, c_pts, Lc, n, N_READ):
                    ut_measurement_closed_form(Pb, zb, n_act[b], Lc, Wm[b, 0], Wc[b, 0], Wc[b, 1], pos_kind,
                                               L1, L2, L3, zf, Sf, Pf, fp, fm)
                else:
                    nsb = 2 * n_act[b] + 1
                    sigb = matrix(sig, b)
                    draw(Pb, matrix(P0, b), zb, c_pts, jitter, L, A, row(act, b), n_act[b], sigb, row(counts, b))
                    ut_measurement(sigb[:nsb], zb, row(Wm, b)[:nsb], row(Wc, b)[:nsb], pos_kind, L1, L2, L3,
                                   hs, col, zf, Sf, Pf)
                innovation(yk, idx, mv, zf, Sf, Pf, Rd, zp, S, Pxz, innov)
                if cholesky(S, Ls, mv):
                    ll_k, nis = log_likelihood(innov, S, Ls, mv, idx, solved, ysol, nu)
                    ll[s, k] = ll_k
                    kalman_update(zb, Pb, K, Pxz, S, Ls, innov, mv, Sinv, e, Sinv_col, ysol,
                                  stop_gate[b, k] and mv == 3, learn, Spp)
                    ewnis[b] += nis_alpha * (nis * m / mv - ewnis[b])
            constrain(zb, Pb, symmetrise, project, joint)
            guard(zb, Pb, row(z_good, b), matrix(P0, b), max_state, ewnis, b, nis_limit, m, row(counts, b))
            nis_out[s, k] = ewnis[b]
            write(zb, Pb, project_mean, row(matrix(mean, s), k), row(matrix(sd, s), k))
