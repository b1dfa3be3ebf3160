"""Tables and figures of a finished study, in the form of the paper's.

* ``ranking.csv``: factors ranked per output, by S1 (Tables 2) and by ST (Table 6);
* ``interactions.csv``: 1 - sum S1 per output (Table 3);
* ``summary.md``: the paper's Tables 2, 3, 4, 6, 7 and 8 for our run;
* figures: steady-state bars of S1 and ST with CI whiskers (Figs. 5 and 7) and
  area plots of the indices over time (Figs. 6 and 8).
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


def write_ranking(result: SobolResult, path: Path) -> Path:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["output", "time_s", "by", "rank", "parameter", "value"])
        for by in ("S1", "ST"):
            values, order = getattr(result, by), result.ranking(by)
            for j, name in enumerate(result.output_names):
                t = _time_text(result, j)
                for rank, i in enumerate(order[:, j], start=1):
                    w.writerow([name, t, by, rank, result.factor_names[i], repr(float(values[i, j]))])
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


def summary_markdown(result: SobolResult, spec, runtime_s: float | None = None) -> str:
    """The paper's tables for this run (steady state, interactions, indices over time)."""
    lines = [f"# Sobol' sensitivity study `{spec.study.name}`", ""]
    if spec.description:
        lines += [spec.description, ""]
    lines += [f"N = {result.N} (runs N(k+2) = {result.N * (len(result.factor_names) + 2)}), "
              f"estimator `{result.estimator}`, {result.n_boot} bootstrap resamples "
              f"({result.ci}, {result.confidence:.0%} intervals), seed {spec.seed}."]
    if runtime_s is not None:
        lines[-1] += f" Wall time {runtime_s:.1f} s."
    if spec.steady_definition:
        lines += ["", f"Steady state: {spec.steady_definition}."]
    lines += [""]
    scalars = _scalars(result)
    if spec.analytic is not None:
        lines += _analytic_table(result, spec, scalars)
        return "\n".join(lines) + "\n"
    lines += _ranking_table(result, scalars, "S1", "Ranking by first-order index at steady state (paper's Table 2)")
    lines += _ranking_table(result, scalars, "ST", "Ranking by total index at steady state (the form of the paper's Table 6)")
    lines += ["## Interactions at steady state (paper's Table 3)", "",
              "| output | 1 − Σ S1 | Σ ST |", "|---|---|---|"]
    inter = result.interactions
    for name, j in scalars.items():
        lines.append(f"| {name} | {_fmt(inter[j], 4)} | {_fmt(np.sum(result.ST[:, j]), 4)} |")
    lines.append("")
    series = _series(result)
    for name, cols in series.items():
        for by, paper in (("ST", "Tables 4 and 8"), ("S1", "Table 7")):
            lines += _over_time_table(result, spec, name, cols, by, paper)
    return "\n".join(lines) + "\n"


def _ranking_table(result, scalars, by, title) -> list[str]:
    names = list(scalars)
    lines = [f"## {title}", "", "| rank | " + " | ".join(names) + " |",
             "|---" * (len(names) + 1) + "|"]
    order = result.ranking(by)
    values = getattr(result, by)
    for rank in range(len(result.factor_names)):
        cells = []
        for name in names:
            j = scalars[name]
            i = order[rank, j]
            cells.append(f"{result.factor_names[i]} ({_fmt(values[i, j])})")
        lines.append(f"| {rank + 1} | " + " | ".join(cells) + " |")
    return lines + [""]


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
    lines = ["## Estimates against the analytic indices", "",
             "| parameter | S1 | 95 % CI | exact S1 | ST | 95 % CI | exact ST |",
             "|---|---|---|---|---|---|---|"]
    for i, name in enumerate(result.factor_names):
        lines.append(
            f"| {name} | {_fmt(result.S1[i, j], 4)} | [{_fmt(result.S1_lo[i, j], 4)}, {_fmt(result.S1_hi[i, j], 4)}] "
            f"| {S1_exact[i]:.4f} | {_fmt(result.ST[i, j], 4)} | [{_fmt(result.ST_lo[i, j], 4)}, "
            f"{_fmt(result.ST_hi[i, j], 4)}] | {ST_exact[i]:.4f} |")
    err = max(np.max(np.abs(result.S1[:, j] - S1_exact)), np.max(np.abs(result.ST[:, j] - ST_exact)))
    return lines + ["", f"Largest absolute error: {err:.4f}.", ""]


def plot_steady_bars(result: SobolResult, path: Path) -> Path | None:
    """Figs. 5 and 7: S1 and ST with CI whiskers per scalar output."""
    scalars = _scalars(result)
    if not scalars:
        return None
    k = len(result.factor_names)
    fig, axes = plt.subplots(1, len(scalars), figsize=(4.2 * len(scalars), 3.6), squeeze=False)
    x = np.arange(k)
    for ax, (name, j) in zip(axes[0], scalars.items()):
        for off, by, color in ((-0.2, "S1", "tab:blue"), (0.2, "ST", "tab:orange")):
            v = getattr(result, by)[:, j]
            lo, hi = getattr(result, by + "_lo")[:, j], getattr(result, by + "_hi")[:, j]
            yerr = np.vstack([np.clip(v - lo, 0, None), np.clip(hi - v, 0, None)])
            ax.bar(x + off, v, 0.4, yerr=np.nan_to_num(yerr), capsize=2, color=color, label=by)
        ax.set_xticks(x, result.factor_names, rotation=45, ha="right", fontsize="small")
        ax.set_title(name)
        ax.set_ylim(0, 1.05)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("Sobol' index")
    axes[0][0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_area_over_time(result: SobolResult, name: str, cols: np.ndarray, path: Path) -> Path:
    """Figs. 6 and 8: stacked areas of S1 and ST of each factor over time for one output."""
    t = result.output_times[cols]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
    for ax, by in zip(axes, ("S1", "ST")):
        values = np.clip(np.nan_to_num(getattr(result, by)[:, cols]), 0, None)
        ax.stackplot(t, values, labels=result.factor_names, alpha=0.85)
        ax.set_title(f"{name}: {'first-order' if by == 'S1' else 'total'} indices")
        ax.set_xlabel("t [s]")
        ax.set_xscale("log")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("stacked index")
    axes[1].legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(result: SobolResult, spec, out: Path, runtime_s: float | None = None) -> list[Path]:
    """Write every table and figure of a study into ``out``; returns the paths."""
    paths = [result.write_csv(out / "indices.csv"), write_ranking(result, out / "ranking.csv"),
             write_interactions(result, out / "interactions.csv")]
    summary = out / "summary.md"
    summary.write_text(summary_markdown(result, spec, runtime_s))
    paths.append(summary)
    bars = plot_steady_bars(result, out / "steady_state_indices.png")
    if bars:
        paths.append(bars)
    for name, cols in _series(result).items():
        paths.append(plot_area_over_time(result, name, cols, out / f"indices_over_time_{name}.png"))
    return paths
