"""Tables, words and figures of a finished study, in the form of the paper's.

* ``ranking.csv``: factors ranked per output, by S1 (Table 2) and by ST (Table 6),
  with the group of factors their 95 % intervals do not separate;
* ``interactions.csv``: 1 - sum S1 per output (Table 3);
* ``summary.md``: what the study shows in plain words, then the paper's Tables 2,
  3, 4, 6, 7 and 8 for our run, every index with its interval;
* figures: steady-state bars of S1 and ST with their intervals (Figs. 5 and 7) and
  the indices over time with their intervals, one line per factor (Figs. 6 and 8).

A ranking is only stated as far as the intervals separate it
(:meth:`gsa.analyze.SobolResult.ranked_groups`): "dp_N_PA ≈ dp_N_BT > Q_N_PA".
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from gsa.analyze import SobolResult  # noqa: E402

#: a factor whose total index stays below this even at its interval's upper end is
#: "negligible": it can stay at its nominal value for this output (factor fixing)
NEGLIGIBLE_ST = 0.05
#: 1 - sum S1 above this: interactions carry a share of the variance worth acting on
MARKED_INTERACTION = 0.1
STEADY = "_steady"


def report_files(result_outputs: tuple[str, ...], output_times) -> tuple[str, ...]:
    """Names of the files :func:`write_report` writes for a study with these outputs."""
    series = sorted({n for n, t in zip(result_outputs, output_times or ()) if math.isfinite(t)})
    return ("indices.csv", "ranking.csv", "interactions.csv", "summary.md", "steady_state_indices.png",
            *(f"indices_over_time_{name}.png" for name in series))


def _series(result: SobolResult) -> dict[str, np.ndarray]:
    """Output base name -> column indices of its time series (finite times), in time order."""
    times = result.output_times
    out: dict[str, list[int]] = {}
    for j, name in enumerate(result.output_names):
        if times is not None and math.isfinite(times[j]):
            out.setdefault(name, []).append(j)
    return {k: np.array(v) for k, v in out.items()}


def _scalars(result: SobolResult) -> dict[str, int]:
    """Outputs without a time (steady-state values, analytic outputs): name -> column."""
    times = result.output_times
    return {name: j for j, name in enumerate(result.output_names)
            if times is None or not math.isfinite(times[j])}


# -- words ------------------------------------------------------------------------------


def ranking_words(result: SobolResult, j: int, by: str = "ST", negligible: bool = True) -> str:
    """One output's ranking as far as the intervals separate it: "a ≈ b (tied within the 95 %
    intervals) > c". ``negligible``: name the factors below :data:`NEGLIGIBLE_ST` apart."""
    if result.constant[j]:
        return "none (the output did not vary, its indices are undefined)"
    hi = getattr(result, by + "_hi")[:, j]
    small = {i for i in range(len(result.factor_names)) if negligible and hi[i] < NEGLIGIBLE_ST}
    groups = [[result.factor_names[i] for i in group if i not in small] for group in result.ranked_groups(j, by)]
    text = tied_ranking(groups, result.confidence)
    if small:
        text += (f"; negligible ({by} < {NEGLIGIBLE_ST:g} at the interval's upper end): "
                 + ", ".join(result.factor_names[i] for i in sorted(small)))
    return text


def tied_ranking(groups: list[list[str]], confidence: float = 0.95) -> str:
    """Groups of names, most influential first, as "a ≈ b (tied within the 95 % intervals) > c"."""
    parts = [" ≈ ".join(g) + (f" (tied within the {_pct(confidence)} intervals)" if len(g) > 1 else "")
             for g in groups if g]
    return " > ".join(parts) or "no factor matters"


def _pct(fraction: float) -> str:
    return f"{100 * fraction:.0f} %"


def _capital(text: str) -> str:
    return text[:1].upper() + text[1:]


