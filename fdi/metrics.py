"""The tune's figures: rates with exact intervals, per fault case, load third and leak flow,
the smallest sizes met, the ROC data and the bound; metrics.json, metrics.md and rates.png.

A case's runs come as arrays per run (fdi.tune's chunks): per hypothesis the first alarm and the
maxima of g/h before the onset, within the scored second and over the run; the onset sample; the
load; the bank's verdicts (the alarm that stood, the fault named and when); the flow a leak
passed; the bound's evidence.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from . import bound as onset_bound
from . import rates
from .faults import HYPOTHESES
from .figures import rates_figure
from .isolation import margin_for
from .montecarlo import LONG_CYCLES, TUNE
from .synth import POSITION_SENSORS
from .thresholds import Thresholds

HYP = tuple(HYPOTHESES)
#: how each position sensor is simulated (fdi.synth.POSITION_SENSORS), for metrics.md
POSITION_SENSOR_TEXT = {"encoder": "the joint angle from the quantised encoder",
                        "linear": f"x from a linear transducer, white noise {POSITION_SENSORS['linear']['x_noise'] * 1e6:g} um"}


def _load_bin(m):
    return np.digitize(m, [b[1] for b in TUNE.load_bins_kg[:-1]])


def analyse(cases: dict, th: Thresholds) -> dict:
    """The metrics of a tune's runs under the thresholds ``th``: ``cases``, case name ("healthy",
    "healthy_long", "K_int_0.25", ...) -> its runs' per-run arrays (fdi.tune's chunk keys). Rates
    are fractions of runs with their exact intervals (fdi.rates), delays in s."""
    healthy = cases["healthy"]
    hmax = healthy["max"][:, :, 2].max(axis=1)  # per run: max over hypotheses of g/h
    level = th.derived.false_alarm_level
    fa = healthy_rates(healthy, level)
    scales = np.geomspace(0.25, 4, 17)
    roc = {"scale": scales.tolist(), "false_alarm": [float((hmax > s).mean()) for s in scales], "detection": {}}
    has_bound = "evidence" in healthy
    bnd = None
    if has_bound:
        bnd = (onset_bound.threshold(healthy["evidence"], level), margin_for(th.confirmation.false_isolation_level))
    rows = []
    for fault, sizes in TUNE.fault_sizes.items():
        for size in sizes:
            name = f"{fault}_{size:g}"
            d = cases[name]
            rows.append(fault_row(d, fault, size, bnd))
            ok_pre = d["max"][:, :, 0].max(axis=1)
            post = d["max"][:, :, 1].max(axis=1)
            roc["detection"][name] = [float(((post > s) & (ok_pre <= s)).mean()) for s in scales]
    smallest, smallest_by_load, smallest_bound, smallest_shown = _smallest_sizes(rows, has_bound)
    n_dec = sum(r["decisions_within_1s"] for r in rows)
    n_wrong = sum(r["wrong_decisions"] for r in rows)
    metrics = {"false_alarm_rate": fa["false_alarm_rate"], "false_alarm_by_load": fa["false_alarm_by_load"],
               "healthy_runs": fa["runs"], "trigger_rate": fa["trigger_rate"],
               **{k: fa[k] for k in ("false_alarms", "false_alarm_ci", "false_alarm_verdict")},
               "healthy_run_s": th.derived.run_length_s, "fault_run_s": TUNE.fault_run_s,
               "load_bins_kg": TUNE.load_bins_kg, "thresholds_source": th.derived.source, "isolation": "likelihood", "rows": rows,
               "isolation_decisions_within_1s": n_dec, "wrong_isolation_decisions": n_wrong,
               "wrong_isolation_rate": n_wrong / n_dec if n_dec else float("nan"),
               "smallest_detected_and_isolated_95pct_within_1s": smallest,
               "smallest_detected_and_isolated_95pct_within_1s_by_load": smallest_by_load,
               "smallest_shown_95pct_within_1s": smallest_shown, "roc": roc}
    flows = _flow_totals(rows)
    if flows:
        metrics["flow_bins_lpm"], metrics["isolated_by_flow"] = TUNE.flow_bins_lpm, flows
    if "healthy_long" in cases:
        long = healthy_rates(cases["healthy_long"], level)
        metrics["long_cycles"] = long
        k, n = fa["false_alarms"] + long["false_alarms"], fa["runs"] + long["runs"]
        metrics["all_healthy"] = {"runs": n, "false_alarm_rate": k / n, **_false_alarm_count(k, n, level)}
    if has_bound:
        metrics["bound"] = {"threshold_nats": bnd[0], "level": level, "margin_nats": bnd[1],
                            "healthy_runs": int(len(hmax)),
                            "smallest_isolable_95pct": smallest_bound}
    return metrics


def write_report(out_dir: Path, metrics: dict, th: Thresholds, reference: bool = False) -> None:
    """metrics.json (no NaN: null), metrics.md and rates.png into ``out_dir``."""
    write_json(Path(out_dir) / "metrics.json", metrics)
    (Path(out_dir) / "metrics.md").write_text("\n".join(_markdown(metrics, th, reference)) + "\n")
    rates_figure(Path(out_dir) / "rates.png", metrics, th.derived.false_alarm_level, TUNE.target_rate, rates.interval)


def healthy_rates(d: dict, level: float) -> dict:
    """The false-alarm figures of loaded healthy chunks ``d``: runs, false-alarm rate (runs with an
    alarm that stood: the bank confirmed it, when the chunks have the bank's verdicts; else any
    alarm), its :func:`fdi.rates.interval` and :func:`fdi.rates.verdict` against the stated
    false-alarm ``level``, the rate per load third (NaN: no run there) and the trigger rate (runs
    with any CUSUM alarm, confirmed or withdrawn)."""
    trigger_runs = d["max"][:, :, 2].max(axis=1) > 1.0
    fa_runs = d["conf_k"] >= 0 if "conf_k" in d else trigger_runs
    lb = _load_bin(d["m_L"])
    return {"runs": int(len(fa_runs)), "false_alarm_rate": float(fa_runs.mean()),
            **_false_alarm_count(int(fa_runs.sum()), len(fa_runs), level),
            "false_alarm_by_load": [float(fa_runs[lb == i].mean()) if (lb == i).any() else float("nan")
                                    for i in range(len(TUNE.load_bins_kg))],
            "trigger_rate": float(trigger_runs.mean())}


def _false_alarm_count(k: int, n: int, level: float) -> dict:
    """false_alarms (k), false_alarm_ci and false_alarm_verdict (<= ``level``) of k false alarms
    in n healthy runs."""
    return {"false_alarms": k, "false_alarm_ci": list(rates.interval(k, n)),
            "false_alarm_verdict": rates.verdict(k, n, level, at_least=False)}


def fault_row(d: dict, fault: str, size: float, bnd: tuple | None) -> dict:
    """The metrics.json row of one fault case from its loaded chunks ``d``; ``bnd``: the bound's
    (threshold, margin) [nats] or None. 'wrong_isolation' = fraction of the decisions taken within
    1 s of the onset (the bank's) that named another fault hypothesis: the rate the stated
    false-isolation level is about."""
    k0 = d["k_onset"]  # (runs,) each run's own onset
    first = np.where(d["first"] >= 0, d["first"], 10**9)
    any_alarm = np.where(d["conf_k"] >= 0, d["conf_k"], 10**9)  # the first alarm that stood (the bank confirmed it)
    before = any_alarm < k0  # alarm before the onset: a false alarm, not a detection
    detected = (any_alarm < 10**9) & ~before
    within = detected & ((any_alarm - k0) * TUNE.dt <= TUNE.within_s)
    right = ("offset+" if size > 0 else "offset-") if fault == "offset" else fault
    ri = HYP.index(right)
    # the bank's decision, taken within 1 s of the onset
    decided = within & (d["iso_h"] >= 0) & (d["iso_k"] >= k0) & ((d["iso_k"] - k0) * TUNE.dt <= TUNE.within_s)
    isolated = decided & (d["iso_h"] == ri)
    wrong = decided & (d["iso_h"] != ri)
    delay = (any_alarm[detected] - k0[detected]) * TUNE.dt
    lb = _load_bin(d["m_L"])
    row = {
        "fault": fault, "size": size, "unit": "%" if fault == "offset" else "L/min", "runs": int(len(first)),
        "detected_within_1s": float(within.mean()), "isolated_within_1s": float(isolated.mean()),
        "isolated_exclusive": float(isolated.mean()), "alarm_before_onset": float(before.mean()),
        "mean_delay_s": float(delay.mean()) if delay.size else float("nan"),
        "isolated_runs": int(isolated.sum()), "isolated_ci": list(rates.interval(isolated.sum(), len(first))),
        "isolated_verdict": rates.verdict(isolated.sum(), len(first), TUNE.target_rate),
        "isolated_by_load": [float(isolated[lb == i].mean()) if (lb == i).any() else float("nan")
                             for i in range(len(TUNE.load_bins_kg))],
        "wrong_isolation": float(wrong.sum() / decided.sum()) if decided.any() else float("nan"),
        "decisions_within_1s": int(decided.sum()), "wrong_decisions": int(wrong.sum()),
    }
    if "leak_flow_lpm" in d:  # leak runs only: an offset passes no flow
        row["leak_flow_median_lpm"] = float(np.median(d["leak_flow_lpm"]))
        row["isolated_by_flow"] = _by_flow(isolated, d["leak_flow_lpm"])
    if "size_value" in d:
        row.update(size_scores(d, isolated))
    if bnd is not None:
        ok, iso = onset_bound.verdicts(d["evidence"], fault, *bnd)
        row.update({"bound_detectable": float(ok.mean()), "bound_isolable": float(iso.mean()),
                    "bound_isolable_ci": list(rates.interval(iso.sum(), len(iso))),
                    "bound_median_nats": float(np.median(d["evidence"][:, onset_bound.HYPOTHESES.index(fault)]))})
    return row


def size_scores(d: dict, isolated: np.ndarray) -> dict:
    """The size figures of a case's isolated runs (``d``: ``size_value``, ``size_lo``, ``size_hi``
    as reported and ``true_size``, in one unit): the median relative error with its interval and
    verdict (within +-TUNE.size_bias) and the fraction whose truth lies inside the reported +-2
    sigma with its interval and verdict (>= TUNE.size_coverage)."""
    sized = isolated & np.isfinite(d["size_value"])
    true = d["true_size"][sized]
    err = d["size_value"][sized] / true - 1.0
    inside = (d["size_lo"][sized] <= true) & (true <= d["size_hi"][sized])
    ci = rates.median_interval(err)
    n, k = int(sized.sum()), int(inside.sum())
    return {"sized_runs": n, "size_error_median": float(np.median(err)) if n else float("nan"),
            "size_error_ci": list(ci), "size_error_verdict": rates.within(ci, -TUNE.size_bias, TUNE.size_bias),
            "size_inside_2sigma": k / n if n else float("nan"), "size_inside_ci": list(rates.interval(k, n)),
            "size_inside_verdict": rates.verdict(k, n, TUNE.size_coverage)}


def _by_flow(isolated: np.ndarray, flow_lpm: np.ndarray) -> list:
    """[[isolated, runs], ...] per bin of TUNE.flow_bins_lpm of the flow each run's leak passed."""
    b = np.digitize(flow_lpm, TUNE.flow_bins_lpm)
    return [[int(isolated[b == i].sum()), int((b == i).sum())] for i in range(len(TUNE.flow_bins_lpm) + 1)]


