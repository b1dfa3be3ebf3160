"""Which reconstruction of a machine do its published sensitivity results support?

For every candidate of a reconstruction study (:mod:`gsa.reconstruct_spec`): run each Sobol'
study of the experiment on the candidate's model, estimate the indices with bootstrap
replicates, and score them against every evidence item (:mod:`gsa.evidence`). All candidates
share the design and the resample counts, so the replicates are *paired*: the difference
between two candidates has an interval of its own. Then decide (:func:`decide`): rank the
candidates on each item, average the ranks, and say who wins, by how much, or that the best are
tied within the intervals.

A finished candidate is saved in ``OUT/candidates/<name>.json`` with a fingerprint of
everything it depends on; a killed run continues with ``resume=True``.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

import numba
import numpy as np
from scipy.optimize import brentq
from scipy.stats import rankdata
from tqdm import tqdm

import sam
from gsa.design import saltelli_design
from gsa.estimators import DEFAULT_ESTIMATOR, SobolStatistic, constant_outputs, output_means
from gsa.evidence import STEADY, Frequency, IndexTable, StudyIndices, instant_label
from gsa.bootstrap import resample_counts
from gsa.reconstruct_spec import Candidate, InitialCondition, ReconstructionSpec
from sam.capability import lift_check, max_liftable_mass, natural_frequency, natural_frequency_over_stroke

FORMAT = 2  #: version of the saved candidate files and of their scoring: a new one recomputes them
CONFIDENCE = 0.95
#: Losses are ranked to this resolution (index units, or a fraction): the paper prints indices to
#: three decimals, and a closer difference is not one (e.g. the gravity stiffness's 1e-4 on Fig. 4).
RESOLUTION = 1e-3
_CHUNK_RUNS = 16384  #: runs per simulated batch (memory)


def initial_states(params: np.ndarray, initial: InitialCondition) -> np.ndarray:
    """(n, 7) states at rest, valve centred, at ``initial.x_m`` with its pressures (see
    :data:`gsa.reconstruct_spec.PRESSURES`), one row per parameter row (n, len(P))."""
    if initial.pressures == "null_leak":
        return sam.initial_state(params, initial.x_m)
    s = np.zeros((params.shape[0], sam.N_STATES))
    s[:, sam.S.x] = initial.x_m
    s[:, sam.S.p_A] = params[:, sam.P.p_T]
    s[:, sam.S.p_B] = params[:, sam.P.p_S] if initial.pressures == "after_retraction" else params[:, sam.P.p_T]
    return s


@dataclass(frozen=True, eq=False)
class CandidateModel:
    """One candidate's outputs for rows of sampled parameters: each signal at each instant, then
    its steady-state value (the mean of every ``stride``-th step from ``steady_from`` to the end).

    ``X`` (n, k) in the study's units -> Y (n, len(signals) (len(instants) + 1)). Before the
    experiment's input ``u`` the valve is held centred for ``lead`` steps from the initial state.
    """

    base: np.ndarray  #: (len(P),) the candidate's parameter vector with the experiment's load
    columns: tuple[int, ...]
    scales: np.ndarray
    u: np.ndarray
    dt: float
    instants: np.ndarray  #: step indices of the instants, counted from the step input
    steady_from: int
    stride: int
    signals: tuple[str, ...]
    initial: InitialCondition
    lead: int = 0

    @property
    def outputs(self) -> tuple[tuple[str, object], ...]:
        t = [float(k * self.dt) for k in self.instants]
        return tuple((s, i) for s in self.signals for i in (*t, STEADY))

    def __call__(self, X: np.ndarray) -> np.ndarray:
        params = np.tile(self.base, (X.shape[0], 1))
        params[:, list(self.columns)] = X * self.scales
        n = len(self.u)
        steady = np.arange(self.steady_from, n + 1, self.stride)
        record = np.unique(np.r_[self.instants, steady]) + self.lead
        res = sam.simulate_batch(params, np.r_[np.zeros(self.lead), self.u], self.dt,
                                 x0=initial_states(params, self.initial), record_at=record, channels=self.signals)
        at = np.searchsorted(record, self.instants + self.lead)
        window = record >= self.steady_from + self.lead
        blocks = []
        for s in self.signals:
            blocks += [res[s][:, at], res[s][:, window].mean(axis=1, keepdims=True)]
        return np.hstack(blocks)


def candidate_model(spec: ReconstructionSpec, study: str, cand: Candidate) -> CandidateModel:
    """The model of study ``study`` (its experiment, its sampled parameters) on candidate ``cand``."""
    m = spec.studies[study].study.model
    base = cand.plant.vector()
    base[sam.P.m_L] = m.base[sam.P.m_L]  # the experiment's load
    return CandidateModel(
        base=base, columns=m.columns, scales=m.scales, u=m.u, dt=m.dt,
        instants=np.array([int(round(t / m.dt)) for t in spec.instants_s]),
        steady_from=int(round(cand.steady_from_s / m.dt)), stride=int(m.record_at[1] - m.record_at[0]),
        signals=m.signals, initial=cand.initial, lead=int(round(cand.initial.centred_s / m.dt)),
    )


def indices_with_replicates(design, Y: np.ndarray, counts: np.ndarray,
                            outputs) -> tuple[StudyIndices, StudyIndices, list]:
    """Point indices (R = 1) and one set per bootstrap replicate (rows of ``counts`` (R, N): how
    often each base sample is drawn) of the default estimator, and the outputs that did not vary
    (their indices are 0)."""
    samples = design.split(Y)
    stat = SobolStatistic(DEFAULT_ESTIMATOR, design.G)
    Q = np.empty((design.N, stat.n_q, Y.shape[1]))
    stat.fill(samples, output_means(samples), Q)
    point = stat.indices(Q.mean(axis=0)[None])
    means = counts.astype(np.float64) @ Q.reshape(design.N, -1) / design.N
    reps = stat.indices(means.reshape(counts.shape[0], stat.n_q, -1))
    flat = constant_outputs(samples)
    out = []
    for d in (point, reps):
        for v in d.values():
            v[..., flat] = 0.0
            np.nan_to_num(v, copy=False, nan=0.0)
        out.append(StudyIndices(design.problem.factor_names, outputs, d["S1"], d["ST"]))
    return out[0], out[1], [outputs[j] for j in np.flatnonzero(flat)]


def percentile_interval(values: np.ndarray) -> tuple[float, float]:
    """(lo, hi): the CONFIDENCE percentile interval of bootstrap replicates (n,)."""
    a = (1 - CONFIDENCE) / 2
    lo, hi = np.quantile(values, [a, 1 - a])
    return float(lo), float(hi)


@dataclass
class CandidateScore:
    """One candidate, scored: what the report and the verdict need (JSON-able)."""

    name: str
    losses: np.ndarray  #: (R, I) every item's loss in every bootstrap replicate
    point: np.ndarray  #: (I,) the losses of the point estimates
    details: dict  #: item id -> label -> [point, lo, hi]
    indices: dict  #: study -> "S1"/"ST" -> signal -> instant label -> factor -> [point, lo, hi]
    frequency: dict  #: x_m, f_hz over the stroke, f_max_hz, x_at_max_m, B_eff_implied [lo, point, hi] Pa
    lift: dict  #: max_kg and one row per load
    constant: list  #: outputs that did not vary (indices taken as 0)
    runtime_s: float
    fingerprint: str = ""

    def to_json(self) -> dict:
        d = asdict(self)
        d["losses"], d["point"] = self.losses.tolist(), self.point.tolist()
        return d

    @classmethod
    def from_json(cls, d: dict) -> "CandidateScore":
        d = dict(d)
        d["losses"], d["point"] = np.array(d["losses"]), np.array(d["point"])
        return cls(**d)


def score_candidate(spec: ReconstructionSpec, cand: Candidate, counts: np.ndarray, bar=None) -> CandidateScore:
    """Run both studies on ``cand``, score the indices against the evidence, and add Fig. 4's
    natural frequency and the lift check."""
    t0 = time.perf_counter()
    point_tables, rep_tables, constant, summary = {}, {}, [], {}
    for name, sspec in spec.studies.items():
        model = candidate_model(spec, name, cand)
        design = saltelli_design(sspec.study.problem, N=spec.N, seed=spec.seed)
        X = design.X
        Y = np.vstack([model(X[i:i + _CHUNK_RUNS]) for i in range(0, len(X), _CHUNK_RUNS)])
        if not np.isfinite(Y).all():
            raise sam.UserError(f"{spec.source}: candidate {cand.name!r}, study {name!r}: the model returned "
                                f"NaN/inf for {int((~np.isfinite(Y)).any(axis=1).sum())} runs")
        point_tables[name], rep_tables[name], flat = indices_with_replicates(design, Y, counts, model.outputs)
        constant += [f"{name}: {s} at {instant_label(t)}" for s, t in flat]
        summary[name] = _summarise(point_tables[name], rep_tables[name])
        if bar is not None:
            bar.update(1)
    freq = _frequency(spec, cand)
    R = counts.shape[0]
    reps = IndexTable(rep_tables, {"frequency_hz": freq["f_max_hz"]}, R)
    pt = IndexTable(point_tables, {"frequency_hz": freq["f_max_hz"]}, 1)
    losses = np.stack([e.loss(reps) for e in spec.evidence], axis=1)
    point = np.array([e.loss(pt)[0] for e in spec.evidence])
    details = {}
    for e in spec.evidence:
        p, r = e.details(pt), e.details(reps)
        details[e.id] = {k: [float(p[k][0]), *percentile_interval(r[k])] for k in p}
    return CandidateScore(cand.name, losses, point, details, summary, freq, _lift(spec, cand), constant,
                          time.perf_counter() - t0)


def _summarise(point: StudyIndices, reps: StudyIndices) -> dict:
    out = {}
    for index in ("S1", "ST"):
        by_signal: dict = {}
        for j, (signal, t) in enumerate(point.outputs):
            by_signal.setdefault(signal, {})[instant_label(t)] = {
                f: [float(getattr(point, index)[0, i, j]), *percentile_interval(getattr(reps, index)[:, i, j])]
                for i, f in enumerate(point.factors)}
        out[index] = by_signal
    return out


def _frequency(spec: ReconstructionSpec, cand: Candidate) -> dict:
    """Fig. 4: the linearised natural frequency over the stroke with the experiment's load, and
    the nominal B_eff that would put its maximum at the published one (+- the reading)."""
    p = cand.plant.vector()
    p[sam.P.m_L] = next(iter(spec.studies.values())).study.model.base[sam.P.m_L]
    x, f = natural_frequency_over_stroke(p, spec.frequency_points)
    k = int(np.nanargmax(f))

    def at_beff(B, target):
        q = p.copy()
        q[sam.P.B_eff] = B
        return natural_frequency(q, x[k]) - target

    out = {"x_m": x.tolist(), "f_hz": f.tolist(), "f_max_hz": float(f[k]), "x_at_max_m": float(x[k])}
    published = [e for e in spec.evidence if isinstance(e, Frequency)]
    if published:
        e = published[0]
        out["B_eff_implied_Pa"] = [_implied(at_beff, p[sam.P.B_eff] * ((e.target_hz + d) / f[k]) ** 2, e.target_hz + d)
                                   for d in (-e.reading_hz, 0.0, e.reading_hz)]
    return out


def _implied(residual, guess: float, target: float) -> float:
    """The B_eff [Pa] where residual(B, target) = 0, near the guess of omega^2 ~ B (the oil spring);
    the guess itself where the root is not bracketed within a factor of 1.5 (an overdamped mode)."""
    try:
        return float(brentq(residual, guess / 1.5, guess * 1.5, args=(target,), rtol=1e-6))
    except ValueError:
        return float(guess)


def _lift(spec: ReconstructionSpec, cand: Candidate) -> dict:
    rows = lift_check(cand.plant, spec.lift_masses, spec.lift_from_m, u_V=spec.lift_u_V,
                      duration_s=spec.lift_duration_s)
    return {"max_kg": max_liftable_mass(cand.plant, spec.lift_from_m),
            "rows": [asdict(r) for r in rows]}


# -- the verdict -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Verdict:
    """Candidates ranked on every item (1 = best, ties averaged) and on average.

    Arrays are over candidates (K) in the study's order; ``*_ci`` are 95 % bootstrap intervals.
    """

    names: tuple[str, ...]
    item_ids: tuple[str, ...]
    ranks: np.ndarray  #: (K, I) rank of each candidate on each item (point estimates)
    best: dict  #: item id -> names best on it or tied with the best (paired interval includes 0)
    mean_rank: np.ndarray  #: (K,) over the items, equal weights
    mean_rank_ci: np.ndarray  #: (K, 2)
    mean_rank_reps: np.ndarray  #: (K, R) in every bootstrap replicate
    group_rank: np.ndarray  #: (K,) mean over groups of the mean rank within each group
    p_best: np.ndarray  #: (K,) share of replicates in which the candidate has the best mean rank
    winner: str
    runner_up: str
    margin: float  #: runner-up's mean rank minus the winner's
    margin_ci: tuple[float, float]
    group_winner: str  #: the winner under group weights
    reference: str  #: the first candidate listed (today's model, by convention)
    reference_margin: float  #: its mean rank minus the winner's
    reference_margin_ci: tuple[float, float]

    @property
    def tied(self) -> bool:
        return self.margin_ci[0] <= 0.0

    def statement(self) -> str:
        """One or two sentences: who wins and by how much, or that the best are tied."""
        k = len(self.names)
        w = self.names.index(self.winner)
        lo, hi = self.margin_ci
        wins = sum(self.winner in v for v in self.best.values())
        text = (f"**{self.winner}** has the best mean rank over the {len(self.item_ids)} evidence items, "
                f"{self.mean_rank[w]:.2f} of {k} [{self.mean_rank_ci[w, 0]:.2f}, {self.mean_rank_ci[w, 1]:.2f}], "
                f"and is best or tied with the best on {wins} of them. ")
        if self.tied:
            text += (f"It is **tied within the intervals** with {self.runner_up}: the runner-up's mean rank is "
                     f"{self.margin:.2f} higher [{lo:.2f}, {hi:.2f}], an interval that includes 0.")
        else:
            text += (f"It beats the runner-up, {self.runner_up}, by {self.margin:.2f} in mean rank "
                     f"[{lo:.2f}, {hi:.2f}], and has the best mean rank in {self.p_best[w]:.0%} of the "
                     f"bootstrap replicates.")
        if self.reference not in (self.winner, self.runner_up):
            lo, hi = self.reference_margin_ci
            text += (f" The first candidate listed, {self.reference}, ranks {self.reference_margin:.2f} behind it "
                     f"[{lo:.2f}, {hi:.2f}]" + (", also within the intervals." if lo <= 0 else "."))
        if self.group_winner != self.winner:
            text += f" Weighting each kind of evidence equally instead, {self.group_winner} wins."
        else:
            text += " Weighting each kind of evidence equally instead gives the same winner."
        return text


def tie_within(values: np.ndarray, resolution: float) -> np.ndarray:
    """``values`` (K, ...) with each run of values along axis 0 that lie within ``resolution`` of
    the smallest of the run set to that smallest: losses closer than the resolution rank as ties,
    wherever they fall (rounding would split two neighbours that straddle a rounding edge)."""
    order = np.argsort(values, axis=0, kind="stable")
    v = np.take_along_axis(values, order, axis=0)
    start = v[0].copy()
    out = np.empty_like(v)
    out[0] = start
    for k in range(1, len(v)):
        start = np.where(v[k] - start >= resolution, v[k], start)
        out[k] = start
    snapped = np.empty_like(values)
    np.put_along_axis(snapped, order, out, axis=0)
    return snapped


def decide(scores: list[CandidateScore], groups: list[str], item_ids: list[str], items=None) -> Verdict:
    """Rank the candidates on each item (all, or the columns ``items``) and on average; paired
    bootstrap intervals throughout."""
    items = list(range(len(item_ids))) if items is None else list(items)
    groups, item_ids = [groups[i] for i in items], [item_ids[i] for i in items]
    names = tuple(s.name for s in scores)
    point = tie_within(np.stack([s.point[items] for s in scores]), RESOLUTION)  # (K, I)
    reps = tie_within(np.stack([s.losses[:, items] for s in scores]), RESOLUTION)  # (K, R, I)
    ranks = rankdata(point, axis=0)
    rank_reps = rankdata(reps, axis=0)  # (K, R, I)
    mean_rank, mean_reps = ranks.mean(axis=1), rank_reps.mean(axis=2)
    by_group = {g: [i for i, gi in enumerate(groups) if gi == g] for g in dict.fromkeys(groups)}
    group_rank = np.mean([ranks[:, ix].mean(axis=1) for ix in by_group.values()], axis=0)
    best = {}
    for i, item in enumerate(item_ids):
        b = int(np.argmin(point[:, i]))
        diff = reps[:, :, i] - reps[b, :, i]  # (K, R) paired
        tied = np.quantile(diff, (1 - CONFIDENCE) / 2, axis=1) <= 0
        best[item] = [names[k] for k in np.flatnonzero(tied | (point[:, i] <= point[b, i]))]
    order = np.lexsort((group_rank, mean_rank))
    w, r = int(order[0]), int(order[1]) if len(order) > 1 else int(order[0])
    lowest = mean_reps == mean_reps.min(axis=0)
    return Verdict(
        names=names, item_ids=tuple(item_ids), ranks=ranks, best=best, mean_rank=mean_rank,
        mean_rank_ci=np.array([percentile_interval(m) for m in mean_reps]), mean_rank_reps=mean_reps, group_rank=group_rank,
        p_best=(lowest / lowest.sum(axis=0)).mean(axis=1), winner=names[w], runner_up=names[r],
        margin=float(mean_rank[r] - mean_rank[w]), margin_ci=percentile_interval(mean_reps[r] - mean_reps[w]),
        group_winner=names[int(np.lexsort((mean_rank, group_rank))[0])], reference=names[0],
        reference_margin=float(mean_rank[0] - mean_rank[w]), reference_margin_ci=percentile_interval(mean_reps[0] - mean_reps[w]),
    )


# -- running a study ---------------------------------------------------------------------------


def candidate_fingerprint(spec: ReconstructionSpec, cand: Candidate) -> str:
    """sha256 of everything a candidate's saved result depends on."""
    try:
        version = metadata.version("sam-fdi")
    except metadata.PackageNotFoundError:
        version = "unknown"
    studies = {n: hashlib.sha256(s.source.read_bytes()).hexdigest() for n, s in spec.studies.items()}
    rest = {k: v for k, v in spec.table.items() if k not in ("candidates", "defaults", "name", "description")}
    blob = {"format": FORMAT, "version": version, "studies": studies, "spec": rest,
            "candidate": cand.settings, "plant": cand.plant.vector().tolist()}
    return hashlib.sha256(json.dumps(blob, sort_keys=True, default=str).encode()).hexdigest()


