"""Write a diagnosis: report.md (readable in two minutes), report.json and figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from sam.errors import UserError

from .simulation import SIGNALS

#: every file a diagnosis writes into its folder (refused there without --force)
OUTPUT_FILES = ("report.md", "report.json", "overlay.png", "overlay_validation.png", "residual.png", "separate.toml")
_MODEL_COLOURS = {"nominal": "tab:blue", "calibrated": "tab:orange", "augmented": "tab:green",
                  "generic term": "tab:purple"}
_SIG_UNIT = {"pA": ("p_A [MPa]", 1e-6), "pB": ("p_B [MPa]", 1e-6), "x": ("x [mm]", 1e3)}


def _clean(obj):
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _candidate_dict(c, rank: int) -> dict:
    return {
        "rank": rank, "name": c.name, "title": c.title, "accepted": c.accepted,
        "evidence": {"signature_match": c.signature, "delta_bic": c.delta_bic, "delta_bic_held_out": c.delta_bic_held,
                     "error_reduction_fit": c.gain_fit, "error_reduction_held_out": c.gain_held,
                     "held_out_segments": c.specificity.as_dict() if c.specificity else None},
        "fitted": c.effect_values(), "fitted_text": c.summary(), "at_bounds": c.result.at_bounds,
        "where_it_shows": "; ".join(h.shows for h in c.hypothesis),
        "looks_alike": [h.alike for h in c.hypothesis if h.alike],
    }


def to_json(report) -> dict:
    return _clean({
        "source": report.source, "validate": report.validate_source,
        "verdict": report.verdict, "headline": report.headline,
        "named_effects": report.named,
        "fit_percent": report.fit_table,
        "calibration": report.calibration,
        "located": report.located,
        "hypotheses": [_candidate_dict(c, i + 1) for i, c in enumerate(report.ranked)],
        "chosen": [_candidate_dict(c, 1) for c in report.chosen],
        "generic_route": report.generic,
        "warnings": report.warnings,
        "notes": report.notes,
        "effective_samples_for_bic": report.n_eff,
        "step_floor": report.floor.as_dict() if report.floor else None,
        "noise_ceiling": report.shortfall,
        "how_sure": report.sureness,
        "what_would_settle_it": report.design.as_dict() if report.design else None,
        "limits_of_the_recording": report.limits,
        "timings_s": report.timings,
        "figures": report.figures,
    })


def _fit_rows(table: dict) -> list[str]:
    rows = ["| model | part | p_A | p_B | x | mean |", "|---|---|---|---|---|---|"]
    words = {"fit": "fitting part", "held": "held out"}
    for model, parts in table.items():
        for part, f in parts.items():
            rows.append(f"| {model} | {words[part]} | {f['pA']:.1f} | {f['pB']:.1f} | {f['x']:.1f} | {f['mean']:.1f} |")
    return rows


def console_lines(report) -> list[str]:
    """What ``samfdi mismatch`` prints: the headline, the warnings, and the notes only when the
    verdict claims a mismatch (an adequate model is not weakened by the segments left out)."""
    lines = [report.headline] + [f"warning: {w}" for w in report.warnings]
    if report.verdict not in ("adequate", "recalibrated"):
        lines += [f"note: {n}" for n in report.notes]
    return lines


def to_markdown(report) -> str:
    L = [f"# Mismatch diagnosis: {Path(report.source).name}", "", f"**{report.headline}**", ""]
    verdict_words = {
        "named": "missing physics named", "adequate": "model adequate", "recalibrated": "model adequate after recalibration",
        "unknown_effect": "an effect outside the library", "unexplained": "mismatch not explained",
    }
    L += [f"Verdict: **{verdict_words.get(report.verdict, report.verdict)}**.", ""]
    if report.warnings:
        L += ["## Warnings", ""] + [f"- {w}" for w in report.warnings] + [""]
    if report.notes:
        L += ["## Notes", ""] + [f"- {n}" for n in report.notes] + [""]
    L += ["## Fit % (NRMSE, 100 = perfect)", "",
          f"Each {report.segment_s:g} s segment is simulated from the measured state at its start; every third "
          f"segment is held out"
          if report.validate_source is None else f"Held out: the whole of {report.validate_source}.", ""]
    L += _fit_rows(report.fit_table) + [""]
    L += ["## Calibration of the nominal parameters (GSA-ranked)", ""]
    L += [f"- {c['text']}" + (" **(at its bound)**" if c["at_bound"] else "") for c in report.calibration] + [""]
    loc = report.located
    L += ["## Where the simulation and the recording differ", ""]
    share = loc["signal_share"]
    L += ["- residual share per signal: " + ", ".join(f"{k} {100 * v:.0f} %" for k, v in share.items())]
    regs = [r for r in loc["regimes"] if r["enrichment"] > 1.2][:4]
    for r in regs:
        L.append(f"- {r['regime']}: {100 * r['residual_share']:.0f} % of the error in {100 * r['time_share']:.0f} % "
                 f"of the time (x{r['enrichment']:.1f})")
    if loc["windows"]:
        L.append("- worst windows: " + ", ".join(f"{w['t_start']:.1f}-{w['t_end']:.1f} s ({100 * w['share']:.0f} %)"
                                                  for w in loc["windows"][:5]))
    wh = ", ".join(f"{k} {'white' if v['white'] else 'not white'} (lag-1 rho {v['rho_lag1']:.2f})"
                   for k, v in loc["whiteness"].items())
    xc = ", ".join(f"{k} {v['max_abs_corr']:.2f} at {1e3 * v['at_lag_s']:.0f} ms"
                   + (" (significant)" if v["significant"] else "") for k, v in loc["input_correlation"].items())
    L += [f"- residual whiteness (calibrated model): {wh}", f"- residual vs input cross-correlation: {xc}", ""]
    L += ["## Hypotheses, ranked", "",
          "Evidence: signature match (0-1, score test of the effect's sensitivity against the residual), "
          f"BIC change (effective samples {report.n_eff:.0f}; below -10 is strong), error reduction on the "
          "fitting part and held out. Accepted = strong BIC, at least 5 % less error on both parts and "
          "+0.5 points of held-out fit. A second effect is accepted on top of the first by strong BIC on "
          f"the fitting part and on the held-out part, each {report.segment_s:g} s segment with its own residual "
          f"variance.", "",
          "| rank | effect | accepted | signature | dBIC | error -% fit | error -% held out | fitted |",
          "|---|---|---|---|---|---|---|---|"]
    for i, c in enumerate(report.ranked[:3]):
        b = " (at bound: " + ", ".join(c.result.at_bounds) + ")" if c.result.at_bounds else ""
        L.append(f"| {i + 1} | {c.title} | {'yes' if c.accepted else 'no'} | {c.signature:.2f} | {c.delta_bic:.0f} | "
                 f"{100 * c.gain_fit:.0f} | {100 * c.gain_held:.0f} | {c.summary()}{b} |")
    for c in report.ranked[:3]:
        L.append(f"- *{c.title}* shows as: {c.hypothesis[0].shows}.")
    if report.chosen and len(report.chosen[0].hypothesis) > 1:
        c = report.chosen[0]
        L += ["", f"Two effects together: **{c.title}** ({c.summary()}), dBIC {c.delta_bic:.0f} over the first alone "
              f"(held out {c.delta_bic_held:.0f}), held-out error -{100 * c.gain_held:.0f} %."]
    for h in (h for c in report.chosen for h in c.hypothesis if h.alike):
        L.append(f"- *{h.title}* looks alike in the data: {h.alike}.")
    L += _sureness(report)
    g = report.generic
    L += ["", "## Generic route (unknown inputs, sparse regression)", ""]
    if g:
        L.append(f"- disturbance estimate rms: Q_dA {g['disturbance_rms']['Q_dA'] * 6e4:.3g} L/min, "
                 f"Q_dB {g['disturbance_rms']['Q_dB'] * 6e4:.3g} L/min, F_d {g['disturbance_rms']['F_d']:.3g} N")
        if g.get("delta_bic") is not None:
            L.append(f"- discovered term: `{g['equation']}` (dBIC {g['delta_bic']:.0f}, held-out error "
                     f"{-100 * g['gain_held']:+.0f} %): {g['mapped']}"
                     + ("" if g.get("significant") or g.get("significant_but_library") else " -- not significant"))
    else:
        L.append("- not run")
    if report.limits:
        L += ["", "## What this recording cannot tell apart", ""] + [f"- {w[0].upper()}{w[1:]}." for w in report.limits]
    if report.figures:
        L += ["", "## Figures", ""] + [f"![{f}]({f})" for f in report.figures]
    t = report.timings
    L += ["", f"Run time {t.get('total_s', 0):.1f} s."]
    return "\n".join(L) + "\n"


def _sureness(report) -> list[str]:
    """The runner-up, the margin, the step floor and the designed experiment, as markdown lines."""
    L = ["", "## How sure, and what would settle it", ""]
    if report.floor is not None:
        L.append(f"- The model's own step accounts for {100 * report.floor.pooled:.2g} % of the calibrated model's "
                 f"held-out squared error (Heun at the model step against a {report.floor.refine}x finer one); an "
                 f"effect must remove more than twice that, and lower the error on every held-out segment where it "
                 f"changes the prediction.")
    s = report.sureness
    if s:
        behind = "accepted too" if s["runner_up_accepted"] else "not accepted"
        L.append(f"- Runner-up: *{s['runner_up_title']}* ({behind}), {s['margin_bic_held']:.0f} behind in held-out "
                 f"BIC and {s['margin_fit_points']:.1f} points of held-out fit.")
    d = report.design
    if d is not None:
        e = d.excitation
        L.append(f"- *{d.first}* and *{d.second}* predict this recording's held-out segments {d.on_recording:.1f} "
                 f"transmitter-noise sd apart. A **{e.name}** ({e.shows}) separates them by {d.best:.1f} sd: "
                 f"`separate.toml` is that test as a scenario; `samfdi simulate separate.toml --out DIR` runs it on "
                 f"the model, the same [input] run on the machine and diagnosed settles it. Other tests: "
                 + ", ".join(f"{k} {v:.1f} sd" for k, v in d.separation.items() if k != e.name) + ".")
    if len(L) == 3:
        return []
    return L


def _and(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def figures(report, out: Path) -> list[str]:
    tr = report.traces
    split = tr["split"]
    names = []
    models = {"nominal": (tr["nominal"], None), "calibrated": (tr["calibrated"].params, tr["calibrated"].meas)}
    if report.chosen:
        models["augmented"] = (tr["final"].params, tr["final"].meas)
    g = report.generic
    for part, sim in (("fit", split.fit_sim), ("held", split.held_sim)):
        if part == "held" and sim is split.fit_sim:
            continue
        d = sim.data
        traces = {}
        for m, (p, meas) in models.items():
            o = sim.simulate(p[None, :], meas[None, :] if meas is not None and np.any(meas) else None, full=True)
            traces[m] = o
        if g and g.get("_model") and (g.get("significant") or g.get("beats_library")):
            model, th = g["_model"]
            pr, meas = model.build(th[None, :])
            traces["generic term"] = sim.simulate(pr, meas if np.any(meas) else None, full=True,
                                                  time_varying=model.tv(th[None, :], sim))
        fig = Figure(figsize=(11, 11), layout="constrained")
        axes = fig.subplots(2 * len(SIGNALS), 1, sharex=True, height_ratios=[3, 1.3] * len(SIGNALS))
        t_seg = np.concatenate([d.t[s:s + sim.seg.length] for s in sim.seg.starts])
        idx_seg = np.concatenate([np.arange(s, min(s + sim.seg.length, d.n)) for s in sim.seg.starts])
        cut = np.r_[np.diff(t_seg) > 1.5 * d.dt, False]  # no line across a segment boundary
        for n, k in enumerate(SIGNALS):
            ax, rax = axes[2 * n], axes[2 * n + 1]
            label, scale = _SIG_UNIT[k]
            # the recording is what the reader checks the models against: drawn boldest, models thin on top
            ax.plot(d.t, d.y[k] * scale, color="black", lw=2.2, label="recording", zorder=2)
            for m, o in traces.items():
                y_seg = np.concatenate([o[k][0, j] for j in range(len(sim.seg.starts))])
                y_seg[cut] = np.nan
                ax.plot(t_seg, y_seg * scale, lw=0.9, alpha=0.85, color=_MODEL_COLOURS.get(m), label=m, zorder=3)
                rax.plot(t_seg, (d.y[k][idx_seg] - y_seg) * scale, lw=0.8, alpha=0.85, color=_MODEL_COLOURS.get(m))
            rax.axhline(0.0, color="black", lw=0.8)
            for j, s in enumerate(sim.seg.starts):
                if sim.seg.held_out[j] and sim is split.fit_sim:
                    for a_ in (ax, rax):
                        a_.axvspan(d.t[s], d.t[min(s + sim.seg.length, d.n - 1)], color="0.92", zorder=0)
            ax.set_ylabel(label)
            rax.set_ylabel(f"recording − model\n{label.split()[-1]}", fontsize=9)
        axes[0].legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=9, ncol=5, frameon=False)
        axes[-1].set_xlabel("t [s]" + ("  (grey bands: held-out segments)" if sim is split.fit_sim else ""))
        fig.suptitle(("Held-out recording" if part == "held" else "Recording")
                     + f": measured (black) against the {_and(list(traces))} model"
                     + "s" * (len(traces) > 1) + "; residual beneath each signal", fontsize=11)
        name = "overlay.png" if part == "fit" else "overlay_validation.png"
        fig.savefig(out / name, dpi=110)
        names.append(name)
    # residual with located windows
    d = split.fit_sim.data
    res = tr["residual"]
    fig = Figure(figsize=(11, 5.5))
    axes = fig.subplots(2, 1, sharex=True)
    for k in SIGNALS:
        axes[0].plot(d.t, res[k], lw=0.6, label=k)
    for w in report.located["windows"]:
        for ax in axes:
            ax.axvspan(w["t_start"], w["t_end"], color="tab:red", alpha=0.15)
    axes[0].set_ylabel("residual / signal std")
    axes[0].legend(fontsize=8)
    axes[0].set_title("calibrated-model residual; shaded: located windows")
    regs = [r for r in report.located["regimes"] if r["enrichment"] > 1.2][:3]
    for i, r in enumerate(regs):
        m = tr["masks"][r["regime"]]
        axes[1].fill_between(d.t, i, i + 0.8 * m, step="mid", alpha=0.6, label=r["regime"])
    axes[1].set_yticks([])
    axes[1].legend(fontsize=8, loc="upper right")
    axes[1].set_xlabel("t [s]")
    axes[1].set_title("operating regimes where the residual concentrates")
    fig.tight_layout()
    fig.savefig(out / "residual.png", dpi=110)
    names.append("residual.png")
    return names


def write(report, out: Path, figures: bool = True) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"{out}: cannot create the output directory: {e.strerror or e}") from None
    if figures:
        report.figures = globals()["figures"](report, out)
    (out / "report.json").write_text(json.dumps(to_json(report), indent=2))
    if report.design is not None:
        (out / "separate.toml").write_text(report.design.scenario_toml(report.plant_path, Path(report.source).name))
    (out / "report.md").write_text(to_markdown(report))
