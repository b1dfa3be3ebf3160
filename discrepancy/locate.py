"""Where the residual concentrates: signal, time windows, operating regime; and residual tests."""

from __future__ import annotations

import numpy as np

from .data import Prepared
from .simulation import SIGNALS, SegmentSimulator

SIGNAL_WORDS = {"pA": "piston-side pressure p_A", "pB": "rod-side pressure p_B", "x": "piston position x"}


def full_residual(sim: SegmentSimulator, full: dict[str, np.ndarray], i: int = 0) -> dict[str, np.ndarray]:
    """Normalised residual (measured - simulated)/scale on the sample grid (NaN outside segments)."""
    d, seg = sim.data, sim.seg
    out = {}
    skip = seg.eval_idx[0]
    for k in SIGNALS:
        r = np.full(d.n, np.nan)
        for j, s in enumerate(seg.starts):
            r[s + skip:s + seg.length] = (d.y[k][s + skip:s + seg.length] - full[k][i, j, skip:]) / sim.scale[k]
        r[~d.valid[k]] = np.nan
        out[k] = r
    return out


def regimes(d: Prepared, p_S: float, x_max: float) -> dict[str, np.ndarray]:
    """Boolean masks of the operating regimes on the sample grid, in words."""
    sm = d.smooth
    v, xs = sm["v"], d.x_s
    vmax = np.percentile(np.abs(v), 99)
    v_thr = max(2e-3, 0.05 * vmax)
    xs_max = np.percentile(np.abs(xs), 99)
    pmin = np.minimum(sm["pA"], sm["pB"])
    pmax = np.maximum(sm["pA"], sm["pB"])
    sign = np.where(v > v_thr, 1, np.where(v < -v_thr, -1, 0))
    # a reversal: the direction flips (through the dead zone) within a short span
    nz = np.flatnonzero(sign != 0)
    flips = nz[1:][np.diff(sign[nz]) != 0] if nz.size > 1 else np.array([], int)
    reversal = np.zeros(d.n, bool)
    w = int(round(0.1 / d.dt))
    for k in flips:
        reversal[max(0, k - w):k + w] = True
    rate = np.abs(sm["dpA"]) + np.abs(sm["dpB"])
    transient = rate > 3 * np.median(rate) + 1e-9
    return {
        f"low chamber pressure (below {0.3 * p_S / 1e6:.1f} MPa)": pmin < 0.3 * p_S,
        f"high pressure level (above {0.7 * p_S / 1e6:.1f} MPa)": pmax > 0.7 * p_S,
        "extending": v > v_thr,
        "retracting": v < -v_thr,
        "standing still": np.abs(v) <= v_thr,
        "velocity reversal": reversal,
        "spool near null": np.abs(xs) < max(0.01, 0.1 * xs_max),
        "high flow demand (spool far open)": np.abs(xs) > 0.7 * xs_max,
        "near a stroke end": (sm["x"] < 0.05 * x_max) | (sm["x"] > 0.95 * x_max),
        "pressure transient": transient,
        "steady (no pressure transient)": ~transient,
    }


def regime_profile(energy: np.ndarray, masks: dict[str, np.ndarray]) -> list[dict]:
    """Per regime: time share, residual-energy share and their ratio (enrichment)."""
    ok = np.isfinite(energy)
    total = energy[ok].sum()
    out = []
    for name, m in masks.items():
        mm = m & ok
        time_share = mm.sum() / max(ok.sum(), 1)
        if time_share < 0.02 or total <= 0:
            continue
        e_share = energy[mm].sum() / total
        out.append({"regime": name, "time_share": float(time_share), "residual_share": float(e_share),
                    "enrichment": float(e_share / time_share)})
    out.sort(key=lambda r: -r["enrichment"])
    return out


def windows(energy: np.ndarray, t: np.ndarray, dt: float, max_windows: int = 8) -> list[dict]:
    """Time windows where the moving residual energy is well above its median."""
    e = np.nan_to_num(energy, nan=0.0)
    w = max(1, int(round(0.1 / dt)))
    mov = np.convolve(e, np.ones(w) / w, mode="same")
    thr = max(3 * np.median(mov[mov > 0]) if np.any(mov > 0) else 0, 1e-12)
    hot = mov > thr
    out = []
    k = 0
    n = len(hot)
    gap = w
    while k < n:
        if not hot[k]:
            k += 1
            continue
        j = k
        while j < n and (hot[j] or (j + gap < n and hot[j:j + gap].any())):
            j += 1
        out.append({"t_start": float(t[k]), "t_end": float(t[min(j, n - 1)]), "energy": float(e[k:j].sum())})
        k = j + 1
    total = e.sum() or 1.0
    for o in out:
        o["share"] = o.pop("energy") / total
    out.sort(key=lambda o: -o["share"])
    return out[:max_windows]


def whiteness(r: np.ndarray, max_lag: int = 30) -> dict:
    """Residual whiteness: share of the first autocorrelation lags outside the 99 % band."""
    r = r[np.isfinite(r)]
    r = r - r.mean()
    n = len(r)
    var = np.dot(r, r) / n
    lags = range(1, max_lag + 1)
    rho = np.array([np.dot(r[k:], r[:-k]) / n / var for k in lags]) if var > 0 else np.zeros(max_lag)
    band = 2.58 / np.sqrt(n)
    outside = float(np.mean(np.abs(rho) > band))
    return {"white": bool(outside <= 0.05), "lags_outside_99pct_band": outside, "rho_lag1": float(rho[0]),
            "band": float(band)}


def input_correlation(r: np.ndarray, u: np.ndarray, dt: float, max_lag_s: float = 0.3) -> dict:
    """Cross-correlation of the residual with the input (residual lagging the input by 0..max_lag)."""
    ok = np.isfinite(r)
    rr = np.where(ok, r - np.nanmean(r), 0.0)
    uu = np.where(ok, u - u[ok].mean(), 0.0)
    n = ok.sum()
    den = np.sqrt(np.dot(rr, rr) * np.dot(uu, uu)) or 1.0
    K = int(round(max_lag_s / dt))
    cc = np.array([np.dot(rr[k:], uu[:len(uu) - k]) for k in range(K + 1)]) / den
    k = int(np.argmax(np.abs(cc)))
    band = 2.58 / np.sqrt(n)
    return {"max_abs_corr": float(abs(cc[k])), "at_lag_s": float(k * dt), "band": float(band),
            "significant": bool(abs(cc[k]) > band)}
