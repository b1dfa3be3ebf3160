"""``samfdi fdi evaluate``: the detector scored on a folder of labelled recordings, from any
source (the rig, ``sam``, a lab's own labelled runs), exactly as the tune scores its Monte Carlo.

Each recording is labelled by its ``true_*`` columns (:func:`label`: healthy, or one fault with
its size and onset), replayed as ``fdi replay`` replays it (:func:`fdi.offline.prepare`, the
shipped filter, its own baseline) and scored by :mod:`fdi.scoring`; the cases (fault and size)
become rates with intervals by :mod:`fdi.metrics`. Alarms before a fault's onset are false
alarms, never detections. One chunk per recording in a :class:`chunkstore.Store` under the
output folder: a killed evaluation resumes, and recordings added to the folder later are scored
on the next run.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from chunkstore import MANIFEST, Store, StoreError, compute
from sam import Plant, UserError, read_recording
from sam.errors import output_folder
from sam.hydraulics import leak_lpm as leak_lpm_of

from . import bound as onset_bound
from . import rates
from .config import FilterConfig
from .faults import FAULTS
from .filter import run_filter
from .isolation import margin_for
from .metrics import fault_row, healthy_rates, write_json
from .montecarlo import TUNE
from .offline import own_noise, prepare
from .recording import decimation, study_rate
from .scoring import bank_decisions, window_maxima
from .statistics import statistics
from .thresholds import Thresholds

#: the fault parameters' truth columns (docs/recordings.md)
TRUTH = {f: f"true_{f}" for f in FAULTS}
SUFFIXES = (".csv", ".mat")
OUTPUTS = ("evaluation.md", "evaluation.json", "evaluation.png")
#: a truth value counts as a fault above this: leaks in L/min at 10 MPa, the offset as a fraction
PRESENT = {"leak_lpm": 1e-3, "offset": 1e-4}
LAYOUT = {"chunks": "<recording>_<stamp>.npz: its label and scores (fdi.evaluate.score_recording)"}


@dataclass(frozen=True)
class Label:
    """What a recording's ``true_*`` columns say: healthy (``fault`` None) or one fault."""

    fault: str | None  #: a FAULTS name, or None
    size: float  #: the case's size: L/min at 10 MPa for leaks, a fraction of spool travel for the offset
    onset_s: float  #: the first faulty sample's time from the recording's start [s] (healthy: NaN)
    load_kg: float  #: the load at the onset (healthy: its mean over the run) [kg]; NaN: not labelled


def label(rec, name: str) -> Label:
    """The :class:`Label` of a recording from its truth columns; a UserError naming the file
    when it has none of them, holds two faults, or a fault from its first sample (its own
    baseline would learn the fault)."""
    found = {f: np.asarray(rec.truth[c], dtype=float) for f, c in TRUTH.items() if c in rec.truth}
    if not found:
        raise UserError(f"{name}: no ground truth: none of the columns {', '.join(TRUTH.values())}; fdi evaluate "
                        "scores labelled recordings only (docs/recordings.md)")
    present = {}
    for f, v in found.items():
        size = np.nan_to_num(v) if f == "offset" else leak_lpm_of(np.nan_to_num(v))
        on = np.abs(size) > (PRESENT["offset"] if f == "offset" else PRESENT["leak_lpm"])
        if on.any():
            present[f] = (int(np.argmax(on)), size)
    if len(present) > 1:
        raise UserError(f"{name}: two faults at once ({', '.join(present)}); fdi evaluate scores one fault per "
                        "recording")
    t = rec.t - rec.t[0]
    m_L = np.asarray(rec.truth["true_mL"], dtype=float) if "true_mL" in rec.truth else np.full(rec.n, np.nan)
    if not present:
        return Label(None, 0.0, math.nan, float(np.nanmean(m_L)) if np.isfinite(m_L).any() else math.nan)
    (fault, (k, size)), = present.items()
    if k == 0:
        raise UserError(f"{name}: '{TRUTH[fault]}': the fault is present from the first sample; a recording's own "
                        "baseline would learn it (replay it with --baseline HEALTHY instead)")
    scored = min(rec.n - 1, k + int(round(TUNE.within_s / rec.dt)))  # its size at the end of the scored second
    return Label(fault, float(np.round(size[scored], 6)), float(t[k]), float(m_L[k]))


