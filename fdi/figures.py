"""The figures of ``samfdi fdi``, drawn for the size they are shown at (about 1200 px wide): the
replay of one recording (replay.png), the tune's rates against fault size (rates.png) and the
fault signatures (signatures.png). Every figure names what it shows in words an engineer reads,
with the codes (K_int, offset+) in brackets where the files use them."""

from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from .states import STATE_NAMES, leak_lpm

FONT = {"font.size": 11, "axes.titlesize": 12, "legend.fontsize": 10}
DPI = 100
#: each leak's colour and words
LEAKS = {"K_int": ("C0", "internal leak, A to B (K_int)"), "K_extA": ("C1", "external leak out of A (K_extA)"),
         "K_extB": ("C2", "external leak out of B (K_extB)")}
#: the words of each change test (and the notch-flow trigger) of the statistics panel
TESTS = {"K_int": "internal-leak test", "K_extA": "external-leak A test", "K_extB": "external-leak B test",
         "offset+": "spool offset test, + side", "offset-": "spool offset test, - side",
         "notch_flow": "valve-flow jump trigger"}
FIGURE_CLIP = 5.0  #: the replay figure shows statistic / threshold up to this


def _wrapped(text: str, width: int = 125) -> str:
    """``text`` broken into lines of at most ``width`` characters (about the figure's width)."""
    return "\n".join(textwrap.fill(line, width) for line in text.splitlines())


def _patch(**style):
    """A legend handle for a shaded span."""
    return Rectangle((0, 0), 1, 1, lw=0, **style)


def replay_figure(path: Path, t, r, th, truth: dict | None = None, truth_t=None) -> None:
    """replay.png of a :class:`fdi.offline.Replay` ``r`` over times ``t`` [s] under the
    thresholds ``th``: the leak and offset estimates with their +-2 sigma bands (and the true sizes
    when the recording has ``true_*`` columns: ``truth``, over ``truth_t``), each test's statistic
    over its threshold, the alarms and the decision, with a legend that says how to read them."""
    out, res, stats, diag = r.output, r.residuals, r.statistics, r.diagnosis
    truth = truth or {}
    with matplotlib.rc_context(FONT):
        fig = Figure(figsize=(12, 10), layout="constrained")
        axes = fig.subplots(3, 1, sharex=True, height_ratios=(1.1, 0.8, 1.1))
        ax = axes[0]
        for name, (c, words) in LEAKS.items():
            j = STATE_NAMES.index(name)
            m, s = leak_lpm(out.mean[0, :, j]), leak_lpm(out.std[0, :, j])
            ax.plot(t, m, c, lw=1.4, label=words)
            ax.fill_between(t, m - 2 * s, m + 2 * s, color=c, alpha=0.15, lw=0)
            if f"true_{name}" in truth:
                ax.plot(truth_t, leak_lpm(truth[f"true_{name}"]), color=c, ls="--", lw=2.0)
        ax.set_ylabel("leak [L/min at 10 MPa]")
        ax2 = axes[1]
        j = STATE_NAMES.index("offset")
        m, s = 100 * out.mean[0, :, j], 100 * out.std[0, :, j]
        ax2.plot(t, m, "C3", lw=1.4, label="valve spool offset")
        ax2.fill_between(t, m - 2 * s, m + 2 * s, color="C3", alpha=0.15, lw=0)
        if "true_offset" in truth:
            ax2.plot(truth_t, 100 * truth["true_offset"], color="C3", ls="--", lw=2.0)
        ax2.set_ylabel("spool offset [% of travel]")
        band = [_patch(color="0.6", alpha=0.3, label="shaded: +-2 sigma of the estimate")]
        known = [Line2D([], [], color="k", ls="--", lw=2.0, label="dashed: the true size (true_* columns)")] \
            if any(k in truth for k in ("true_K_int", "true_K_extA", "true_K_extB", "true_offset")) else []
        for a in (ax, ax2):
            handles = a.get_legend_handles_labels()[0] + band + known
            a.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        _statistics_panel(axes[2], t, res, stats, th)
        marks = _decision_lines(axes, diag)
        axes[2].set_xlabel("time [s]")
        fig.legend(handles=marks, loc="outside lower left", ncol=len(marks), frameon=False)
        fig.suptitle(_wrapped(diag.headline()), fontsize=12, x=0.01, ha="left")
        fig.savefig(path, dpi=DPI)


