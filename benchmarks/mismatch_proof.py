"""Run the mismatch diagnosis blind on a proof set recorded on the rig, score it, and tabulate.

    python benchmarks/mismatch_proof.py --set dev --out results/dev.jsonl [--case NAME ...]
    python benchmarks/mismatch_proof.py --set heldout --out results/heldout.jsonl
    python benchmarks/mismatch_proof.py --table results/heldout.jsonl      # the tables of docs/mismatch.md

Each case is recorded on the rig (benchmarks/mismatch_sets.py) and diagnosed with the default
plant file; its truth is used only here, to score. One JSON line per case, appended as it is
done: a killed run resumes where it stopped (cases already in --out are skipped).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

from scipy.stats import beta

import sam
from discrepancy import Settings, diagnose
from mismatch_sets import SETS, Case, record

#: The targets of the issue, by kind of case: (share, what it counts).
TARGETS = {"single": (0.90, "named first"), "clean": (0.95, "no effect named"),
           "unknown": (1.0, "not a known effect"), "pair": (0.70, "both named")}


def score(case: Case, report) -> dict:
    """Whether the diagnosis got ``case`` right, and what it found."""
    named = report.named
    if case.kind == "clean":
        ok = report.verdict in ("adequate", "recalibrated")
    elif case.kind == "unknown":
        ok = report.verdict == "unknown_effect"
    elif case.kind == "pair":
        ok = set(case.expect) <= set(named)
    else:
        ok = bool(named) and named[0] == case.expect[0]
    ft = report.fit_table
    final = "augmented" if "augmented" in ft else ("generic" if report.verdict == "unknown_effect" and "generic" in ft
                                                   else "calibrated")
    return {
        "case": case.name, "group": case.group or case.kind, "kind": case.kind, "loop": case.loop,
        "load_kg": case.load_kg, "rate_Hz": case.rate_Hz, "position": case.position, "magnitude": case.magnitude,
        "expected": " + ".join(case.expect) or "none", "verdict": report.verdict, "named": " + ".join(named) or "-",
        "ok": bool(ok), "fitted": {k: v for c in report.chosen for k, v in c.effect_values().items()},
        "runner_up": report.sureness.get("runner_up", "-"),
        "margin_bic_held": report.sureness.get("margin_bic_held"),
        "design": report.design.excitation.name if report.design else "",
        "floor_held": report.floor.pooled if report.floor else None,
        "generic": (report.generic or {}).get("equation", "") if report.verdict == "unknown_effect" else "",
        # the generic route's best term whatever the verdict, and the library form it maps to
        "generic_term": (report.generic or {}).get("equation", ""),
        "generic_effect": (report.generic or {}).get("library_effect"),
        "generic_significant": bool((report.generic or {}).get("significant_but_library",
                                                              (report.generic or {}).get("significant"))),
        "via_generic": any("through the generic route" in w for w in report.warnings),
        "held_nominal": ft["nominal"]["held"]["mean"], "held_calibrated": ft["calibrated"]["held"]["mean"],
        "held_final": ft[final]["held"]["mean"], "time_s": report.timings["total_s"],
        "ceiling_held": report.shortfall.get("ceiling_held", {}).get("mean"), "excess": report.shortfall.get("excess"),
        # every first-round candidate's evidence, to study the acceptance rule without re-running
        "first_round": [{"name": c.name, "accepted": c.accepted, "physical": c.physical, "dbic": c.delta_bic,
                         "seg_bic_fit": c.seg_bic_fit, "seg_bic_held": c.seg_bic_held, "dbic_held": c.delta_bic_held,
                         "gain_fit": c.gain_fit, "gain_held": c.gain_held, "fit_before": c.fit_before.get("mean"),
                         "fit_after": c.fit_after.get("mean"),
                         "specific": bool(c.specificity.passed) if c.specificity else None,
                         "segments": c.specificity.as_dict() if c.specificity else None,
                         "floor_pooled": report.floor.pooled if report.floor else None,
                         "values": c.effect_values()} for c in report.ranked],
    }


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) interval of a share k of n."""
    a = 1.0 - level
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def verdict(k: int, n: int, target: float) -> str:
    """met (the interval lies at or above the target), not met (below it), or undecided."""
    if n == 0:
        return "no cases"
    lo, hi = clopper_pearson(k, n)
    if target >= 1.0:
        return "met" if k == n else "not met"
    return "met" if lo >= target else ("not met" if hi < target else "undecided")


def interleaved(cases: list[Case]) -> list[Case]:
    """The cases group by group in turn (first of every group, then second, ...): a run stopped
    early has covered every group evenly."""
    groups: dict[str, list[Case]] = defaultdict(list)
    for c in cases:  # clean recordings twice a round (closed and open loop): the largest target
        groups[(c.group or c.kind) + (c.loop if c.kind == "clean" else "")].append(c)
    out = []
    for i in range(max(len(g) for g in groups.values())):
        out += [g[i] for g in groups.values() if i < len(g)]
    return out