def _join(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def _named(result: SobolResult, spec, i: int) -> str:
    words = spec.factor_words.get(result.factor_names[i])
    return f"{result.factor_names[i]} ({words})" if words else result.factor_names[i]


def _output_words(spec, name: str) -> str:
    base = name[: -len(STEADY)] if name.endswith(STEADY) else name
    words = spec.output_words.get(base, base)
    return f"the steady {words}" if name.endswith(STEADY) else words


def conclusion(result: SobolResult, spec) -> list[str]:
    """The section a hydraulics engineer reads first: for each steady output what matters,
    as far as the intervals tell, and what to do about it."""
    scalars = {n: j for n, j in _scalars(result).items() if not result.constant[j]}
    if not scalars:
        return []
    lines = ["## What the study shows", ""]
    leads: dict[int, list[str]] = {}  # factor -> the outputs it leads
    negligible = set(range(len(result.factor_names)))
    for name, j in scalars.items():
        groups = result.ranked_groups(j, "ST")
        top = groups[0]
        for i in top:
            leads.setdefault(i, []).append(name[: -len(STEADY)] if name.endswith(STEADY) else name)
        negligible &= {i for i in range(len(result.factor_names)) if result.ST_hi[i, j] < NEGLIGIBLE_ST}
        values = ", ".join(f"{result.ST[i, j]:.2f} [{result.ST_lo[i, j]:.2f}, {result.ST_hi[i, j]:.2f}]"
                           for i in top)
        tied = (f", tied within the {_pct(result.confidence)} intervals: the data cannot say which "
                f"matters more" if len(top) > 1 else "")
        lines.append(f"- **{_capital(_output_words(spec, name))}** depends most on "
                     f"{_join([_named(result, spec, i) for i in top])} (total index {values}{tied}). "
                     f"Full ranking: {ranking_words(result, j)}.")
    lines.append("")
    key = sorted(leads)
    fixed = [result.factor_names[i] for i in sorted(negligible - set(key))]
    inter = [float(result.interactions[j]) for j in scalars.values()]
    watch = "; ".join(f"{result.factor_names[i]} in {_join(leads[i])}" for i in key)
    advice = (f"**What to do with it.** {_join([result.factor_names[i] for i in key])} move these outputs the "
              f"most. Where the model must match a machine, get them right first (measure or calibrate "
              f"them); where they change in service (wear, a leak), a change shows first where each leads: "
              f"{watch}.")
    if fixed:
        advice += (f" {_join(fixed)} can stay at {'its' if len(fixed) == 1 else 'their'} nominal "
                   f"value{'s' * (len(fixed) > 1)} for these outputs: over the studied ranges "
                   f"{'it moves' if len(fixed) == 1 else 'they move'} none of them measurably.")
    advice += " " + _transient_note(result, spec, negligible - set(key))
    if max(inter) > MARKED_INTERACTION:
        advice += (f" Interactions carry up to {_pct(max(inter))} of the variance (1 − Σ S1): change "
                   f"parameters together when calibrating, not one at a time.")
    else:
        advice += (f" Interactions are small (1 − Σ S1 at most {max(inter):.2f}): each parameter acts "
                   f"mostly on its own, so they can be calibrated one by one.")
    if any(sum(result.ST_hi[i, j] >= NEGLIGIBLE_ST for i in g) > 1
           for j in scalars.values() for g in result.ranked_groups(j, "ST")):
        advice += (f" Where parameters are tied, N = {result.N} cannot tell them apart: the intervals narrow "
                   f"as 1/√N, so a run with --n {4 * result.N} halves them.")
    return lines + [advice.replace("  ", " ").strip(), ""]


def _transient_note(result: SobolResult, spec, steady_negligible: set[int]) -> str:
    """Factors negligible at steady state that clearly matter at some instant of the transient."""
    notes = []
    for i in sorted(steady_negligible):
        peak = None
        for name, cols in _series(result).items():
            lo = result.ST_lo[i, cols]
            if np.any(np.isfinite(lo)) and np.nanmax(lo) >= NEGLIGIBLE_ST:
                k = int(np.nanargmax(lo))
                if peak is None or result.ST[i, cols[k]] > peak[0]:
                    peak = (float(result.ST[i, cols[k]]), name, float(result.output_times[cols[k]]))
        if peak:
            notes.append(f"{result.factor_names[i]} matters only during the transient (total index "
                         f"{peak[0]:.2f} in {spec.output_words.get(peak[1], peak[1])} at {peak[2]:g} s): "
                         f"it needs to be right for the start of a motion, not for steady operation.")
    return " ".join(notes)


# -- tables -----------------------------------------------------------------------------


def write_ranking(result: SobolResult, path: Path) -> Path:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["output", "time_s", "by", "rank", "group", "parameter", "value", "lo", "hi"])
        for by in ("S1", "ST"):
            values, lo, hi = (getattr(result, by + part) for part in ("", "_lo", "_hi"))
            for j, name in enumerate(result.output_names):
                t = _time_text(result, j)
                rank = 0
                for g, group in enumerate(result.ranked_groups(j, by), start=1):
                    for i in group:
                        rank += 1
                        w.writerow([name, t, by, rank, g, result.factor_names[i],
                                    *(repr(float(v[i, j])) for v in (values, lo, hi))])
    return path