def stamp(path: Path) -> str:
    """A short hash of a file's name, size and modification time: its chunk is scored again when
    the file changes."""
    st = path.stat()
    return hashlib.sha256(f"{path.name}|{st.st_size}|{st.st_mtime_ns}".encode()).hexdigest()[:10]


def chunk_key(path: Path) -> str:
    """The store key of a recording's chunk: its stem (file-name safe) and :func:`stamp`."""
    return f"{re.sub(r'[^A-Za-z0-9_.+-]', '_', path.stem)}_{stamp(path)}"


def score_recording(path: Path, plant: Plant, thresholds: Thresholds | None, bound: bool = False) -> dict:
    """One recording's chunk: its label (``fault`` index in FAULTS or -1, ``size``, ``onset_s``),
    and its scores as the tune's chunks hold them (:mod:`fdi.scoring`, one run), with the size
    the bank reports and ``true_size`` in the same unit (L/min at 10 MPa, % of spool travel)."""
    rec = read_recording(path)
    lab = label(rec, str(path))
    return score(rec, lab, plant, thresholds, bound=bound)


def score(rec, lab: Label, plant: Plant, thresholds: Thresholds | None, cfg: FilterConfig | None = None,
          bound: bool = False) -> dict:
    """The chunk of a labelled recording ``rec`` (:func:`score_recording`); ``cfg``: the filter
    (default: the shipped one); ``bound``: also ``evidence``, what the data carry at the true onset
    (:func:`fdi.bound.onset_evidence`; a healthy run at an onset drawn from its length, seeded)."""
    cfg = FilterConfig() if cfg is None else cfg
    rec, inp, th, _, _ = prepare(rec, plant, thresholds, plant_name="the plant", stops=cfg.stops)
    check_rate(th)
    out = run_filter(inp, own_noise(cfg, inp)[0])
    st = statistics(out, th)
    faulty = lab.fault is not None
    t = rec.t - rec.t[0]
    k0 = np.array([np.searchsorted(t, lab.onset_s - 1e-9) if faulty else len(t)], dtype=np.int64)
    res = window_maxima(st, th, k0)
    res.update(bank_decisions(out, st, th, k0, faulty, size=True))
    if bound:
        res["evidence"] = onset_bound.onset_evidence(out, k0 if faulty else healthy_onset(th, len(t), len(t)))
    true = lab.size * (100.0 if lab.fault == "offset" else 1.0)
    res.update({"m_L": np.array([lab.load_kg]), "resets": out.n_cov_reset, "k_onset": k0,
                "true_size": np.array([true]), "fault": np.array([FAULTS.index(lab.fault) if faulty else -1]),
                "size": np.array([lab.size]), "onset_s": np.array([lab.onset_s]),
                "duration_s": np.array([float(t[-1])])})
    return res


def check_rate(th: Thresholds) -> None:
    """Refuse thresholds for another rate than the scoring's (its windows count 1 ms samples)."""
    if abs(th.derived.sample_dt_s / TUNE.dt - 1.0) > 1e-9:
        raise UserError(f"--thresholds: derived for {1 / th.derived.sample_dt_s:.4g} Hz recordings, but fdi evaluate "
                        f"scores {1 / TUNE.dt:g} Hz recordings only: leave --thresholds out (the shipped ones) or "
                        f"give thresholds derived at {1 / TUNE.dt:g} Hz")