def _flow_totals(rows: list) -> dict:
    """{leak: [[isolated, runs], ...] per flow bin, every size of that leak together} of the rows
    that have flows (none: {})."""
    out = {}
    for r in (r for r in rows if "isolated_by_flow" in r):
        tot = out.setdefault(r["fault"], [[0, 0] for _ in r["isolated_by_flow"]])
        for t, (k, n) in zip(tot, r["isolated_by_flow"]):
            t[0] += k
            t[1] += n
    return out


def _smallest_sizes(rows: list, has_bound: bool) -> tuple:
    """({key: smallest |size| met}, {key: [per load third]}, {key: the bound's}, {key: smallest
    |size| shown met by its interval}) with keys K_int, K_extA, K_extB, offset+, offset-
    (:func:`smallest_met`; sizes as in TUNE.fault_sizes)."""
    smallest, smallest_by_load, smallest_bound, smallest_shown = {}, {}, {}, {}
    for fault in TUNE.fault_sizes:
        for sign in ((1, -1) if fault == "offset" else (1,)):
            mine = [r for r in rows if r["fault"] == fault and np.sign(r["size"]) == sign]
            key = fault if fault != "offset" else ("offset+" if sign > 0 else "offset-")
            smallest[key] = smallest_met(mine, lambda r: r["isolated_within_1s"] >= TUNE.target_rate)
            smallest_shown[key] = smallest_met(mine, lambda r: r["isolated_verdict"] == "met")
            if has_bound:
                smallest_bound[key] = smallest_met(mine, lambda r: r["bound_isolable"] >= TUNE.target_rate)
            smallest_by_load[key] = [smallest_met(mine, lambda r, b=b: r["isolated_by_load"][b] >= TUNE.target_rate)
                                     for b in range(len(TUNE.load_bins_kg))]
    return smallest, smallest_by_load, smallest_bound, smallest_shown