def write_interactions(result: SobolResult, path: Path) -> Path:
    inter = result.interactions
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["output", "time_s", "interaction_1_minus_sum_S1", "sum_ST"])
        for j, name in enumerate(result.output_names):
            w.writerow([name, _time_text(result, j), repr(float(inter[j])),
                        repr(float(np.sum(result.ST[:, j])))])
    return path


def _time_text(result: SobolResult, j: int) -> str:
    if result.output_times is None or not math.isfinite(result.output_times[j]):
        return ""
    return repr(float(result.output_times[j]))


def _nearest(result: SobolResult, cols: np.ndarray, t: float) -> int:
    return int(cols[np.argmin(np.abs(result.output_times[cols] - t))])


def _fmt(v: float, digits: int = 3) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.{digits}f}"


def _with_interval(result: SobolResult, by: str, i: int, j: int, digits: int = 3) -> str:
    lo, hi = getattr(result, by + "_lo")[i, j], getattr(result, by + "_hi")[i, j]
    return f"{_fmt(getattr(result, by)[i, j], digits)} [{_fmt(lo, digits)}, {_fmt(hi, digits)}]"


def summary_markdown(result: SobolResult, spec, runtime_s: float | None = None) -> str:
    """What the study shows in words, then the paper's tables for this run."""
    lines = [f"# Sobol' sensitivity study `{spec.study.name}`", ""]
    if spec.description:
        lines += [spec.description, ""]
    lines += [f"N = {result.N} (runs N(k+2) = {result.N * (len(result.factor_names) + 2)}), "
              f"estimator `{result.estimator}`, {result.n_boot} bootstrap resamples "
              f"({result.ci}, {_pct(result.confidence)} intervals), seed {spec.seed}."]
    if runtime_s is not None:
        lines[-1] += f" Wall time {runtime_s:.1f} s."
    if spec.steady_definition:
        lines += ["", f"Steady state: {spec.steady_definition}."]
    lines += ["", f"Every index is given with its {_pct(result.confidence)} bootstrap interval. A ranking "
              f"is stated only as far as the intervals separate it: \"a ≈ b\" means the intervals of a "
              f"and b overlap, so the data do not tell which matters more; \"a > b\" means they are "
              f"disjoint.", ""]
    scalars = _scalars(result)
    if spec.analytic is not None:
        lines += _analytic_table(result, spec, scalars)
        return "\n".join(lines) + "\n"
    lines += conclusion(result, spec)
    lines += _ranking_tables(result, spec, scalars)
    lines += ["## Interactions at steady state (paper's Table 3)", "",
              "| output | 1 − Σ S1 | Σ ST |", "|---|---|---|"]
    inter = result.interactions
    for name, j in scalars.items():
        lines.append(f"| {name} | {_fmt(inter[j], 4)} | {_fmt(np.sum(result.ST[:, j]), 4)} |")
    lines.append("")
    for name, cols in _series(result).items():
        for by, paper in (("ST", "Tables 4 and 8"), ("S1", "Table 7")):
            lines += _over_time_table(result, spec, name, cols, by, paper)
    return "\n".join(lines) + "\n"