def check_scoring_rate(rec, name: str) -> None:
    """Refuse a recording the scoring cannot take, saying what the user can do instead: the
    scores count 1 ms samples (a whole multiple of 1000 Hz is kept 1 in k, as replay does)."""
    if decimation(rec, TUNE.dt) is not None:
        return
    rate, supported = 1.0 / rec.dt, study_rate(rec)
    alone = (f"; to diagnose it alone: `samfdi fdi thresholds --sample-rate {supported:.5g} --out th{supported:.0f}`, "
             f"then `samfdi fdi replay {name} --thresholds th{supported:.0f}/thresholds.toml`" if supported else "")
    raise UserError(f"{name}: sampled at {rate:.4g} Hz, but fdi evaluate scores {1 / TUNE.dt:g} Hz recordings only "
                    f"(or a whole multiple): move it out of the folder{alone}")


def healthy_onset(th: Thresholds, n: int, seed: int) -> np.ndarray:
    """(1,) the sample at which a healthy run of n samples is asked for the bound's evidence: uniform
    between the end of the own baseline's window and 1 s before the end, seeded by ``seed``."""
    lo = int(round((th.window.warmup_s + th.window.baseline_s + 1.0) / TUNE.dt))
    hi = max(lo + 1, n - int(round((TUNE.within_s + 0.1) / TUNE.dt)))
    return np.random.default_rng(seed).integers(lo, hi, 1)


def recordings(folder: Path) -> list[Path]:
    """The recordings (.csv, .mat) of ``folder``, sorted; a UserError when it has none."""
    if not folder.is_dir():
        raise UserError(f"{folder}: no such folder")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in SUFFIXES and p.is_file())
    if not paths:
        raise UserError(f"{folder}: no recordings (.csv or .mat files) in it")
    return paths


def check_recordings(paths: list[Path], plant: Plant, thresholds: Thresholds | None) -> None:
    """Refuse, before any filtering, a recording that cannot be labelled or that replay would
    refuse (:func:`fdi.offline.prepare`): one line naming it, so that a long evaluation never
    stops halfway on a bad file."""
    for path in paths:  # the labels and rates first: they need no model
        rec = read_recording(path)
        label(rec, str(path))
        check_scoring_rate(rec, str(path))
    for path in paths:
        prepare(read_recording(path), plant, thresholds, plant_name="the plant")


def fingerprint(plant: Plant, th: Thresholds | None) -> dict:
    """What an evaluation folder's chunks depend on besides their recording: the plant and the
    thresholds (None: the shipped file of each recording's position sensor)."""
    vec = np.ascontiguousarray(plant.vector(), dtype=np.float64)
    return {"job": "fdi evaluate", "layout": "1",
            "thresholds_sha256": "shipped" if th is None else hashlib.sha256(th.to_json().encode()).hexdigest(),
            "plant_sha256": hashlib.sha256(vec.tobytes()).hexdigest()}


def evaluate_folder(folder: Path, out_dir: Path, plant: Plant, thresholds: Thresholds | None = None,
                    workers: int = 1, progress: bool = True, force: bool = False, bound: bool = False) -> dict:
    """Score every recording of ``folder`` into ``out_dir`` (resumable; :func:`summarise`),
    with ``workers`` local processes; ``bound``: also what the data carry at the true onset
    (chunks of their own). Returns the summary."""
    folder, out_dir = Path(folder), Path(out_dir)
    paths = recordings(folder)
    if thresholds is not None:
        check_rate(thresholds)
    check_recordings(paths, plant, thresholds)
    output_folder(out_dir, create=False)
    mine = [f for f in OUTPUTS if (out_dir / f).exists()]
    if mine and not force and not (out_dir / MANIFEST).exists():
        raise UserError(f"{out_dir}: already holds {', '.join(mine)}; use another --out, or --force to overwrite")
    tasks = {chunk_key(p) + ("_b" if bound else ""): (p, plant, thresholds, bound) for p in paths}
    chunks = {}
    try:
        with Store.open(out_dir, fingerprint(plant, thresholds), resume=True, layout=LAYOUT) as store:
            for chunk in compute(store, score_recording, tasks, executor="processes" if workers > 1 else "inline",
                                 workers=workers if workers > 1 else None, progress=progress, desc="fdi evaluate",
                                 unit="recording"):
                chunks[chunk.key] = chunk.arrays
    except StoreError as exc:
        raise UserError(str(exc)) from None
    runs = {k: chunks[k] for k in tasks}
    summary = summarise(runs, thresholds or Thresholds.shipped())
    summary["folder"] = str(folder)
    write_report(out_dir, summary)
    return summary