def _statistics_panel(ax, t, res: dict, stats: dict, th) -> None:
    """Each test's statistic over its threshold, the alarm level at 1, and the spans where the
    tests are held (pressures pinned) or count only large excursions (long strokes)."""
    h = th.test.h
    for i, (name, g) in enumerate(stats.items()):
        ax.plot(t, g[0] / h[name], f"C{i}", lw=1.2, label=TESTS.get(name, name))
    # a real fault drives g/h to hundreds: clip, so that the alarm level stays readable
    top = max((float(np.nanmax(g[0] / h[name])) for name, g in stats.items()), default=1.0)
    ax.set_ylim(0.0, min(max(2.0, 1.1 * top), FIGURE_CLIP))
    if top > FIGURE_CLIP:
        ax.text(0.99, 0.97, f"clipped at {FIGURE_CLIP:g} (largest {top:.3g})", transform=ax.transAxes,
                ha="right", va="top", fontsize=9)
    ax.axhline(1.0, color="k", ls="--", lw=1.2)
    extra = [Line2D([], [], color="k", ls="--", lw=1.2, label="alarm level: a test alarms where it crosses 1")]
    if "pinned" in res and res["pinned"][0].any():
        ax.fill_between(t, 0, 1, where=res["pinned"][0] > 0, transform=ax.get_xaxis_transform(), color="0.85", lw=0)
        extra.append(_patch(color="0.85", label="grey: pressures at supply / tank,\nthose tests held"))
    if "long_stroke" in res and res["long_stroke"][0].any():
        ax.fill_between(t, 0, 1, where=res["long_stroke"][0] > 0, transform=ax.get_xaxis_transform(), color="C9",
                        alpha=0.12, lw=0)
        which = " and ".join(th.test.long_stroke_params)
        extra.append(_patch(color="C9", alpha=0.25, label=f"blue: long stroke, {which}\n"
                                                         f"tests count only > {th.test.long_stroke_drift:g} sigma"))
    ax.set_ylabel("test statistic / its threshold")
    ax.legend(handles=ax.get_legend_handles_labels()[0] + extra, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              borderaxespad=0)


def _decision_lines(axes, diag) -> list:
    """Draw the alarms and the decision on every panel; their legend handles."""
    lik, marks = diag.likelihood, []
    styles = {"alarm": {"color": "r", "lw": 1.2}, "withdrawn": {"color": "0.45", "lw": 1.0, "ls": "--"},
              "decision": {"color": "k", "lw": 1.6, "ls": ":"}}
    if "withdrawn_alarms_s" not in lik:  # no bank ran: every test's first alarm
        times = {"alarm": list(diag.alarms.values())}
    else:
        times = {"alarm": [lik["alarm_s"]] if lik.get("alarm_s") is not None and lik.get("confirmed_s") is not None
                 else [], "withdrawn": lik["withdrawn_alarms_s"]}
    if diag.isolation_time_s is not None:
        times["decision"] = [diag.isolation_time_s]
    words = {"alarm": "red: the alarm that stood", "withdrawn": "grey dashed: an alarm the bank withdrew (no fault "
             "fitted better; tests restarted)", "decision": f"black dotted: {', '.join(diag.isolated)} named by the "
             "likelihood bank"}
    for kind, ts in times.items():
        for ta in ts:
            for a in axes:
                a.axvline(ta, **styles[kind])
        if ts:
            marks.append(Line2D([], [], **styles[kind], label=words[kind]))
    return marks or [Line2D([], [], color="none", label="vertical lines: none (no alarm)")]