def _write_json_atomic(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(obj))
    os.replace(tmp, path)


@dataclass
class ReconstructionResult:
    spec: ReconstructionSpec
    scores: list[CandidateScore]
    verdicts: dict[str, Verdict]  #: "headline" (the issue's evidence) and, with more items, "all"
    runtime_s: float
    computed: int = 0
    reused: int = 0

    @property
    def verdict(self) -> Verdict:
        return self.verdicts["headline"]


def run_reconstruction(spec: ReconstructionSpec, out: Path, *, resume: bool = False, progress: bool = True,
                       threads: int | None = None) -> ReconstructionResult:
    """Score every candidate (reusing saved ones whose fingerprint matches when ``resume``) and
    decide. Candidates are saved to ``out/candidates`` as they finish."""
    if threads is not None:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    t0 = time.perf_counter()
    folder = out / "candidates"
    folder.mkdir(parents=True, exist_ok=True)
    counts = resample_counts(spec.N, spec.n_bootstrap, np.random.SeedSequence(spec.seed, spawn_key=(0xB007,)))
    scores, computed, reused = [], 0, 0
    steps = len(spec.candidates) * len(spec.studies)
    with tqdm(total=steps, desc="candidates", unit="study", disable=not progress) as bar:
        for cand in spec.candidates:
            fp = candidate_fingerprint(spec, cand)
            path = folder / f"{cand.name}.json"
            saved = _load(path) if resume else None
            if saved is not None and saved.fingerprint == fp:
                scores.append(saved)
                reused += 1
                bar.update(len(spec.studies))
                continue
            bar.set_postfix_str(cand.name)
            score = score_candidate(spec, cand, counts, bar)
            score.fingerprint = fp
            _write_json_atomic(path, score.to_json())
            scores.append(score)
            computed += 1
    groups, ids = [e.group for e in spec.evidence], [e.id for e in spec.evidence]
    headline = [i for i, e in enumerate(spec.evidence) if e.headline]
    verdicts = {"headline": decide(scores, groups, ids, headline)}
    if len(headline) < len(ids):
        verdicts["all"] = decide(scores, groups, ids)
    return ReconstructionResult(spec, scores, verdicts, time.perf_counter() - t0, computed, reused)


