"""Thresholds from the sensitivity ranking (``samfdi fdi thresholds``; docs/fdi.md).

Two Sobol' studies through the generic engine :mod:`gsa`, whose "model" is one simulated run of
the SAM followed by the filter and the change residuals (:mod:`fdi.statistics`):

1. **Leakage study** (the Table 5 box of ``scenarios/gsa/paper_leakage.toml``: K_int, K_extA,
   K_extB 0-1 L/min at 10 MPa, plus the offset +-2 %), faults stepping in during the run. Output:
   the mean change of every fault estimate per regime. A residual **votes** for fault f in a
   regime where f's share of it over the box, sqrt(ST_f Var(Y)), is at least ``vote_snr``
   healthy spreads.
2. **Nuisance study**: the nuisance box of :data:`fdi.montecarlo.NUISANCE` and the unknown load,
   the experiment (input kind, amplitude, frequency) and the noise realisation as factors, healthy
   runs of ``run_length_s``. Output: the RMS change of each healthy estimate per regime; its
   second moment over the design is the healthy spread sigma, its Sobol' indices name what
   carries it. Each CUSUM threshold h is the (1 - alpha / n) quantile (:func:`level_threshold`)
   of the per-run maxima of its statistic over the same healthy runs: alpha the trigger level
   per run, Bonferroni over the n tests (the five CUSUMs and the notch-flow trigger).
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from chunkstore import execute
from gsa import Problem, analyze, saltelli_design
from gsa.studies import load_study
from sam import P, Plant

from .conditions import held, long_stroke_mask, regimes
from .config import FilterConfig
from .faults import HYPOTHESES, NOTCH_STATES, NOTCH_TRIGGER, PARAMS, REGIMES
from .filter import run_filter
from .montecarlo import LOAD_RANGE, NUISANCE
from .statistics import change_spread, cusum, cusum_drift, has_notch_states, notch_armed, notch_jump, own_baseline
from .synth import INPUT_KINDS, POSITION_SENSORS, random_input, simulate_runs
from .thresholds import MAX_RUN_LENGTH_S, MIN_RUN_LENGTH_S, Thresholds, describe, to_toml

NOTCHES = tuple(s.removeprefix("Q_N_") for s in NOTCH_STATES)  #: the valve's four notches
LEAKAGE_STUDY = Path(__file__).resolve().parents[1] / "scenarios" / "gsa" / "paper_leakage.toml"
#: The files :func:`write_thresholds` writes.
OUTPUT_FILES = ("thresholds.toml", "thresholds.md", "thresholds_gsa.json")


@dataclass(frozen=True)
class StudyDesign:
    """The two studies that derive a thresholds file, and what the file is stated for."""

    n_leak: int = 16  #: base sample size of the leakage study
    #: base sample size of the nuisance study: its healthy runs also set h, a high quantile of
    #: their maxima, and a Saltelli design has only 2N distinct experiments among its N (k + 2) runs
    n_nuisance: int = 128
    seed: int = 2011  #: the Saltelli designs' seed (the nuisance study's is seed + 1)
    sample_dt_s: float = 1e-3  #: s: the recordings' sampling step (a whole multiple of sim_dt)
    position_sensor: str = "encoder"  #: the position channel simulated (fdi.synth.POSITION_SENSORS)
    #: s: the nuisance study's healthy runs, over which the false-alarm level is stated: long
    #: enough for a run's lasting offsets of the change residual to show
    run_length_s: float = 20.0
    false_alarm_level: float = 0.01  #: false alarms per healthy run the detector is for
    #: alarms (triggers) per healthy run h is set for; the bank withdraws the healthy ones (None: h
    #: at false_alarm_level)
    trigger_level: float | None = 0.10
    memory_s: float | None = 0.5  #: s: the CUSUM memory (None: the classic CUSUM)
    long_stroke_s: float | None = 2.0  #: s: the long-stroke rule (None: none)
    drift: float = 1.0  #: sigma: the CUSUM drift
    #: per parameter, the weight of the filter's std in the change residual's spread: the external
    #: leaks' filter std overstates their healthy spread 4-8 times and would hide small leaks
    filter_sd_weight: dict = field(default_factory=lambda: {"K_int": 1.0, "K_extA": 0.0, "K_extB": 0.0, "offset": 1.0})
    vote_snr: float = 3.0  #: healthy spreads a fault's share of a residual needs for it to vote
    #: sigma s: the smallest h (where healthy runs never lift a CUSUM off 0 the quantile is ~0)
    h_floor: float = 0.02
    leak_run_s: float = 4.0  #: s: the leakage study's runs
    leak_onset_s: float = 1.5  #: s: when its faults step in
    offset_range: float = 0.02  #: the leakage study's offset box, +- (fraction of travel)
    sim_dt: float = 1e-3  #: s: the studies' simulation step

    def __post_init__(self):
        for name in ("n_leak", "n_nuisance"):
            n = getattr(self, name)
            if isinstance(n, bool) or not isinstance(n, int) or n < 4:
                raise ValueError(f"{name}: need at least 4, got {n!r}")
        if self.memory_s is not None and not 0 < self.memory_s < math.inf:
            raise ValueError(f"memory_s: {self.memory_s!r} s is not a time constant (> 0, or None for none)")
        if self.long_stroke_s is not None and not 0 < self.long_stroke_s < math.inf:
            raise ValueError(f"long_stroke_s: {self.long_stroke_s!r} s is not a duration (> 0, or None for no "
                             "long-stroke rule)")
        fa = self.false_alarm_level
        if self.trigger_level is not None and not fa <= self.trigger_level <= 1.0:
            raise ValueError(f"trigger_level: {self.trigger_level!r} is not a rate per run between the false-alarm "
                             f"level {fa:g} and 1")
        if not MIN_RUN_LENGTH_S <= self.run_length_s <= MAX_RUN_LENGTH_S:
            raise ValueError(f"run_length_s: {self.run_length_s!r} s is outside {MIN_RUN_LENGTH_S:g}-"
                             f"{MAX_RUN_LENGTH_S:g} s")
        if self.position_sensor not in POSITION_SENSORS:
            raise ValueError(f"position_sensor: {self.position_sensor!r} is not one of {', '.join(POSITION_SENSORS)}")
        k = self.sample_factor
        if k < 1 or abs(k * self.sim_dt - self.sample_dt_s) > 1e-9 * self.sample_dt_s:
            raise ValueError(f"sample_dt_s: {self.sample_dt_s!r} s is not a whole multiple of the studies' "
                             f"{self.sim_dt:g} s step")

    @property
    def sample_factor(self) -> int:
        """The decimation of the simulated signals (every sim_dt) to the recordings' sampling step."""
        return int(round(self.sample_dt_s / self.sim_dt))


