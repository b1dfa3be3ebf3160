"""Fault signature tables: sign and size of each fault's effect on every measured
output, filter estimate and residual, per motion, load case and phase."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from sam import P, Plant

from .statistics import residuals
from .thresholds import Thresholds
from .synth import lpm, profile, simulate_runs
from .figures import signatures_figure
from .filter import run_filter
from .states import leak_lpm

FAULTS = {"K_int": ("K_int", lpm(1.0)), "K_extA": ("K_extA", lpm(1.0)), "K_extB": ("K_extB", lpm(1.0)),
          "offset+": ("offset", 0.02), "offset-": ("offset", -0.02)}
MOTIONS = {"extend": (1.5, 0.15), "retract": (-1.5, 0.35)}  #: input [V], start position [m]
LOADS = (0.0, 494.0, 800.0)
ONSET, DURATION = 0.5, 2.5
PHASES = {"transient": (ONSET, ONSET + 0.3), "steady": (DURATION - 0.5, DURATION)}
#: m/s: a healthy piston slower than this over a window is stalled (or on an end stop): the
#: effects there are a stall's (no valve flow to disturb), not the motion's; e.g. extension at
#: 800 kg with the reconstructed boom geometry (docs/model.md)
STALL_V = 1e-3
#: each quantity of the table in words, with its unit: measured outputs, filter estimates, residuals
QUANTITY_WORDS = {"d_pA_kPa": "p_A [kPa]", "d_pB_kPa": "p_B [kPa]", "d_v_mm_s": "velocity [mm/s]",
                  "est_K_int_Lpm": "est. internal leak [L/min]", "est_K_extA_Lpm": "est. ext. leak A [L/min]",
                  "est_K_extB_Lpm": "est. ext. leak B [L/min]", "est_offset_pct": "est. offset [%]",
                  "est_F_d_kN": "est. load force [kN]", "r_K_int": "internal-leak residual [sigma]",
                  "r_K_extA": "ext. leak A residual [sigma]", "r_K_extB": "ext. leak B residual [sigma]",
                  "r_offset+": "offset + residual [sigma]", "r_offset-": "offset - residual [sigma]"}
QUANTITIES = tuple(QUANTITY_WORDS)
PHASE_WORDS = {"transient": f"transient (first {PHASES['transient'][1] - ONSET:g} s after the fault)",
               "steady": f"steady (last {PHASES['steady'][1] - PHASES['steady'][0]:g} s)"}


def signature_table(plant: Plant, dt: float = 1e-3, seed: int = 0) -> list[dict]:
    T = int(round(DURATION / dt)) + 1
    t = np.arange(T) * dt
    cases = [(f, mo, mL) for mo in MOTIONS for mL in LOADS for f in (None, *FAULTS)]
    rows = []
    for mo in MOTIONS:
        amp, x0 = MOTIONS[mo]
        sub = [c for c in cases if c[1] == mo]
        params = np.tile(plant.vector(), (len(sub), 1))
        nominal = params.copy()
        fault_arrays = {"K_int": np.zeros((len(sub), T)), "K_extA": np.zeros((len(sub), T)),
                        "K_extB": np.zeros((len(sub), T)), "offset": np.zeros((len(sub), T))}
        for i, (f, _, mL) in enumerate(sub):
            params[i, P.m_L] = mL
            if f is not None:
                col, v = FAULTS[f]
                fault_arrays[col][i] = profile("step", v, t, t0=ONSET)
        u = np.full(T, amp)
        runs = simulate_runs(params, u, dt, faults=fault_arrays, nominal=nominal, seed=seed, x0=x0)
        out = run_filter(runs.inp)
        res = residuals(out, Thresholds.shipped())
        est = {
            "est_K_int_Lpm": leak_lpm(out.mean[:, :, 7]), "est_K_extA_Lpm": leak_lpm(out.mean[:, :, 8]),
            "est_K_extB_Lpm": leak_lpm(out.mean[:, :, 9]), "est_offset_pct": 100 * out.mean[:, :, 10],
            "est_F_d_kN": out.mean[:, :, 11] / 1e3,
        }
        for i, (f, _, mL) in enumerate(sub):
            if f is None:
                continue
            h = next(k for k, c in enumerate(sub) if c[0] is None and c[2] == mL)
            for ph, (a, b) in PHASES.items():
                w = (t >= a) & (t < b)
                v_healthy = float(np.mean(runs.truth["v"][h, w]))
                row = {"fault": f, "motion": mo, "load_kg": mL, "phase": ph, "v_healthy_mm_s": 1e3 * v_healthy,
                       "stalled": "yes" if abs(v_healthy) < STALL_V else "no"}
                row["d_pA_kPa"] = float(np.mean(runs.inp.pA[i, w] - runs.inp.pA[h, w])) / 1e3
                row["d_pB_kPa"] = float(np.mean(runs.inp.pB[i, w] - runs.inp.pB[h, w])) / 1e3
                row["d_v_mm_s"] = float(np.mean(runs.truth["v"][i, w] - runs.truth["v"][h, w])) * 1e3
                for k, arr in est.items():
                    row[k] = float(np.mean(arr[i, w] - arr[h, w]))
                for k in ("K_int", "K_extA", "K_extB", "offset+", "offset-"):
                    row[f"r_{k}"] = float(np.mean(res[f"r_{k}"][i, w] - res[f"r_{k}"][h, w]))
                rows.append(row)
    return rows


def write_signatures(rows: list[dict], out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    keys = ["fault", "motion", "load_kg", "phase", "v_healthy_mm_s", "stalled", *QUANTITIES]
    csv_path = out_dir / "signatures.csv"
    with csv_path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]) for k in keys})
    md = out_dir / "signatures.md"
    lines = ["# Fault signatures", "",
             "Effect of each fault (leaks 1 L/min at 10 MPa, offset +-2 %) against the same run without it.",
             "`d_*`: change of the measured output; `est_*`: change of the filter estimate; `r_*`: change of the "
             "residual [sigma]. Windows: transient = first 0.3 s after onset, steady = last 0.5 s.",
             f"`v_healthy_mm_s`: the healthy piston's mean velocity there; `stalled` = yes when it is below "
             f"{STALL_V * 1e3:g} mm/s (held against the load or on an end stop): those rows show a stall's "
             "signature (no valve flow), not the motion's.", "",
             "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        lines.append("| " + " | ".join(_cell(r[k]) for k in keys) + " |")
    md.write_text("\n".join(lines) + "\n")
    png = out_dir / "signatures.png"
    signatures_figure(png, rows, QUANTITY_WORDS, PHASE_WORDS)
    return [csv_path, md, png]


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:+.3g}"
    return str(v)