def main_effects(result: "ReconstructionResult", verdict: str = "headline") -> dict:
    """Each convention on its own. For each factor of the study's grid and each of its options:
    the mean over the candidates with that option of each item's loss, and of their mean rank
    with its interval, and the difference of that mean rank to the factor's best option with
    its (paired) interval. {factor: {option: {"losses": {item: mean}, "mean_rank": [point, lo,
    hi], "behind_best": [point, lo, hi], "n": candidates}}}; empty without [factors]."""
    v = result.verdicts[verdict]
    ids = [e.id for e in result.spec.evidence]
    by_factor: dict = {}
    for k, c in enumerate(result.spec.candidates):
        for f, o in c.levels.items():
            by_factor.setdefault(f, {}).setdefault(o, []).append(k)
    gridded = sum(bool(c.levels) for c in result.spec.candidates)
    if gridded != int(np.prod([len(o) for o in by_factor.values()])):
        return {}  # not every combination: an option's average would mix in its partners' effects
    out: dict = {}
    for f, options in by_factor.items():
        reps = {o: v.mean_rank_reps[ks].mean(axis=0) for o, ks in options.items()}
        point = {o: float(v.mean_rank[ks].mean()) for o, ks in options.items()}
        best = min(point, key=point.get)
        out[f] = {o: {"losses": {i: float(np.mean([result.scores[k].point[j] for k in ks])) for j, i in enumerate(ids)},
                      "mean_rank": [point[o], *percentile_interval(reps[o])],
                      "behind_best": [point[o] - point[best], *percentile_interval(reps[o] - reps[best])], "n": len(ks)}
                  for o, ks in options.items()}
    return out


def _load(path: Path) -> CandidateScore | None:
    """A saved candidate, or None if there is none or it cannot be read (it is then computed again)."""
    try:
        return CandidateScore.from_json(json.loads(path.read_text()))
    except (OSError, ValueError, TypeError, KeyError):
        return None