def _experiment(x: float, t: np.ndarray) -> np.ndarray:
    """The input of factor value x in [0, 1): its kind (thirds), the rest drawn from a generator
    seeded by x (fdi.synth.random_input)."""
    kind = INPUT_KINDS[min(int(x * 3), 2)]
    return random_input(kind, t, np.random.default_rng(int(x * 2**31)))


def study_runs(params: np.ndarray, exp: np.ndarray, noise: np.ndarray, nominal: np.ndarray, design: StudyDesign,
              faults=None, duration: float | None = None):
    """Simulate and filter one run of ``duration`` [s] per row, sampled every sample_dt_s, the
    filter given the ``nominal`` plant; deterministic given the factor values."""
    duration = design.leak_run_s if duration is None else duration
    dt = design.sim_dt
    T = int(round(duration / dt)) + 1
    t = np.arange(T) * dt
    u = np.stack([_experiment(x, t) for x in exp])
    sensor = dict(POSITION_SENSORS[design.position_sensor])
    x_noise = sensor.pop("x_noise", 0.0)
    runs = simulate_runs(params, u, dt, faults=faults, nominal=np.tile(nominal, (len(params), 1)), pressure_noise=0.0,
                         **sensor)
    for i, x in enumerate(noise):  # each row's noise from its own factor value
        r = np.random.default_rng(int(x * 2**31) + 17)
        runs.inp.pA[i] += 20e3 * r.standard_normal(T)
        runs.inp.pB[i] += 20e3 * r.standard_normal(T)
        if x_noise:
            runs.inp.pos[i] += x_noise * r.standard_normal(T)
    return run_filter(runs.inp.decimated(design.sample_factor), FilterConfig())