def cases(runs: dict) -> dict:
    """Case name ("healthy", "K_int_0.25", "offset_-0.01") -> the arrays of its runs joined."""
    groups: dict = {}
    for arrays in runs.values():
        f = int(arrays["fault"][0])
        name = "healthy" if f < 0 else f"{FAULTS[f]}_{float(arrays['size'][0]):g}"
        groups.setdefault(name, []).append(arrays)
    return {name: {k: np.concatenate([a[k] for a in parts]) for k in parts[0]} for name, parts in groups.items()}


def summarise(runs: dict, th: Thresholds) -> dict:
    """The rates of the scored recordings ``runs`` (chunk key -> arrays), as the tune states them
    (:func:`fdi.metrics.fault_row`, :func:`fdi.metrics.healthy_rates`), and the target verdicts."""
    by_case = cases(runs)
    level = th.derived.false_alarm_level
    out = {"recordings": len(runs), "false_alarm_level": level, "target_rate": TUNE.target_rate,
           "size_bias": TUNE.size_bias, "size_coverage": TUNE.size_coverage, "load_bins_kg": TUNE.load_bins_kg}
    if "healthy" in by_case:
        h = by_case["healthy"]
        out["healthy"] = healthy_rates(h, level)
        out["healthy"]["duration_s"] = [float(h["duration_s"].min()), float(h["duration_s"].max())]
    bnd = None
    if "healthy" in by_case and all("evidence" in d for d in by_case.values()):
        bnd = (onset_bound.threshold(by_case["healthy"]["evidence"], level),
               margin_for(th.confirmation.false_isolation_level))
        out["bound"] = {"threshold_nats": bnd[0], "margin_nats": bnd[1], "healthy_runs": out["healthy"]["runs"],
                        "enough_healthy_runs": onset_bound.enough_healthy_runs(level)}
    rows = []
    for name in sorted((n for n in by_case if n != "healthy"), key=_case_order):
        d = by_case[name]
        fault, size = FAULTS[int(d["fault"][0])], float(d["size"][0])
        row = fault_row(d, fault, size, bnd)
        n, before = row["runs"], int(round(row["alarm_before_onset"] * row["runs"]))
        row.update({"alarm_before_onset_runs": before, "alarm_before_onset_ci": list(rates.interval(before, n)),
                    "wrong_ci": list(rates.interval(row["wrong_decisions"], row["decisions_within_1s"]))})
        rows.append(row)
    out["rows"] = rows
    before = sum(r["alarm_before_onset_runs"] for r in rows)
    n_fault = sum(r["runs"] for r in rows)
    if n_fault:  # an alarm before the onset is a false alarm of the healthy stretch before it
        out["alarm_before_onset"] = {"runs": n_fault, "alarms": before, "rate": before / n_fault,
                                     "ci": list(rates.interval(before, n_fault))}
    return out


def _case_order(name: str) -> tuple:
    fault, size = name.rsplit("_", 1)
    return FAULTS.index(fault), abs(float(size)), -float(size)


def size_text(fault: str, size: float) -> str:
    """A case's size with its unit: leaks in L/min at 10 MPa, the offset in % (signed)."""
    return f"{size * 100:+g} %" if fault == "offset" else f"{size:g} L/min"


def _pct(v) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{100 * v:.1f}"


def _delay(v) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.2f}"


def _ci(ci) -> str:
    return "-" if not all(v is not None and math.isfinite(v) for v in ci) else f"{100 * ci[0]:.1f}-{100 * ci[1]:.1f}"