#: the tune figure's panels: (fault, sign of the size, title)
RATE_PANELS = (("K_int", 1, LEAKS["K_int"][1]), ("K_extA", 1, LEAKS["K_extA"][1]), ("K_extB", 1, LEAKS["K_extB"][1]),
               ("offset", 1, "valve spool offset, + side (offset+)"), ("offset", -1, "valve spool offset, - side (offset-)"))


def rates_figure(path: Path, m: dict, false_alarm_level: float, target: float, interval) -> None:
    """rates.png of a tune's metrics ``m`` (:func:`fdi.metrics.analyse`): per fault, the share of
    runs detected, and detected and isolated, within 1 s of the onset against the fault's size, and
    the false alarms per healthy run; each rate k of n runs with its ``interval(k, n)`` as a bar,
    against the ``target`` rate and the stated ``false_alarm_level``."""
    with matplotlib.rc_context(FONT):
        fig = Figure(figsize=(13, 8.5), layout="constrained")
        axes = fig.subplots(2, 3)
        for ax, (fault, sign, title) in zip(axes.flat, RATE_PANELS):
            rows = sorted((r for r in m["rows"] if r["fault"] == fault and np.sign(r["size"]) == sign),
                          key=lambda r: abs(r["size"]))
            x = np.array([abs(r["size"]) * (100 if fault == "offset" else 1) for r in rows])
            n = np.array([r["runs"] for r in rows])
            for key, shift, style in (
                    ("detected_within_1s", 0.96, {"color": "0.45", "marker": "o", "mfc": "white", "ls": "--",
                                                  "label": "detected within 1 s"}),
                    ("isolated_within_1s", 1.04, {"color": "C0", "marker": "s", "ls": "-",
                                                  "label": "detected and isolated within 1 s"})):
                k = np.array([round(r[key] * r["runs"]) for r in rows])
                p, (lo, hi) = 100 * k / n, 100 * np.array([interval(a, b) for a, b in zip(k, n)]).T
                ax.errorbar(x * shift, p, yerr=(p - lo, hi - p), capsize=4, lw=1.5, ms=6, **style)
            ax.axhline(100 * target, color="C3", ls=":", lw=1.3, label=f"target {100 * target:g} %")
            ax.set_xscale("log")
            ax.set_xticks(x, [f"{v:g}" for v in x])
            ax.minorticks_off()
            ax.set_xlabel("offset [% of spool travel]" if fault == "offset" else "leak [L/min at 10 MPa]")
            ax.set_ylabel("runs [%]")
            ax.set_ylim(0, 103)
            ax.set_title(title)
            ax.grid(alpha=0.3)
        axes.flat[0].legend(loc="lower right")
        _false_alarm_panel(axes.flat[5], m, false_alarm_level)
        n_case = min(r["runs"] for r in m["rows"])
        fig.suptitle(f"fdi tune: the share of runs, {n_case} or more per fault and size, that a fault was detected "
                     "(and isolated) within 1 s of its onset; bars: exact 95 % intervals", x=0.01, ha="left")
        fig.savefig(path, dpi=DPI)


def _false_alarm_panel(ax, m: dict, level: float) -> None:
    """False alarms per healthy run [%] of each healthy population, with their intervals."""
    groups = [(f"tune inputs\n{m['healthy_runs']} x {m['healthy_run_s']:g} s", m)]
    if "long_cycles" in m:
        groups += [(f"20-60 s cycles\n{m['long_cycles']['runs']} runs", m["long_cycles"]),
                   (f"all healthy\n{m['all_healthy']['runs']} runs", m["all_healthy"])]
    for i, (label, g) in enumerate(groups):
        p, (lo, hi) = 100 * g["false_alarm_rate"], 100 * np.array(g["false_alarm_ci"])
        ax.errorbar([i], [p], yerr=([p - lo], [hi - p]), color="k", marker="o", capsize=6, lw=1.5, ms=6)
        ax.annotate(f"{g['false_alarms']} of {g.get('runs', m['healthy_runs'])}", (i, hi), textcoords="offset points",
                    xytext=(0, 6), ha="center", fontsize=10)
    ax.axhline(100 * level, color="C3", ls=":", lw=1.3, label=f"stated level {100 * level:g} %")
    ax.set_xticks(range(len(groups)), [label for label, _ in groups])
    ax.set_xlim(-0.5, len(groups) - 0.5)
    top = max(100 * max(g["false_alarm_ci"][1] for _, g in groups), 100 * level)
    ax.set_ylim(0, 1.3 * top)
    ax.set_ylabel("runs with a false alarm [%]")
    ax.set_title("false alarms per healthy run")
    ax.legend(loc="upper right")
    ax.grid(alpha=0.3, axis="y")