def _dev(out, th: Thresholds):
    """Changes of the fault estimates from their baselines (n, 4, T), their filter std (n, 4, T),
    the regimes (n, T), the held and the armed samples (n, 4, T), as fdi.statistics scores them."""
    hidden = held(out, th)
    base, ready = own_baseline(out, th, hidden)
    dev = np.stack([out.mean[:, :, j] - base[:, i:i + 1] for i, j in enumerate(PARAMS.values())], axis=1)
    sd = np.stack([out.std[:, :, j] for j in PARAMS.values()], axis=1)
    reg = regimes(out.u, out.inp.dt, th.regimes.band_V, th.regimes.transient_s)
    return dev, sd, reg, hidden, ready


def _regime_stat(dev, reg, hidden, ready, after: float, how: str, dt: float) -> np.ndarray:
    """(n, 4 params x 5 regimes): mean or RMS of dev per regime after time ``after``, over the
    samples (every dt [s]) the change test scores (``ready`` and not ``hidden``)."""
    n, npar, T = dev.shape
    k0 = int(round(after / dt))
    Y = np.zeros((n, npar, len(REGIMES)))
    for g in range(len(REGIMES)):
        for i in range(npar):
            w = (reg[:, k0:] == g) & ~hidden[:, i, k0:] & ready[:, i, k0:]
            cnt = np.maximum(w.sum(axis=1), 1)
            d = dev[:, i, k0:]
            Y[:, i, g] = (np.where(w, d, 0).sum(axis=1) / cnt if how == "mean"
                          else np.sqrt(np.where(w, d * d, 0).sum(axis=1) / cnt))
    return Y.reshape(n, -1)


def output_names() -> list[str]:
    return [f"{p}|{g}" for p in PARAMS for g in REGIMES]


def _leak_model(X: np.ndarray, th: Thresholds, nominal: np.ndarray, design: StudyDesign) -> np.ndarray:
    """Leakage study model: X columns K_int, K_extA, K_extB, offset, experiment, noise."""
    dt = design.sim_dt
    t = np.arange(int(round(design.leak_run_s / dt)) + 1) * dt
    params = np.tile(nominal, (len(X), 1))
    faults = {name: np.where(t[None, :] >= design.leak_onset_s, X[:, [i]], 0.0)
              for i, name in enumerate(("K_int", "K_extA", "K_extB", "offset"))}
    out = study_runs(params, X[:, 4], X[:, 5], nominal, design, faults)
    dev, _, reg, hidden, ready = _dev(out, th)
    return _regime_stat(dev, reg, hidden, ready, design.leak_onset_s + 0.2, "mean", th.derived.sample_dt_s)