def markdown(s: dict) -> list:
    """The lines of evaluation.md."""
    lines = ["# Fault detection on labelled recordings (`samfdi fdi evaluate`)", "",
             f"{s['recordings']} recordings from {s.get('folder', 'the folder')}, each replayed as `fdi replay` does "
             "(its own baseline, the shipped filter and the thresholds of its position sensor) and scored as "
             "`fdi tune` scores its runs. Rates are k of n runs [%] with their exact 95 % interval "
             "(fdi/rates.py): **met** where the whole interval lies on the target's side, **not met** where it "
             "lies on the other, else undecided at this many runs.", ""]
    if "healthy" in s:
        lines += [_healthy_line(s), ""]
    if "alarm_before_onset" in s:
        b = s["alarm_before_onset"]
        lines += [f"**Alarms before the onset** (fault runs; false alarms, never detections): {b['alarms']} of "
                  f"{b['runs']} = {_pct(b['rate'])} % [{_ci(b['ci'])}].", ""]
    bins = [f"{int(a)}-{int(round(b))} kg" for a, b in s["load_bins_kg"]]
    if not s["rows"]:
        lines += ["No fault runs in the folder (no recording has a true_* column with a fault): only false alarms "
                  "are scored."]
    else:
        lines += ["| fault | size | runs | isolated within 1 s [95 %] | vs 95 % | alarm before onset | wrong isolations "
                  "| mean delay [s] | median size error [95 %] | within +-10 % | truth inside +-2 sigma [95 %] | vs 90 % | "
                  + " | ".join(f"isolated {b}" for b in bins) + " |",
                  "|" + "---|" * (12 + len(bins))]
        for r in s["rows"]:
            lines.append(
                f"| {r['fault']} | {size_text(r['fault'], r['size'])} | {r['runs']} | {_pct(r['isolated_within_1s'])} "
                f"[{_ci(r['isolated_ci'])}] | {r['isolated_verdict']} | {r['alarm_before_onset_runs']} "
                f"| {r['wrong_decisions']} of {r['decisions_within_1s']} | "
                f"{_delay(r['mean_delay_s'])} | "
                f"{_pct(r.get('size_error_median'))} [{_ci(r.get('size_error_ci', [math.nan] * 2))}] | "
                f"{r.get('size_error_verdict', '-')} | {_pct(r.get('size_inside_2sigma'))} "
                f"[{_ci(r.get('size_inside_ci', [math.nan] * 2))}] | {r.get('size_inside_verdict', '-')} | "
                + " | ".join(_pct(v) for v in r["isolated_by_load"]) + " |")
    if "bound" in s and s["rows"]:
        b = s["bound"]
        lines += ["", "**What the data carry** (`--bound`, fdi/bound.py): a bank started at the TRUE onset, which no "
                  f"detector knows; 'isolable': its evidence for the true fault beats {b['threshold_nats']:.1f} nats (what "
                  f"the best fault beats in {100 * s['false_alarm_level']:g} % of the healthy runs, at an onset drawn in "
                  f"each) and every other fault by {b['margin_nats']:.1f} nats"
                  + (f"; rough: {b['healthy_runs']} healthy runs, {b['enough_healthy_runs']} wanted" if
                     b["healthy_runs"] < b["enough_healthy_runs"] else "") + ".", "",
                  "| fault | size | ours: isolated within 1 s | bound: detectable | bound: isolable [95 %] |",
                  "|---|---|---|---|---|"]
        lines += [f"| {r['fault']} | {size_text(r['fault'], r['size'])} | {_pct(r['isolated_within_1s'])} | "
                  f"{_pct(r['bound_detectable'])} | {_pct(r['bound_isolable'])} [{_ci(r['bound_isolable_ci'])}] |"
                  for r in s["rows"]]
    if s["rows"]:
        lines += ["", "'isolated within 1 s': a confirmed alarm at or after the onset and the bank naming the right fault "
                  "by 1 s after it. 'wrong isolations': decisions within 1 s that named another fault. Size errors are "
                  "relative, over the isolated runs; the size and its +-2 sigma band are the ones `fdi replay` reports."]
    return lines