def write_json(path: Path, obj) -> None:
    """``obj`` as JSON with every NaN / inf as null (json.dumps would write NaN: not JSON)."""
    path.write_text(json.dumps(_json_safe(obj), indent=2, allow_nan=False) + "\n")


def _json_safe(x):
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    return x


def _f2(v: float, digits: int = 2) -> str:
    """A rate or delay for metrics.md: ``digits`` decimals, '-' for none (NaN: no run to average)."""
    return "-" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _size_text(key: str, v: float | None) -> str:
    """A smallest size for metrics.md with its unit: offsets (fractions of spool travel) in %,
    leaks in L/min at 10 MPa; 'none': not met even at the largest tested size."""
    if v is None:
        return "none"
    return f"{abs(v) * 100:g} %" if key.startswith("offset") else f"{abs(v):g} L/min"


def _size_table(label_values: list) -> list:
    """A Markdown table of smallest sizes: one column per fault key, one row per (label, {key: size})."""
    keys = list(label_values[0][1])
    return (["| | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
            + [f"| {label} | " + " | ".join(_size_text(k, vals[k]) for k in keys) + " |"
               for label, vals in label_values])


def _markdown(m: dict, th: Thresholds, reference: bool) -> list:
    """The lines of metrics.md from the metrics ``m`` of :func:`analyse`."""
    bins = [f"{int(a)}-{int(round(b))} kg" for a, b in TUNE.load_bins_kg]
    wr = m["wrong_isolation_rate"]
    lines = ["# FDI tuning metrics", "",
             f"Thresholds: {th.derived.source} (not fitted to these runs).", "",
             *([] if m.get("source", "sam") == "sam" else
               [f"Runs recorded by the {m['source']} (`--source {m['source']}`), each scored as `fdi evaluate` scores "
                "a labelled recording: healthy runs of 20-60 s, fault runs with onsets at 4-8 s (the texts on inputs "
                "and onsets below are the sam runs'; rig/population.py says how the runs are drawn).", ""]),
             f"Position sensor: {th.derived.position_sensor} ({POSITION_SENSOR_TEXT[th.derived.position_sensor]}), as the "
             "thresholds were derived for.", "",
             *([f"Every machine was first calibrated on a healthy {TUNE.reference_s:g} s reference recording of its own (another "
                 "load and input): `--reference`, as `fdi replay --reference` does.", ""] if reference else []),
             "Held-out healthy runs (the studies' sine, 2-4 s cycle and PRBS inputs): "
             + _healthy_line({**m, "runs": m["healthy_runs"]}, th, bins)
             + ("" if th.derived.trigger_level is None else
                f" (the h were set for {th.derived.trigger_level:g} of the nuisance study's healthy runs)"), "",
             *([f"Held-out healthy runs of the issue's 20-60 s extend/retract cycles (random period, amplitude "
                f"{LONG_CYCLES['amplitude_V'][0]:g}-{LONG_CYCLES['amplitude_V'][1]:g} V, phase and start position: "
                "some long strokes end on an end stop, some reverse in mid-stroke; not in the threshold studies): "
                + _healthy_line(m["long_cycles"], th, bins), "",
                f"All {m['all_healthy']['runs']} healthy runs: false-alarm rate "
                + _false_alarm_text(m["all_healthy"], th), ""]
               if "long_cycles" in m else []),
             f"Isolation decisions within 1 s of the onset (fault runs detected within 1 s): "
             f"{m['isolation_decisions_within_1s']}, of which wrong (named another fault hypothesis): "
             f"{m['wrong_isolation_decisions']}" + (f" = {wr:.3f}" if math.isfinite(wr) else ""), "",
             f"Each fault run steps in at its own onset, uniform in [{TUNE.onset_range_s[0]:g}, {TUNE.onset_range_s[1]:g}] s; "
             "'within 1 s', 'before onset' and the delay are per run from its own onset. "
             "'isolated' = detected within 1 s and "
             "the likelihood bank named the fault by 1 s after the onset (data up to its decision only). "
             "'wrong isolation' = fraction of the decisions within 1 s of the onset (the bank's) that named "
             "another fault hypothesis.", "",
             *_interval_lines(m["rows"])]
    cols = ["fault", "size", "runs", "within 1 s", "isolated", f"isolated: {rates.LEVEL * 100:g} % interval",
            f"vs {TUNE.target_rate * 100:g} %",
            "wrong isolation", "alarm before onset", "mean delay [s]", *(f"isolated {b}" for b in bins)]
    sized = all("size_error_median" in r for r in m["rows"])
    if sized:
        cols += ["median size error [%]", "its interval", "truth inside +-2 sigma", "its interval"]
    lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in m["rows"]:
        cells = [r["fault"], _row_size(r), str(r["runs"]), _f2(r["detected_within_1s"]), _f2(r["isolated_within_1s"]),
                 _interval_text(r["isolated_ci"]), r["isolated_verdict"],
                 _f2(r["wrong_isolation"]),
                 _f2(r["alarm_before_onset"]), _f2(r["mean_delay_s"]), *(_f2(v) for v in r["isolated_by_load"])]
        if sized:
            cells += [_f2(100 * r["size_error_median"], 1), _interval_text([100 * v for v in r["size_error_ci"]], 1),
                      _f2(r["size_inside_2sigma"]), _interval_text(r["size_inside_ci"])]
        lines.append("| " + " | ".join(cells) + " |")
    smallest, by_load = m["smallest_detected_and_isolated_95pct_within_1s"], \
        m["smallest_detected_and_isolated_95pct_within_1s_by_load"]
    lines += ["", "Smallest size detected and isolated within 1 s in >= 95 % of runs (that size and every larger "
              "tested size; per load third about a third of the runs each; 'none': not even the largest):", ""]
    lines += _size_table([("all loads", smallest),
                          (f"all loads, shown by the {rates.LEVEL * 100:g} % interval", m["smallest_shown_95pct_within_1s"])]
                         + [(b, {k: v[i] for k, v in by_load.items()}) for i, b in enumerate(bins)])
    if "isolated_by_flow" in m:
        lines += _flow_lines(m["isolated_by_flow"], m["flow_bins_lpm"])
    if "bound" in m:
        lines += _bound_lines(m["rows"], m["bound"], smallest)
    lines += ["",
              "Thresholds (CUSUM h [sigma s], drift %.2g sigma): %s" % (th.test.drift, json.dumps(th.test.h))]
    return lines


def _healthy_line(r: dict, th: Thresholds, bins: list) -> str:
    """metrics.md's words for the false-alarm figures ``r`` of a healthy population
    (:func:`healthy_rates`: ``runs``, ``false_alarm_rate``, ``false_alarm_by_load``, ``trigger_rate``)."""
    return (f"{r['runs']} x {th.derived.run_length_s:g} s; false-alarm rate (any alarm "
            f"{'that the bank confirmed ' if th.confirmation.confirm_nats > 0 else ''}per run): "
            f"{_false_alarm_text(r, th)}; by load " + ", ".join(f"{b}: {_f2(v, 3)}"
                                                                 for b, v in zip(bins, r["false_alarm_by_load"]))
            + f"; runs with any CUSUM alarm (confirmed or withdrawn): {r['trigger_rate']:.3f}")


def _false_alarm_text(r: dict, th: Thresholds) -> str:
    """A population's false-alarm rate with its count, interval and verdict against the stated level."""
    return (f"{r['false_alarm_rate']:.3f} ({r['false_alarms']} of {r['runs']}; {rates.LEVEL * 100:g} % "
            f"interval {_interval_text(r['false_alarm_ci'], 4)}; <= {th.derived.false_alarm_level:g}: {r['false_alarm_verdict']})")


def _flow_lines(by_flow: dict, edges: list) -> list:
    """metrics.md's table of isolation within 1 s by the flow the leak passed (:func:`_flow_totals`)."""
    heads = [f"< {edges[0]:g}"] + [f"{a:g}-{b:g}" for a, b in zip(edges[:-1], edges[1:])] + [f">= {edges[-1]:g}"]
    lines = ["", "Isolated within 1 s by the flow the leak passed in its scored second (Eqs. (41)-(43) at the run's "
             "true pressures; a leak rated at 10 MPa passes K sqrt(dp) at the machine's own pressure difference: "
             "K_int less where p_A and p_B balance, K_extB less where p_B is low), every size of a leak together, "
             "isolated / runs:", "", "| leak | " + " | ".join(f"{h} L/min" for h in heads) + " |",
             "|---|" + "---|" * len(heads)]
    for leak, cells in by_flow.items():
        lines.append(f"| {leak} | " + " | ".join(f"{k}/{n}" if n else "-" for k, n in cells) + " |")
    return lines


def _interval_lines(rows: list) -> list:
    """metrics.md's words on the rates' intervals, with the runs a case needs to show the target."""
    need = rates.runs_to_show(TUNE.target_rate)
    few = min(r["runs"] for r in rows) < need
    return [f"Each rate is k of n runs. Its {rates.LEVEL * 100:g} % interval is the exact (Clopper-Pearson) one, "
            f"fdi/rates.py; 'vs {TUNE.target_rate * 100:g} %' is 'met' where the whole interval lies above "
            f"{TUNE.target_rate * 100:g} %, "
            "'not met' where it lies below, else 'undecided' at this many runs. Even with no miss, a case shows "
            f"{TUNE.target_rate * 100:g} % only from {need} runs on" + (" (more --runs)." if few else "."), ""]


def _interval_text(ci: list, digits: int = 2) -> str:
    """A rate's interval [low, high] for metrics.md: 'low-high' ('-' where nothing was measured)."""
    return "-" if not all(math.isfinite(v) for v in ci) else f"{ci[0]:.{digits}f}-{ci[1]:.{digits}f}"


def _row_size(r: dict) -> str:
    """A row's fault size with sign and unit (offsets in %)."""
    return f"{r['size'] * (100 if r['fault'] == 'offset' else 1):+g} {r['unit']}"


def _bound_lines(rows: list, b: dict, ours: dict) -> list:
    """The metrics.md section of ``--bound``: our detector against the evidence at the known onset;
    ``ours``: our smallest sizes met, next to the bound's."""
    lines = ["", "## What the data carry within 1 s of the onset (`--bound`, fdi/bound.py)", "",
             "A bank started at the TRUE onset (which no detector knows), calibration as uncertain constants. "
             f"'detectable': its evidence for the true fault beats {b['threshold_nats']:.1f} nats, what the best "
             f"fault hypothesis beats in {b['level']:.0%} of the healthy runs; 'isolable': and it beats every other "
             f"fault by the isolation margin {b['margin_nats']:.1f} nats (the threshold is at least "
             f"ln(1 / {b['level']:g}) = {np.log(1 / b['level']):.1f} nats). A bound on what a likelihood test could do "
             "with this nuisance model, not a detector.", "",
             *([f"**Rough:** the threshold is read from {b['healthy_runs']} healthy runs; a {b['level']:.0%} quantile "
                f"needs at least {onset_bound.enough_healthy_runs(b['level'])} (--runs).", ""]
               if b["healthy_runs"] < onset_bound.enough_healthy_runs(b["level"]) else []),
             "| fault | size | ours: isolated within 1 s | bound: detectable | bound: isolable | "
             f"bound: isolable, {rates.LEVEL * 100:g} % interval | median evidence [nats] |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['fault']} | {_row_size(r)} | {_f2(r['isolated_within_1s'])} | {_f2(r['bound_detectable'])} | "
                     f"{_f2(r['bound_isolable'])} | {_interval_text(r['bound_isolable_ci'])} | "
                     f"{r['bound_median_nats']:.0f} |")
    return lines + ["", "Smallest size in >= 95 % of runs (that size and every larger tested size; 'none': not "
                    "even the largest):", ""] + _size_table([("ours: detected and isolated within 1 s", ours),
                                                              ("bound: isolable", b["smallest_isolable_95pct"])])


def smallest_met(rows: list, passes) -> float | None:
    """The smallest |size| of ``rows`` from which on EVERY larger tested size also ``passes(row)``
    (None: not even the largest). A size that passes below one that fails is a lucky draw, not a
    size the tool can be trusted at. A NaN rate (a load third with no runs of that size) fails."""
    met = None
    for r in sorted(rows, key=lambda r: -abs(r["size"])):
        if not passes(r):
            break
        met = abs(r["size"])
    return met