def _nuisance_params(X: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    params = np.tile(nominal, (len(X), 1))
    c = 0
    for notch in NOTCHES:
        params[:, P[f"Q_N_{notch}"]] *= X[:, c]
        params[:, P[f"dp_N_{notch}"]] *= X[:, c + 1]
        c += 2
    params[:, P.B_eff] *= X[:, c]
    params[:, P.b] *= X[:, c + 1]
    params[:, P.m_L] = X[:, c + 2]
    return params


def _nuisance_model(X: np.ndarray, th: Thresholds, nominal: np.ndarray, design: StudyDesign):
    out = study_runs(_nuisance_params(X, nominal), X[:, -2], X[:, -1], nominal, design,
                     duration=th.derived.run_length_s)
    dev, sd, reg, hidden, ready = _dev(out, th)
    w = th.window
    return (_regime_stat(dev, reg, hidden, ready, w.warmup_s + w.baseline_s, "rms", th.derived.sample_dt_s),
            (dev, sd, reg, hidden, ready, long_stroke_mask(out, th), _notch_maxima(out, th, ready)))


def _notch_maxima(out, th: Thresholds, ready) -> np.ndarray | None:
    """(n,) per-run maxima of the notch-flow trigger's statistic of the healthy runs in ``out``,
    armed as fdi.statistics arms it; None for a filter without notch-flow states."""
    if not has_notch_states(out):
        return None
    warm = int(round(th.window.warmup_s / th.derived.sample_dt_s))
    return notch_jump(out, th, notch_armed(out, th, ready), warm).max(axis=1)


def _problems(design: StudyDesign):
    leak = load_study(LEAKAGE_STUDY).study.problem  # the Table 5 box, as the paper's study file gives it
    off = design.offset_range
    lp = Problem(names=(*leak.names, "offset", "experiment", "noise"),
                 bounds=(*leak.bounds, (-off, off), (0.0, 1.0), (0.0, 1.0)))
    names, bounds, groups = [], [], []
    for notch in NOTCHES:
        for q in ("Q_N", "dp_N"):
            names.append(f"{q}_{notch}")
            bounds.append((1 - NUISANCE[f"{q}_{notch}"], 1 + NUISANCE[f"{q}_{notch}"]))
            groups.append(f"valve_{notch}")
    for q in ("B_eff", "b"):
        names.append(q)
        bounds.append((1 - NUISANCE[q], 1 + NUISANCE[q]))
        groups.append(q)
    names += ["m_L", "experiment", "noise"]
    bounds += [LOAD_RANGE, (0.0, 1.0), (0.0, 1.0)]
    groups += ["m_L", "experiment", "noise"]
    return lp, Problem(names=tuple(names), bounds=tuple(bounds), groups=tuple(groups))


def _evaluate(model, X, workers: int, chunk: int = 32, progress: str | None = None) -> list:
    """model(rows) over X in chunks of ``chunk`` rows, in order, here or on ``workers`` local
    processes (the chunk store's pool); ``progress``: the label of a progress bar (None: silent).
    Nothing is stored: the studies' intermediate arrays are GBs and take minutes to compute."""
    tasks = {f"rows_{i:06d}": (X[i:i + chunk],) for i in range(0, len(X), chunk)}
    done = {}
    with tqdm(total=len(X), desc=progress, unit="run", disable=progress is None) as bar:
        for key, res in execute(model, tasks, "processes" if workers > 1 else "inline",
                                workers=workers if workers > 1 else None):
            done[key] = res
            bar.update(len(tasks[key][0]))
    return [done[key] for key in tasks]


def level_threshold(maxima: np.ndarray, p: float) -> float:
    """The threshold of a stated level: the p quantile of the healthy per-run maxima, the larger of
    a Gumbel law fitted by moments and the empirical quantile, so that neither a poor fit nor a
    thin tail lowers it (not the largest maximum: with long runs that is one outlying run)."""
    return float(max(gumbel_quantile(maxima, p), np.quantile(maxima, p)))


def gumbel_quantile(x: np.ndarray, p: float) -> float:
    """The p quantile of a Gumbel law fitted to x by its mean and std."""
    m, s = float(np.mean(x)), float(np.std(x))
    if s == 0.0:
        return m
    beta = s * math.sqrt(6.0) / math.pi
    mu = m - 0.5772156649 * beta
    return mu - beta * math.log(-math.log(p))


def compute_thresholds(plant: Plant, design: StudyDesign = StudyDesign(), workers: int = 1,
                       progress: bool = False) -> tuple[Thresholds, dict]:
    """Run both studies on ``plant`` and derive the thresholds. Returns (thresholds, report)."""
    d = design
    nominal = plant.vector()
    th0 = Thresholds().with_(drift=d.drift, filter_sd_weight=dict(d.filter_sd_weight),
                             sample_dt_s=d.sample_factor * d.sim_dt, memory_s=d.memory_s, run_length_s=d.run_length_s,
                             long_stroke_s=d.long_stroke_s, position_sensor=d.position_sensor)
    lp, npb = _problems(d)
    names = output_names()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # ---- (a) leakage study: which residual votes for which fault, in which regime
        d_leak = saltelli_design(lp, d.n_leak, d.seed)
        Y_leak = np.vstack(_evaluate(partial(_leak_model, th=th0, nominal=nominal, design=d), d_leak.X, workers,
                                     progress="leakage GSA" if progress else None))
        r_leak = analyze(lp, d_leak, Y_leak, n_boot=0, output_names=names)
        # ---- (b) nuisance study: healthy variance per residual and regime
        d_nui = saltelli_design(npb, d.n_nuisance, d.seed + 1)
        parts = _evaluate(partial(_nuisance_model, th=th0, nominal=nominal, design=d), d_nui.X, workers,
                          progress="nuisance GSA" if progress else None)
        r_nui = analyze(npb, d_nui, np.vstack([p[0] for p in parts]), n_boot=0, output_names=names)
    Y_nui = np.vstack([p[0] for p in parts])
    dev, sd, reg, hidden, ready, long_stroke = (np.concatenate([p[1][i] for p in parts]) for i in range(6))

    # ---- healthy variance per residual and regime (second moment over the A and B blocks)
    iid = np.r_[0:d.n_nuisance, d.n_nuisance:2 * d.n_nuisance]
    ms = (Y_nui[iid] ** 2).mean(axis=0).reshape(len(PARAMS), len(REGIMES))
    sigma = {p: [float(max(math.sqrt(ms[i, g]), 1e-15)) for g in range(len(REGIMES))] for i, p in enumerate(PARAMS)}

    faults = list(r_leak.factor_names[:4])  # K_int, K_extA, K_extB, offset
    ST = np.nan_to_num(r_leak.ST)
    var_leak = Y_leak[np.r_[0:d.n_leak, d.n_leak:2 * d.n_leak]].var(axis=0)
    votes, vote_st, vote_snr = {}, {}, {}
    for i, p in enumerate(PARAMS):
        fi = faults.index(p)
        v, st_own, snr = [], [], []
        for g, gname in enumerate(REGIMES):
            col = names.index(f"{p}|{gname}")
            st_own.append(float(ST[fi, col]))
            snr.append(float(math.sqrt(ST[fi, col] * var_leak[col]) / sigma[p][g]))
            v.append(snr[-1] >= d.vote_snr)
        if not any(v):  # never silence a hypothesis entirely: vote where it shows most
            v[int(np.argmax(st_own))] = True
        votes[p], vote_st[p], vote_snr[p] = v, st_own, snr
    th1 = th0.with_(sigma=sigma, votes=votes)

    # ---- CUSUM thresholds for the stated level, from the same healthy runs
    st = _healthy_statistics(dev, sd, reg, hidden, ready, long_stroke, th1)
    maxima = {h: g.max(axis=1) for h, g in st.items()}
    notch = [p[1][6] for p in parts]
    if all(m is not None for m in notch):  # a sixth test: the level is split over six
        maxima[NOTCH_TRIGGER] = np.concatenate(notch)
    q = 1.0 - (d.false_alarm_level if d.trigger_level is None else d.trigger_level) / len(maxima)
    h = {k: max(level_threshold(v, q), d.h_floor) for k, v in maxima.items()}
    dt = th1.derived.sample_dt_s
    th = th1.with_(h=h, false_alarm_level=d.false_alarm_level, trigger_level=d.trigger_level,
                   nuisance_sd={p: float(np.sqrt(np.mean(dev[:, i, int(0.5 / dt):] ** 2)))
                                for i, p in enumerate(PARAMS)},
                   source=(f"samfdi fdi thresholds: leakage GSA N={d.n_leak} ({d_leak.n_runs} runs), nuisance GSA "
                           f"N={d.n_nuisance} ({d_nui.n_runs} runs), seed {d.seed}, healthy runs {d.run_length_s:g} s"
                           + ("" if d.position_sensor == "encoder" else f", {d.position_sensor} position sensor")
                           + ("" if dt == d.sim_dt else f", sampled at {1 / dt:g} Hz")))
    ranking = {nm: r_nui.ranked_factors(nm)[:3] for nm in names}
    st_nui = {nm: {f: float(np.nan_to_num(r_nui.ST[i, j])) for i, f in enumerate(r_nui.factor_names)}
              for j, nm in enumerate(names)}
    st_leak = {nm: {f: float(np.nan_to_num(r_leak.ST[i, j])) for i, f in enumerate(r_leak.factor_names)}
               for j, nm in enumerate(names)}
    narrowed = {"Q_N": NUISANCE["Q_N_PA"], "dp_N": NUISANCE["dp_N_PA"], "B_eff": NUISANCE["B_eff"], "b": NUISANCE["b"]}
    report = {"votes_ST_own": vote_st, "votes_snr_own": vote_snr, "leakage_ST": st_leak, "nuisance_ST": st_nui,
              "nuisance_top3": ranking,
              "healthy_maxima_quantiles": {k: [float(np.quantile(v, 0.5)), float(np.quantile(v, 0.99)),
                                               float(np.max(v))] for k, v in maxima.items()},
              # the studies' own healthy runs that a CUSUM alarms in (at most the trigger level)
              "healthy_trigger_fraction": float(np.mean(np.any([v > h[k] for k, v in maxima.items()], axis=0))),
              "n_runs": {"leakage": d_leak.n_runs, "nuisance": d_nui.n_runs},
              "narrowed_ranges": {**{k: f"+-{100 * v:g} %" for k, v in narrowed.items()},
                                  "m_L": f"{LOAD_RANGE[0]:g}-{LOAD_RANGE[1]:g} kg"}}
    return th, report


def _healthy_statistics(dev, sd, reg, hidden, ready, long_stroke, th: Thresholds) -> dict:
    """CUSUM statistics of healthy runs from their changes dev (n, 4, T), filter sd, regimes (n, T),
    held and armed samples (n, 4, T) and long-stroke samples (n, T), as fdi.statistics scores them."""
    t, dt = th.test, th.derived.sample_dt_s
    warm = int(round(th.window.warmup_s / dt))
    out = {}
    for h, (_, sign) in HYPOTHESES.items():
        p = h.rstrip("+-")
        i = list(PARAMS).index(p)
        sig = np.asarray(t.sigma[p])[reg]
        r = np.where(ready[:, i], sign * dev[:, i] / change_spread(sd[:, i], sig, t.sd_weight(p)), 0.0)
        active = np.asarray(t.votes[p], dtype=bool)[reg] & ~hidden[:, i]
        out[h] = cusum(r, cusum_drift(p, long_stroke, th), dt, warm, active, t.memory_s)
    return out


def write_thresholds(th: Thresholds, report: dict, out_dir: Path) -> list[Path]:
    """thresholds.toml, thresholds.md and thresholds_gsa.json (the studies' report) into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    texts = (to_toml(th), "# FDI thresholds from the sensitivity ranking\n\n" + describe(th) + "\n",
             json.dumps(report, indent=1) + "\n")
    paths = [out_dir / name for name in OUTPUT_FILES]
    for path, text in zip(paths, texts):
        path.write_text(text)
    return paths