def _healthy_line(s: dict) -> str:
    """The false-alarm paragraph of evaluation.md: one duration when the runs are equally long,
    the rate of each load third that has runs."""
    h = s["healthy"]
    lo, hi = h["duration_s"]
    length = f"{lo:.0f} s" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f} s"
    thirds = [f"{int(a)}-{int(round(b))} kg: {_pct(v)} %" for (a, b), v in zip(s["load_bins_kg"], h["false_alarm_by_load"])
              if v is not None and math.isfinite(v)]
    by_load = f"; by load ({', '.join(thirds)})" if len(thirds) > 1 else ""
    return (f"**False alarms** (an alarm the bank confirmed, per healthy run of {length}): {h['false_alarms']} of "
            f"{h['runs']} = {_pct(h['false_alarm_rate'])} % [{_ci(h['false_alarm_ci'])}], <= "
            f"{100 * s['false_alarm_level']:g} %: **{h['false_alarm_verdict']}**{by_load}; runs with any CUSUM alarm "
            f"(confirmed or withdrawn) {_pct(h['trigger_rate'])} %.")


def write_report(out_dir: Path, s: dict) -> None:
    """evaluation.json (no NaN: null), evaluation.md and evaluation.png into ``out_dir``."""
    write_json(out_dir / "evaluation.json", s)
    (out_dir / "evaluation.md").write_text("\n".join(markdown(s)) + "\n")
    figure(out_dir / "evaluation.png", s)


def figure(path: Path, s: dict) -> None:
    """Isolated within 1 s against the fault's size, each case with its 95 % interval as a bar:
    leaks (L/min at 10 MPa) on the left, offsets (% of spool travel) on the right."""
    fig = Figure(figsize=(10, 4.2))
    axes = fig.subplots(1, 2, sharey=True)
    style = {"K_int": ("C0", "o"), "K_extA": ("C1", "s"), "K_extB": ("C2", "^"), "offset": ("C3", "D")}
    for fault, (color, marker) in style.items():
        rows = [r for r in s["rows"] if r["fault"] == fault]
        if not rows:
            continue
        ax = axes[1 if fault == "offset" else 0]
        x = np.array([r["size"] * (100 if fault == "offset" else 1) for r in rows])
        y = np.array([r["isolated_within_1s"] for r in rows])
        ci = np.array([r["isolated_ci"] for r in rows], dtype=float)
        shift = {"K_int": 0.96, "K_extA": 1.0, "K_extB": 1.04, "offset": 1.0}[fault]  # apart, on a shared size
        ax.errorbar(x * shift, 100 * y, yerr=100 * np.abs(ci.T - y), color=color, marker=marker, ls="none",
                    capsize=3, label=f"{fault} (n = {', '.join(str(r['runs']) for r in rows)})")
    sizes = [abs(r["size"]) * (100 if r["fault"] == "offset" else 1) for r in s["rows"]]
    if sizes:
        axes[0].set_xlim(0.0, 1.2 * max([v for r, v in zip(s["rows"], sizes) if r["fault"] != "offset"], default=1.0))
        top = 1.2 * max([v for r, v in zip(s["rows"], sizes) if r["fault"] == "offset"], default=1.0)
        axes[1].set_xlim(-top, top)
    axes[0].set_ylim(-3, 103)
    for ax, unit in zip(axes, ("leak [L/min at 10 MPa]", "offset [% of spool travel]")):
        ax.axhline(100 * s["target_rate"], color="k", ls="--", lw=0.8, label=f"target {100 * s['target_rate']:g} %")
        ax.set_xlabel(unit)
        ax.legend(fontsize=7, loc="lower right")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("isolated within 1 s of the onset [%] (95 % interval)")
    h = s.get("healthy")
    title = "fdi evaluate: " + (f"false alarms {h['false_alarms']} of {h['runs']} healthy runs "
                                f"[{_ci(h['false_alarm_ci'])} %]" if h else "no healthy runs")
    if "alarm_before_onset" in s:
        b = s["alarm_before_onset"]
        title += f"; alarms before the onset {b['alarms']} of {b['runs']} fault runs"
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