#: the signature figure's words for each fault of the table
FAULT_WORDS = {"K_int": "internal leak", "K_extA": "ext. leak A", "K_extB": "ext. leak B",
               "offset+": "offset +2 %", "offset-": "offset -2 %"}


#: an effect below this share of the largest on its quantity is left unlabelled (it reads as white)
NEGLIGIBLE_EFFECT = 0.05


def signatures_figure(path: Path, rows: list, quantities: dict, phases: dict) -> None:
    """signatures.png of the signature table ``rows`` (fdi.signatures): one heat map per motion
    and phase (``phases``: phase -> its words), a row per fault and load, a column per quantity
    (``quantities``: table key -> words with unit), each cell coloured by the effect over the
    largest |effect| on that quantity in the whole table and labelled with its value where that is
    not negligible."""
    keys = list(quantities)
    scale = np.maximum(np.abs(np.array([[r[k] for k in keys] for r in rows], dtype=float)).max(axis=0), 1e-30)
    panels = list(dict.fromkeys((r["motion"], r["phase"]) for r in rows))
    with matplotlib.rc_context(FONT):
        fig = Figure(figsize=(17, 13), layout="constrained")
        axes = fig.subplots(2, 2)
        order = {f: i for i, f in enumerate(dict.fromkeys(r["fault"] for r in rows))}
        for ax, (motion, phase) in zip(axes.flat, panels):
            mine = sorted((r for r in rows if (r["motion"], r["phase"]) == (motion, phase)),
                          key=lambda r: (order[r["fault"]], r["load_kg"]))
            M = np.array([[r[k] for k in keys] for r in mine], dtype=float)
            im = ax.imshow(M / scale, cmap="RdBu_r", vmin=-1, vmax=1, aspect="auto")
            for (i, j), v in np.ndenumerate(M):
                if abs(v / scale[j]) >= NEGLIGIBLE_EFFECT:
                    ax.text(j, i, f"{v:.0f}" if abs(v) >= 10 else f"{v:.2g}", ha="center", va="center", fontsize=9,
                            color="w" if abs(v / scale[j]) > 0.6 else "k")
            ax.set_xticks(range(len(keys)), list(quantities.values()), rotation=50, ha="right")
            ax.set_yticks(range(len(mine)), [f"{FAULT_WORDS.get(r['fault'], r['fault'])}, {r['load_kg']:g} kg"
                                             + (" (stalled)" if r["stalled"] == "yes" else "") for r in mine])
            for i in range(1, len(mine)):  # a line between faults
                if mine[i]["fault"] != mine[i - 1]["fault"]:
                    ax.axhline(i - 0.5, color="k", lw=1.0)
            for j in (3, 8):  # measured | estimates | residuals
                ax.axvline(j - 0.5, color="k", lw=1.0)
            ax.set_title(f"{motion}, {phases[phase]}")
        fig.colorbar(im, ax=axes, shrink=0.6, label="effect / largest |effect| on that quantity (sign and size)")
        fig.suptitle("Fault signatures: each fault (leaks 1 L/min at 10 MPa, offset +-2 %) against the same run "
                     "without it; cell: the change, in the column's unit (blank: under 5 % of the column's largest)",
                     x=0.01, ha="left")
        fig.savefig(path, dpi=DPI)