def run(cases: list[Case], out: Path, plant: sam.Plant, settings: Settings = Settings()) -> None:
    done = set()
    if out.exists():
        done = {json.loads(line)["case"] for line in out.read_text().splitlines() if line.strip()}
    out.parent.mkdir(parents=True, exist_ok=True)
    for case in cases:
        if case.name in done:
            continue
        rec = record(case).measured()
        t0 = time.perf_counter()
        try:
            rep = diagnose(rec, plant, None, figures=False, settings=settings)
        except Exception as e:  # a crash is a result too: scored wrong, the run goes on
            row = {"case": case.name, "group": case.group or case.kind, "kind": case.kind, "ok": False,
                   "error": f"{type(e).__name__}: {e}", "time_s": time.perf_counter() - t0}
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(f"{case.name:44s} ERROR {row['error']}", flush=True)
            continue
        row = score(case, rep)
        row["time_s"] = time.perf_counter() - t0
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(f"{row['case']:44s} {'ok ' if row['ok'] else 'NO '} {row['verdict']:14s} {row['named']:36s} "
              f"{row['held_nominal']:6.1f} -> {row['held_calibrated']:5.1f} -> {row['held_final']:5.1f} "
              f"{row['time_s']:5.1f} s", flush=True)


def tables(rows: list[dict], quiet: bool = False) -> str:
    """The per-case table and the summary against the targets (markdown)."""
    lines = ["| case | loop, load, logger | concealed | expected | verdict: named (runner-up, its held-out BIC margin) "
             "| ok | held-out fit nominal -> calibrated -> final | time |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['case']} | | | | error: {r['error']} | **no** | | {r['time_s']:.0f} s |")
            continue
        found = r["named"]
        if r["verdict"] == "unknown_effect":
            found = f"not a known effect: `{r['generic']}`"
        if r["runner_up"] not in ("-", None) and r["named"] != "-":
            margin = r.get("margin_bic_held")
            found += f" ({r['runner_up']}" + (f", {margin:+.0f}" if margin is not None else "") + ")"
        logger = f"{r['loop']}, {r['load_kg']:.0f} kg" + (f", {r['rate_Hz']:.0f} Hz" if r["rate_Hz"] != 1000 else "") \
            + (", theta" if r["position"] == "theta" else "")
        lines.append(f"| {r['case']} | {logger} | {r['magnitude']} | {r['expected']} | {r['verdict']}: {found} | "
                     f"{'yes' if r['ok'] else '**no**'} | {r['held_nominal']:.1f} -> {r['held_calibrated']:.1f} -> "
                     f"{r['held_final']:.1f} | {r['time_s']:.0f} s |")
    lines += ["", "| kind | cases | right | rate [95 % interval] | target | verdict |", "|---|---|---|---|---|---|"]
    by_kind = defaultdict(list)
    by_group = defaultdict(list)
    for r in rows:
        by_kind[r["kind"]].append(r["ok"])
        by_group[r["group"]].append(r["ok"])
    for kind, (target, what) in TARGETS.items():
        k, n = sum(by_kind[kind]), len(by_kind[kind])
        if n:
            lo, hi = clopper_pearson(k, n)
            lines.append(f"| {kind} ({what}) | {n} | {k} | {k / n:.0%} [{lo:.0%}, {hi:.0%}] | {target:.0%} | "
                         f"{verdict(k, n, target)} |")
    rows = [r for r in rows if "error" not in r] + [r for r in rows if "error" in r]
    improved = [r["held_final"] > r["held_calibrated"] for r in rows if r.get("named", "-") != "-"]
    lines.append(f"| held-out fit improves where an effect is named | {len(improved)} | {sum(improved)} | | all | "
                 f"{'met' if all(improved) else 'not met'} |")
    worst = max(r["time_s"] for r in rows)
    # wall time: a verdict only when the run had the machine to itself (--quiet), never on a shared one
    lines.append(f"| time per recording (wall) | {len(rows)} | | median {sorted(r['time_s'] for r in rows)[len(rows) // 2]:.0f} s, "
                 f"worst {worst:.0f} s | <= 60 s | "
                 f"{('met' if worst <= 60 else 'not met') if quiet else 'undecided (shared machine)'} |")
    lines += ["", "| effect | cases | right | rate [95 % interval] |", "|---|---|---|---|"]
    for group, oks in sorted(by_group.items()):
        k, n = sum(oks), len(oks)
        lo, hi = clopper_pearson(k, n)
        lines.append(f"| {group} | {n} | {k} | {k / n:.0%} [{lo:.0%}, {hi:.0%}] |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=sorted(SETS), default="dev")
    ap.add_argument("--out", type=Path, help="JSON lines, one per case (appended; resumes)")
    ap.add_argument("--case", action="append", help="only these cases (repeatable)")
    ap.add_argument("--group", action="append", help="only the cases of these groups (repeatable)")
    ap.add_argument("--table", type=Path, help="print the tables of a finished run and stop")
    ap.add_argument("--setting", action="append", default=[], metavar="NAME=VALUE",
                    help="a discrepancy.Settings knob other than its default (repeatable), e.g. excess_limit=inf")
    ap.add_argument("--quiet", action="store_true", help="the run had the machine to itself: judge the time target")
    args = ap.parse_args(argv)
    if args.table:
        print(tables([json.loads(line) for line in args.table.read_text().splitlines() if line.strip()], args.quiet))
        return 0
    if args.out is None:
        ap.error("--out is needed to run a set")
    cases = [c for c in SETS[args.set]() if (not args.case or c.name in args.case)
             and (not args.group or c.group in args.group)]
    knobs = dict(kv.split("=", 1) for kv in args.setting)
    settings = dataclasses.replace(Settings(), **{k: type(getattr(Settings(), k))(v) for k, v in knobs.items()})
    run(interleaved(cases), args.out, sam.load_plant(), settings)
    return 0


if __name__ == "__main__":
    sys.exit(main())
