"""The scored table, its JSON and the figure of a reconstruction study (:mod:`gsa.reconstruct`).

* ``reconstruct.md``: the verdict in words, every candidate's loss on every evidence item with
  its 95 % interval, the distances per instant, the statements' margins, Fig. 4's natural
  frequency, the lift check and the candidates' settings;
* ``reconstruct.json``: the same numbers, and every index the evidence read;
* ``reconstruct.png``: the best candidates (rows, best first) against evidence items (columns),
  coloured by rank and labelled with the loss, beside each candidate's mean rank with its interval;
* ``reconstruct_factors.png`` (with ``[factors]``): each option of each convention, its
  candidates' mean loss on every item.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from gsa.evidence import Frequency, Interaction, Ranking, Statement, Values, instant_label  # noqa: E402
from gsa.reconstruct import CONFIDENCE, ReconstructionResult, percentile_interval, main_effects  # noqa: E402

REPORT_FILES = ("reconstruct.md", "reconstruct.json", "reconstruct.png", "reconstruct_factors.png")

_LOSS_MEANING = {
    "rankings": "share of the published pairwise orders reversed (0: the same ranking; two negligible indices are never reversed)",
    "values": "root-mean-square distance to the published indices",
    "frequency": "|f_max - f_paper| / f_paper",
    "statements": "shortfall of the statement's smallest margin, in index units (0: it holds)",
}


def _cell(p: float, lo: float, hi: float, digits: int = 3) -> str:
    if not math.isfinite(p):
        return "–"
    if lo == hi == p:
        return f"{p:.{digits}f}"
    return f"{p:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _order(result: ReconstructionResult) -> list[int]:
    v = result.verdict
    return list(np.lexsort((v.group_rank, v.mean_rank)))


def _item_verdict(result: ReconstructionResult):
    """The verdict over every item: per-item ranks and bests are the same in any verdict."""
    return result.verdicts.get("all", result.verdict)


def _loss_cells(result: ReconstructionResult, k: int) -> list[tuple[float, float, float]]:
    s = result.scores[k]
    return [(float(s.point[i]), *percentile_interval(s.losses[:, i])) for i in range(len(s.point))]


def _ids(result, headline: bool | None = None) -> str:
    return ", ".join(e.id for e in result.spec.evidence if headline is None or e.headline == headline)


def summary_markdown(result: ReconstructionResult) -> str:
    spec = result.spec
    ev = spec.evidence
    order = _order(result)
    study_runs = {n: spec.N * (len(s.study.problem.factor_names) + 2) for n, s in spec.studies.items()}
    runs = " + ".join(f"{r} ({n})" for n, r in study_runs.items())
    lines = [f"# Reconstruction study `{spec.name}`", ""]
    if spec.description:
        lines += [spec.description + ".", ""]
    lines += [f"{len(spec.candidates)} candidates, each run through {len(spec.studies)} Sobol' studies at "
              f"N = {spec.N}: {runs} runs per candidate; estimator `saltelli2010-jansen`; "
              f"{spec.n_bootstrap} bootstrap replicates ({CONFIDENCE:.0%} percentile intervals), the same "
              f"design and resamples for every candidate (paired); seed {spec.seed}. Wall time "
              f"{result.runtime_s:.0f} s ({result.computed} candidates computed, {result.reused} reused).", "",
              "## Verdict", "", f"On the evidence the issue names ({_ids(result, True)}): "
              + result.verdict.statement(), ""]
    if "all" in result.verdicts:
        lines += [f"With the text's other checkable statements too ({_ids(result, False)}): "
                  + result.verdicts["all"].statement(), ""]
    w = spec.candidates[result.verdict.names.index(result.verdict.winner)]
    lines += [f"The winner, {w.name}: {w.description}.", ""]
    lines += _effects(result)
    best_on = "; ".join(f"{i}: {', '.join(n) if len(n) <= 6 else f'{len(n)} candidates'}"
                        for i, n in _item_verdict(result).best.items())
    lines += [f"Best on each item, or tied with the best within the paired intervals: {best_on}.", ""]
    lines += ["## How to read the scores", "",
              "Each column is one published result; each number is a candidate's *loss* against it "
              "(lower is better, 0 reproduces it) with its 95 % bootstrap interval, and in brackets the "
              "candidate's rank on it (1 = best; losses closer than 0.001 tie). The mean rank averages "
              "the items with equal weights; P(best) is the share of bootstrap replicates in which the "
              "candidate has the best mean rank. The intervals cover the Monte Carlo error of our "
              "indices only: the paper's own numbers (N = 10000, the Saltelli 2002 estimator) carry an "
              "error we do not know. They are percentile intervals of replicates; ranks and distances "
              "are not smooth in the indices, so an estimate can sit at the edge of its interval.", "",
              "| item | kind | in the issue | evidence | loss |", "|---|---|---|---|---|"]
    for e in ev:
        lines.append(f"| {e.id} | {e.group} | {'yes' if e.headline else 'no'} | {e.text} | "
                     f"{_LOSS_MEANING.get(e.group, '')} |")
    lines.append("")
    iv = _item_verdict(result)
    kinds = [("rankings and values", [i for i, e in enumerate(ev) if e.group in ("rankings", "values")]),
             ("Fig. 4, the statements, and overall", [i for i, e in enumerate(ev) if e.group not in ("rankings", "values")])]
    for title, items in kinds:
        head = [ev[i].id for i in items]
        extra = ["mean rank, issue's items", "mean rank, all items", "P(best)"] if title.startswith("Fig") else []
        if "all" not in result.verdicts:
            extra = extra[:1] + extra[2:]
        lines += [f"## Scores: {title}", "", "| candidate | " + " | ".join(head + extra) + " |",
                  "|---" * (len(head) + len(extra) + 1) + "|"]
        for k in order:
            cells = _loss_cells(result, k)
            row = [_cell(*cells[i], digits=2 if ev[i].group == "statements" else 3) + f" ({iv.ranks[k, i]:g})"
                   for i in items]
            if extra:
                for name in ("headline", "all"):
                    if name in result.verdicts:
                        vv = result.verdicts[name]
                        row.append(_cell(vv.mean_rank[k], *vv.mean_rank_ci[k], digits=1))
                row.append(f"{result.verdict.p_best[k]:.0%}")
            lines.append(f"| {iv.names[k]} | " + " | ".join(row) + " |")
        lines.append("")
    lines += _per_instant(result, order) + _per_output(result, order) + _frequency(result, order)
    lines += _lift(result, order) + _candidates(result)
    for k in _tabled(result):
        lines += _table_by_table(result, k)
    lines += _notes(result)
    return "\n".join(lines) + "\n"


def _effects(result) -> list[str]:
    effects = {name: main_effects(result, name) for name in result.verdicts}
    first = effects["headline"]
    if not first:
        return []
    ev = result.spec.evidence
    lines = ["### Each convention on its own", "",
             "For each factor of the candidate grid and each of its options: the mean rank of its "
             "candidates (averaged over every combination of the other factors), how far that is "
             "behind the factor's best option (a paired interval: above 0 means the option is worse "
             "beyond the Monte Carlo error), and the items on which its candidates' mean loss is the "
             "lowest of the factor's options.", "",
             "| factor | option | candidates | mean rank, issue's items | behind the best | mean rank, all items "
             "| behind the best | lowest mean loss on |", "|---|---|---|---|---|---|---|---|"]
    for f, options in first.items():
        for o, d in options.items():
            wins = [e.id for e in ev if d["losses"][e.id] <= min(x["losses"][e.id] for x in options.values()) + 1e-3]
            cells = []
            for name in ("headline", "all"):
                if name in effects:
                    dd = effects[name][f][o]
                    cells += [_cell(*dd["mean_rank"], digits=1), _cell(*dd["behind_best"], digits=1)]
                else:
                    cells += ["–", "–"]
            lines.append(f"| {f} | {o} | {d['n']} | " + " | ".join(cells) + f" | {', '.join(wins)} |")
    lines.append("")
    for name, label in (("headline", "On the issue's items"), ("all", "On all items")):
        if name in effects:
            lines.append(f"{label}, the best option of each convention: " + "; ".join(
                f"{f} {_best_option(options)}" for f, options in effects[name].items()) + ".")
    return lines + [""]


def _best_option(options: dict) -> str:
    """'B (clear: the next best is 3.1 [2.6, 8.0] behind)' or 'tank (tied with null)'."""
    ordered = sorted(options, key=lambda o: options[o]["mean_rank"][0])
    best, rest = ordered[0], ordered[1:]
    tied = [o for o in rest if options[o]["behind_best"][1] <= 0.0]
    if tied:
        return f"{best} (tied with {', '.join(tied)})"
    nxt = options[rest[0]]["behind_best"] if rest else [0.0, 0.0, 0.0]
    return f"{best} (clear: the next, {rest[0]}, {_cell(*nxt, digits=1)} behind)" if rest else best


def _per_instant(result, order) -> list[str]:
    lines = []
    for e in result.spec.evidence:
        if not isinstance(e, Values):
            continue
        labels = list(result.scores[0].details[e.id])
        lines += [f"## {e.id} per instant: RMS distance to {e.text[:7]} ({e.index} on {e.signal})", "",
                  "| candidate | " + " | ".join(labels) + " |", "|---" * (len(labels) + 1) + "|"]
        for k in order:
            d = result.scores[k].details[e.id]
            lines.append(f"| {result.verdict.names[k]} | " + " | ".join(_cell(*d[t], digits=2) for t in labels) + " |")
        lines.append("")
    return lines


def _per_output(result, order) -> list[str]:
    lines = []
    ev = result.spec.evidence
    for e in ev:
        if not isinstance(e, Ranking):
            continue
        labels = list(result.scores[0].details[e.id])
        lines += [f"## {e.id}: share of the published pairwise orders reproduced, per output", "",
                  f"{e.text}.", "", "| candidate | " + " | ".join(labels) + " |", "|---" * (len(labels) + 1) + "|"]
        for k in order:
            d = result.scores[k].details[e.id]
            lines.append(f"| {result.verdict.names[k]} | " + " | ".join(_cell(*d[t]) for t in labels) + " |")
        lines.append("")
    statements = [e for e in ev if isinstance(e, Statement)]
    if statements:
        lines += ["## Statements: the smallest margin of each (> 0: it holds)", "",
                  " ".join(f"{e.id}: {e.text}." for e in statements), "",
                  "| candidate | " + " | ".join(e.id for e in statements) + " |", "|---" * (len(statements) + 1) + "|"]
        for k in order:
            d = result.scores[k].details
            lines.append(f"| {result.verdict.names[k]} | "
                         + " | ".join(_cell(*d[e.id]["margin"], digits=2) for e in statements) + " |")
        lines.append("")
    return lines


def _frequency(result, order) -> list[str]:
    published = [e for e in result.spec.evidence if isinstance(e, Frequency)]
    if not published:
        return []
    e = published[0]
    lines = [f"## {e.id}: the linearised hydraulic natural frequency over the stroke", "",
             f"The hydraulic mode of the linearised model (valve centred, load held at rest) at "
             f"{result.spec.frequency_points} positions from the retracted end to the end stop "
             f"(`sam.capability`). The paper: {e.target_hz:g} Hz at most. The last column is the "
             f"nominal B_eff that would put the maximum at {e.target_hz:g} ± {e.reading_hz:g} Hz "
             f"(a fit, shown for the reader; no candidate uses it).", "",
             "| candidate | B_eff [MPa] | f_max [Hz] | at x [m] | B_eff for the paper's maximum [MPa] |",
             "|---|---|---|---|---|"]
    for k in order:
        f, cand = result.scores[k].frequency, result.spec.candidates[k]
        lo, mid, hi = (b / 1e6 for b in f["B_eff_implied_Pa"])
        lines.append(f"| {cand.name} | {cand.plant.fluid.B_eff / 1e6:.0f} | {f['f_max_hz']:.2f} | "
                     f"{f['x_at_max_m']:.3f} | {mid:.0f} [{lo:.0f}, {hi:.0f}] |")
    return lines + [""]


def _lift(result, order) -> list[str]:
    spec = result.spec
    masses = spec.lift_masses
    lines = [f"## Lift check: which loads each candidate lifts from x = {spec.lift_from_m:g} m", "",
             f"Static: the piston-side pressure that breaks the load away (F_S) at x = {spec.lift_from_m:g} m "
             f"and keeps it sliding (F_C) to the end stop, with the rod side at tank, against the "
             f"supply. Simulated: {spec.lift_duration_s:g} s at u = {spec.lift_u_V:g} V from rest. "
             f"Each cell: lifts or stalls (needed pressure), and the simulated travel.", "",
             "| candidate | largest load [kg] | " + " | ".join(f"{m:g} kg" for m in masses) + " |",
             "|---" * (len(masses) + 2) + "|"]
    for k in order:
        lift = result.scores[k].lift
        cells = []
        for row in lift["rows"]:
            verdict = "lifts" if row["lifts"] else f"stalls at {row['stalls_at']:.3f} m"
            cells.append(f"{verdict} ({row['pressure_needed'] / 1e6:.1f} MPa), {row['travel'] * 1e3:.0f} mm")
        lines.append(f"| {result.verdict.names[k]} | {lift['max_kg']:.0f} | " + " | ".join(cells) + " |")
    return lines + [""]


def _candidates(result) -> list[str]:
    lines = ["## Candidates", "",
             "| candidate | description | theta_level [rad] | cog_angle | B_eff [MPa] | initial condition | steady state |",
             "|---|---|---|---|---|---|---|"]
    duration = _duration(result)
    for c in result.spec.candidates:
        b, ini = c.plant.boom, c.initial
        press = {"null_leak": "null-leakage balance", "after_retraction": "after a retraction",
                 "tank": "tank pressure"}[ini.pressures]
        centred = f", then centred {ini.centred_s:g} s" if ini.centred_s else ""
        steady = f"value at {duration:g} s" if c.steady_from_s >= duration else f"mean over [{c.steady_from_s:g}, {duration:g}] s"
        lines.append(f"| {c.name} | {c.description} | {b.theta_level:.4f} | {math.degrees(b.cog_angle):+.0f}° | "
                     f"{c.plant.fluid.B_eff / 1e6:.0f} | x = {ini.x_m:g} m, {press}{centred} | {steady} |")
    return lines + [""]


def _duration(result) -> float:
    m = next(iter(result.spec.studies.values())).study.model
    return len(m.u) * m.dt


#: Studies of at most this many candidates get every candidate's table-by-table comparison;
#: larger ones the winner's and the first listed (today's model, by convention).
TABLED_ALL = 4


def _tabled(result) -> list[int]:
    names = result.verdict.names
    if len(names) <= TABLED_ALL:
        return list(range(len(names)))
    return list(dict.fromkeys([names.index(result.verdict.winner), 0]))


def _index_cell(score, study: str, index: str, signal: str, instant: str, factor: str, digits: int = 3) -> str:
    return _cell(*score.indices[study][index][signal][instant][factor], digits=digits)


def _table_by_table(result, k: int) -> list[str]:
    """The paper's tables and statements beside candidate k's, with our 95 % intervals."""
    score, cand = result.scores[k], result.spec.candidates[k]
    lines = [f"## {cand.name} against the paper, table by table", "", f"{cand.description}.", ""]
    for e in result.spec.evidence:
        if isinstance(e, Ranking):
            inst = instant_label(e.instant)
            signals = list(e.orders)
            lines += [f"### {e.text} ({e.id})", "", "| rank | " + " | ".join(f"{s} paper | {s} ours ({e.index})"
                                                                             for s in signals) + " |",
                      "|---" * (2 * len(signals) + 1) + "|"]
            ours = {s: sorted(e.orders[s], key=lambda f: -score.indices[e.study][e.index][s][inst][f][0]) for s in signals}
            for r in range(max(len(o) for o in e.orders.values())):
                cells = []
                for s in signals:
                    f = ours[s][r]
                    cells += [e.orders[s][r], f"{f} {_index_cell(score, e.study, e.index, s, inst, f)}"]
                lines.append(f"| {r + 1} | " + " | ".join(cells) + " |")
            lines.append("")
        elif isinstance(e, Values):
            factors = list(e.values)
            lines += [f"### {e.text} ({e.id}): ours [95 % interval] (paper)", "",
                      "| t | " + " | ".join(factors) + " |", "|---" * (len(factors) + 1) + "|"]
            for j, t in enumerate(e.instants):
                lines.append(f"| {instant_label(t)} | " + " | ".join(
                    f"{_index_cell(score, e.study, e.index, e.signal, instant_label(t), f)} ({e.values[f][j]:g})"
                    for f in factors) + " |")
            lines.append("")
        elif isinstance(e, Interaction):
            lines += [f"### {e.text} ({e.id})", "", "| output | paper | ours |", "|---|---|---|"]
            for sig, paper in e.values.items():
                s1 = score.indices[e.study]["S1"][sig][instant_label(e.instant)]
                lines.append(f"| {sig} | {paper:g} | {1 - sum(v[0] for v in s1.values()):.4f} |")
            lines.append("")
    f = score.frequency
    lines += [f"Fig. 4: the largest linearised natural frequency is {f['f_max_hz']:.2f} Hz at x = "
              f"{f['x_at_max_m']:.3f} m (the paper: 4.5 Hz at most).", ""]
    statements = [e for e in result.spec.evidence if isinstance(e, Statement)]
    if statements:
        lines += ["| statement | holds | smallest margin [95 %] |", "|---|---|---|"]
        for e in statements:
            m = score.details[e.id]["margin"]
            lines.append(f"| {e.id}: {e.text} | {'yes' if m[0] >= 0 else 'no'} | {_cell(*m, digits=3)} |")
        lines.append("")
    return lines


def _notes(result) -> list[str]:
    lines = ["## Notes", ""]
    for s in result.scores:
        if s.constant:
            lines.append(f"* {s.name}: outputs that did not vary (every index taken as 0): {', '.join(s.constant)}.")
    lines += ["* Mean ranks depend on which candidates are compared; the per-item columns do not.",
              "* The statements' thresholds are our reading of the text; they are in the study file.", ""]
    return lines


def _verdict_json(v) -> dict:
    return {"items": list(v.item_ids), "winner": v.winner, "runner_up": v.runner_up, "margin": v.margin,
            "margin_ci": list(v.margin_ci), "tied": v.tied, "group_winner": v.group_winner,
            "statement": v.statement()}


def to_json(result: ReconstructionResult) -> dict:
    spec, iv = result.spec, _item_verdict(result)
    cands = []
    for k, (c, s) in enumerate(zip(spec.candidates, result.scores)):
        cells = _loss_cells(result, k)
        cands.append({
            "name": c.name, "description": c.description, "settings": c.settings, "levels": c.levels,
            "losses": {e.id: list(cells[i]) for i, e in enumerate(spec.evidence)},
            "ranks": {e.id: float(iv.ranks[k, i]) for i, e in enumerate(spec.evidence)},
            "mean_rank": {n: [float(v.mean_rank[k]), *map(float, v.mean_rank_ci[k])] for n, v in result.verdicts.items()},
            "group_mean_rank": {n: float(v.group_rank[k]) for n, v in result.verdicts.items()},
            "p_best": {n: float(v.p_best[k]) for n, v in result.verdicts.items()},
            "details": s.details, "indices": s.indices, "frequency": s.frequency, "lift": s.lift,
            "constant_outputs": s.constant, "runtime_s": s.runtime_s,
        })
    return {
        "study": spec.name, "source": str(spec.source), "N": spec.N, "seed": spec.seed,
        "n_bootstrap": spec.n_bootstrap, "confidence": CONFIDENCE, "runtime_s": result.runtime_s,
        "evidence": [{"id": e.id, "group": e.group, "headline": e.headline, "text": e.text} for e in spec.evidence],
        "verdicts": {n: _verdict_json(v) for n, v in result.verdicts.items()},
        "best_per_item": iv.best,
        "main_effects": {n: main_effects(result, n) for n in result.verdicts},
        "candidates": cands,
    }


#: Rows of the scores figure: the best candidates by mean rank (and the first listed, today's).
FIGURE_ROWS = 20


#: Losses are coloured on one scale, from 0 (green: the paper's result) to this or more (red): a
#: quarter of the pairwise orders wrong, an RMS error of 0.25 in the indices, a frequency 25 % off,
#: a statement missed by 0.25 in an index.
LOSS_SCALE = 0.25


def _short(loss: float) -> str:
    return f"{loss:.2f}"[1:] if 0 <= loss < 0.995 else f"{loss:.1f}"


def plot_scores(result: ReconstructionResult, path: Path) -> Path:
    """The best candidates (rows, best first) by evidence item (columns), coloured by their rank
    among all candidates and labelled with the loss; beside each, its mean rank and interval."""
    v, iv, ev = result.verdict, _item_verdict(result), result.spec.evidence
    order = _order(result)
    rows = order[:FIGURE_ROWS] + ([0] if 0 not in order[:FIGURE_ROWS] else [])
    K, I, n = len(order), len(ev), len(rows)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(2.6 + 0.62 * I + 3.4, 1.9 + 0.34 * n),
                                  gridspec_kw={"width_ratios": [0.62 * I, 3.0]}, sharey=True)
    losses = np.stack([result.scores[k].point for k in rows])
    im = ax.imshow(losses, cmap="RdYlGn_r", vmin=0.0, vmax=LOSS_SCALE, aspect="auto")
    for r, k in enumerate(rows):
        for i in range(I):
            ax.text(i, r, _short(result.scores[k].point[i]), ha="center", va="center", fontsize=7)
    ax.set_xticks(range(I), [e.id + ("" if e.headline else "*") for e in ev], fontsize=8)
    ax.xaxis.tick_top()
    ax.set_yticks(range(n), [v.names[k] + ("  (listed first)" if k == 0 and k not in order[:FIGURE_ROWS] else "")
                             for k in rows], fontsize=8)
    ax.set_title("loss on each published result (0: the paper's result reproduced)\n"
                 "T: tables, F4: Fig. 4, Q: the text; * not named in the issue", fontsize=8.5)
    for name, marker, color, shift in (("headline", "o", "tab:green", -0.15), ("all", "s", "tab:blue", 0.15)):
        if name not in result.verdicts:
            continue
        vv = result.verdicts[name]
        m, ci = vv.mean_rank[rows], vv.mean_rank_ci[rows]
        y = np.arange(n) + shift
        # a percentile interval need not hold the mean of a skewed bootstrap: bars end at the point then
        err = np.clip([m - ci[:, 0], ci[:, 1] - m], 0.0, None)
        ax2.errorbar(m, y, xerr=err, fmt=marker, color=color, ms=4, capsize=2, lw=1,
                     label="issue's items" if name == "headline" else "all items")
    ax2.set_xlim(0.5, K + 0.5)
    ax2.grid(axis="x", alpha=0.3)
    ax2.set_xlabel(f"mean rank, {CONFIDENCE:.0%} interval (1 = best of {K})", fontsize=8.5)
    ax2.legend(fontsize=7.5, loc="lower right")
    ax2.set_title(f"winner: {v.winner}" + (" (tied)" if v.tied else ""), fontsize=9)
    fig.colorbar(im, ax=ax2, fraction=0.06, pad=0.03, label=f"loss (red: {LOSS_SCALE:g} or more)", extend="max")
    fig.suptitle(f"{result.spec.name}: the {n} best of {K} candidates against the paper's results", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_factors(result: ReconstructionResult, path: Path) -> Path | None:
    """Each convention on its own: for every option of every factor, the mean loss on each item
    of the candidates with that option, coloured by its rank within the factor."""
    effects = main_effects(result)
    if not effects:
        return None
    ev = result.spec.evidence
    labels, losses, mean_rank = [], [], []
    for f, options in effects.items():
        for o, d in options.items():
            labels.append(f"{f} = {o}")
            losses.append([d["losses"][e.id] for e in ev])
            mean_rank.append(d["mean_rank"][0])
    n, I = len(labels), len(ev)
    fig, ax = plt.subplots(figsize=(2.6 + 0.62 * I, 1.6 + 0.36 * n))
    im = ax.imshow(np.array(losses), cmap="RdYlGn_r", vmin=0.0, vmax=LOSS_SCALE, aspect="auto")
    for r, row in enumerate(losses):
        for i, loss in enumerate(row):
            ax.text(i, r, _short(loss), ha="center", va="center", fontsize=7)
    ax.set_xticks(range(I), [e.id + ("" if e.headline else "*") for e in ev], fontsize=8)
    ax.xaxis.tick_top()
    ax.set_yticks(range(n), [f"{lab}  (mean rank {m:.1f})" for lab, m in zip(labels, mean_rank)], fontsize=8)
    edges = np.cumsum([len(o) for o in effects.values()])[:-1] - 0.5
    for y in edges:
        ax.axhline(y, color="k", lw=1)
    ax.set_title("each convention on its own: mean loss of the candidates with that option\n"
                 "(0: the paper's result reproduced; * not named in the issue)", fontsize=8.5)
    fig.colorbar(im, ax=ax, fraction=0.03, pad=0.02, label=f"loss (red: {LOSS_SCALE:g} or more)", extend="max")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_reconstruction_report(result: ReconstructionResult, out: Path) -> list[Path]:
    """Write reconstruct.md, reconstruct.json and the figures into ``out``; returns the paths."""
    paths = []
    for name, text in (("reconstruct.md", summary_markdown(result)),
                       ("reconstruct.json", json.dumps(to_json(result), indent=1))):
        path = out / name
        tmp = path.with_name(f".{name}.tmp-{os.getpid()}")
        tmp.write_text(text)
        os.replace(tmp, path)
        paths.append(path)
    paths.append(plot_scores(result, out / "reconstruct.png"))
    factors = plot_factors(result, out / "reconstruct_factors.png")
    return paths + ([factors] if factors else [])