def _ranking_tables(result, spec, scalars) -> list[str]:
    """Per steady output: the ranking in words, then every factor's S1 and ST with intervals
    (the paper's Tables 2 and 6), tied factors sharing a rank range."""
    lines = ["## Ranking at steady state (paper's Tables 2 and 6)", ""]
    for name, j in scalars.items():
        lines += [f"### {name}: {_output_words(spec, name)}", "",
                  f"By total index ST: {ranking_words(result, j, 'ST')}.  ",
                  f"By first-order index S1: {ranking_words(result, j, 'S1')}.", "",
                  "| rank (ST) | parameter | S1 [95 % interval] | ST [95 % interval] |", "|---|---|---|---|"]
        rank = 1
        for group in result.ranked_groups(j, "ST"):
            label = str(rank) if len(group) == 1 else f"{rank}–{rank + len(group) - 1} (tied)"
            for i in group:
                lines.append(f"| {label} | {_named(result, spec, i)} | {_with_interval(result, 'S1', i, j)} "
                             f"| {_with_interval(result, 'ST', i, j)} |")
            rank += len(group)
        lines.append("")
    return lines


def _over_time_table(result, spec, name, cols, by, paper) -> list[str]:
    instants = spec.instants_s or tuple(result.output_times[cols][:: max(1, len(cols) // 10)])
    values = getattr(result, by)
    lines = [f"## {name}: {'total' if by == 'ST' else 'first-order'} indices over time (cf. paper's {paper})",
             "", "| time [s] | " + " | ".join(result.factor_names) + " |",
             "|---" * (len(result.factor_names) + 1) + "|"]
    for t in instants:
        j = _nearest(result, cols, t)
        lines.append(f"| {t:.2f} | " + " | ".join(_fmt(values[i, j]) for i in range(len(result.factor_names))) + " |")
    return lines + [""]


def _analytic_table(result, spec, scalars) -> list[str]:
    S1_exact, ST_exact = spec.analytic
    j = next(iter(scalars.values()))
    lines = [f"Ranking by total index: {ranking_words(result, j, 'ST', negligible=False)}.", "",
             "## Estimates against the analytic indices", "",
             "| parameter | S1 | 95 % CI | exact S1 | ST | 95 % CI | exact ST |",
             "|---|---|---|---|---|---|---|"]
    for i, name in enumerate(result.factor_names):
        lines.append(
            f"| {name} | {_fmt(result.S1[i, j], 4)} | [{_fmt(result.S1_lo[i, j], 4)}, {_fmt(result.S1_hi[i, j], 4)}] "
            f"| {S1_exact[i]:.4f} | {_fmt(result.ST[i, j], 4)} | [{_fmt(result.ST_lo[i, j], 4)}, "
            f"{_fmt(result.ST_hi[i, j], 4)}] | {ST_exact[i]:.4f} |")
    err = max(np.max(np.abs(result.S1[:, j] - S1_exact)), np.max(np.abs(result.ST[:, j] - ST_exact)))
    return lines + ["", f"Largest absolute error: {err:.4f}.", ""]


# -- figures ----------------------------------------------------------------------------


def _colour(i: int):
    """One colour per factor, the same in every figure of a study."""
    return plt.get_cmap("tab10")(i % 10)


def plot_steady_bars(result: SobolResult, spec, path: Path) -> Path | None:
    """Figs. 5 and 7: S1 and ST with their intervals per steady output."""
    scalars = _scalars(result)
    if not scalars:
        return None
    k = len(result.factor_names)
    fig, axes = plt.subplots(1, len(scalars), figsize=(3.6 * len(scalars) + 1.0, 4.2), squeeze=False,
                             sharey=True)
    x = np.arange(k)
    for ax, (name, j) in zip(axes[0], scalars.items()):
        for off, by, color in ((-0.2, "S1", "tab:blue"), (0.2, "ST", "tab:orange")):
            v = getattr(result, by)[:, j]
            lo, hi = getattr(result, by + "_lo")[:, j], getattr(result, by + "_hi")[:, j]
            yerr = np.vstack([np.clip(v - lo, 0, None), np.clip(hi - v, 0, None)])
            ax.bar(x + off, v, 0.4, yerr=yerr, capsize=2, color=color,
                   label=f"{by} ({'first-order' if by == 'S1' else 'total'})")
        ax.set_xticks(x, result.factor_names, rotation=45, ha="right")
        ax.set_title(_capital(_output_words(spec, name)), fontsize="medium")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("Sobol' index")
    axes[0][0].legend(fontsize="small")
    fig.suptitle(f"Steady-state indices of {spec.study.name}, N = {result.N}, "
                 f"{_pct(result.confidence)} intervals as whiskers", fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_indices_over_time(result: SobolResult, spec, name: str, cols: np.ndarray, path: Path) -> Path:
    """Figs. 6 and 8 as lines: S1 (top) and ST (bottom) of each factor over time for one output,
    each with its interval shaded. Instants where the output did not vary are gaps, not 0;
    factors negligible throughout are listed under the plot instead of drawn."""
    t = result.output_times[cols]
    G = len(result.factor_names)
    shown = [i for i in range(G) if np.nanmax(result.ST_hi[i, cols], initial=-np.inf) >= NEGLIGIBLE_ST]
    hidden = [result.factor_names[i] for i in range(G) if i not in shown]
    fig, axes = plt.subplots(2, 1, figsize=(9.0, 7.5), sharex=True, layout="constrained")
    for ax, by in zip(axes, ("S1", "ST")):
        v, lo, hi = (getattr(result, by + part)[:, cols] for part in ("", "_lo", "_hi"))
        for i in shown:  # NaN stays NaN: matplotlib leaves a gap
            ax.plot(t, v[i], color=_colour(i), lw=1.6, label=_named(result, spec, i))
            ax.fill_between(t, lo[i], hi[i], where=np.isfinite(lo[i]) & np.isfinite(hi[i]),
                            color=_colour(i), alpha=0.2, lw=0)
        ax.set_ylabel(f"{by}, {'first-order' if by == 'S1' else 'total'} index")
        ax.set_xscale("log")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3, which="both")
    axes[-1].set_xlabel("time after the start of the run t [s] (log scale)")
    title = (f"{_capital(spec.output_words.get(name, name))}: Sobol' indices over time\n"
             f"N = {result.N}; shaded: {_pct(result.confidence)} bootstrap intervals")
    if result.constant[cols].any():
        title += "; gaps: the output did not vary there"
    fig.suptitle(title, fontsize="medium")
    handles, labels = axes[0].get_legend_handles_labels()
    if hidden:
        handles.append(plt.Line2D([], [], color="none"))
        labels.append(f"not drawn (total index below {NEGLIGIBLE_ST:g} throughout): {', '.join(hidden)}")
    fig.legend(handles, labels, loc="outside lower center", ncol=2, fontsize="small", frameon=False)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_report(result: SobolResult, spec, out: Path, runtime_s: float | None = None) -> list[Path]:
    """Write every table and figure of a study into ``out``; returns the paths."""
    paths = [result.write_csv(out / "indices.csv"), write_ranking(result, out / "ranking.csv"),
             write_interactions(result, out / "interactions.csv")]
    summary = out / "summary.md"
    summary.write_text(summary_markdown(result, spec, runtime_s))
    paths.append(summary)
    bars = plot_steady_bars(result, spec, out / "steady_state_indices.png")
    if bars:
        paths.append(bars)
    for name, cols in _series(result).items():
        paths.append(plot_indices_over_time(result, spec, name, cols, out / f"indices_over_time_{name}.png"))
    return paths
