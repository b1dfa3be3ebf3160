"""The diagnosis of a filtered recording: it drives the stages, one way.

filter output -> :func:`fdi.statistics.statistics` -> :func:`fdi.alarms.alarms` -> for each
alarm the likelihood bank (:func:`fdi.isolation.judge_alarms`): a withdrawn alarm restarts the
tests after its window (:func:`fdi.statistics.restart`) and the next alarm is judged, until
one stands or the record ends (:func:`judge`) -> :class:`Diagnosis`: healthy, a fault, several
faults, or a fault that is not isolable, with sizes, confidences and the filter's health.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from .alarms import first_alarm, first_alarms, nis_alarm
from .bank import DESIGN, BankDesign, run_reference
from .conditions import first_motion_s, held_on_stop, long_stroke_mask, on_end_stop, pinned, resting_on_stop
from .faults import MULTI, PAIR_SEP, PARAMS, hypothesis_name, size_entry
from .filter import FilterOutput, sample_step
from .isolation import (
    Decision, best_single, confirm_evidence, judge_alarms, margin_for, margin_level, max_episodes,
)
from .states import leak_lpm
from .statistics import RestartBasis, Statistics, restart, restart_basis, statistics, tested_seconds
from .thresholds import Thresholds

STATUSES = ("healthy", "fault", "several faults", "fault, not isolable")


@dataclass(frozen=True)
class Diagnosis:
    """The diagnosis of one recording: what diagnosis.json holds."""

    status: str  #: one of STATUSES
    isolated: list  #: hypotheses held responsible (the candidates when not isolable)
    detection_time_s: float | None  #: the alarm that stood (or the model-fit alarm) [s]
    alarms: dict  #: test -> its first alarm [s] (the offset only on the side that alarmed first)
    size: dict  #: hypothesis -> {"value", "minus_2sigma", "plus_2sigma", "unit"}
    confidence: dict  #: hypothesis -> posterior probability with equal priors
    model_fit_alarm_s: float | None  #: the first model-fit (NIS) alarm [s]
    filter_health: dict  #: the filter's resets, gaps, held and tested seconds, the input's checks
    thresholds: dict  #: the settings the diagnosis was made with
    note: str = ""  #: what the status alone does not say
    isolation_time_s: float | None = None  #: when the bank named the fault [s]
    likelihood: dict = field(default_factory=dict)  #: the bank's evidence [nats] and the alarms it judged
    detail: str = ""  #: the evidence behind the note, for whoever checks it (diagnosis.json only)

    def to_json(self) -> str:
        """diagnosis.json's text."""
        return json.dumps(asdict(self), indent=2, default=float)

    def reading(self) -> str:
        """The status with the faults named, their sizes and the alarm, in one line."""
        line = self.status
        if self.isolated:  # the bank may name another hypothesis than the one that alarmed first
            line += ": " + ", ".join(f"{h} {self.size[h]['value']:.3g} {self.size[h]['unit']}" if h in self.size else h
                                     for h in self.isolated)
            if self.detection_time_s is not None:
                line += f" (alarm t = {self.detection_time_s:.3f} s)"
        return line

    def caveats(self) -> list:
        """What keeps the recording from supporting a diagnosis, in words ([] when nothing does):
        a constant valve input, a model that does not fit the measurements."""
        h = self.filter_health
        out = [h["input_not_excited"]] if h.get("input_not_excited") else []
        if h.get("model_fit_warning"):
            why = ([f"NIS alarm at t = {self.model_fit_alarm_s:.3f} s"] if self.model_fit_alarm_s is not None else []) \
                + ([f"{h['covariance_resets'] + h['state_resets']} filter resets"]
                   if h.get("covariance_resets", 0) + h.get("state_resets", 0) else [])
            out.append(f"the model does not fit the measurements ({', '.join(why)}): check the plant file "
                       "(`samfdi mismatch` locates what differs)")
        return out

    def headline(self) -> str:
        """What a person reads first: the :meth:`reading`, or, when the recording cannot support a
        diagnosis, that and why on the first line and the reading, marked as such, on the second."""
        caveats = self.caveats()
        if not caveats:
            return self.reading()
        return (f"no diagnosis (the recording cannot support one): {'; '.join(caveats)}\n"
                f"the detector's reading, not a diagnosis: {self.reading()}")


@dataclass(frozen=True)
class Verdict:
    """The bank's verdict on a run, as the diagnosis reports it."""

    status: str
    isolated: list
    size: dict
    confidence: dict
    isolation_time_s: float | None
    likelihood: dict
    note: str
    detail: str = ""


def judge(out: FilterOutput, th: Thresholds, stats: Statistics | None = None, baseline=None, rows=None,
          k_stop=None, size: bool = True, pairs: bool | None = None, design: BankDesign = DESIGN) -> dict:
    """Judge the alarms of runs ``rows`` (default: every run) of ``out``: run -> Decision. Each
    alarm goes to the bank over the decision window after it; a withdrawn alarm restarts that
    run's tests at the window's end (the wandering parameters' baselines re-learnt there) and the
    next alarm is judged, at most :func:`fdi.isolation.max_episodes` times. A run's decision is its
    first confirmed one (with the earlier withdrawn alarms), else its last withdrawn one.
    ``stats``: :func:`fdi.statistics.statistics` of ``out`` (computed here if None); ``baseline``
    as given to it; ``k_stop`` (per row): never judged beyond; ``size``, ``pairs``: the sizing and
    several-faults stages (``pairs`` None: the thresholds' ``several_faults``); ``th``: the
    thresholds; ``design``: the likelihood bank's settings."""
    dt = sample_step(out.t)
    stats = statistics(out, th, baseline) if stats is None else stats
    pairs = th.confirmation.several_faults if pairs is None else pairs
    B, T = out.mean.shape[:2]
    rows = np.arange(B) if rows is None else np.asarray(rows, dtype=np.int64)
    stop = np.full(B, T, dtype=np.int64)
    if k_stop is not None:
        stop[rows] = np.minimum(T, k_stop)
    # the change test is armed after the baseline window (own baseline) or the warm-up
    k_ready = int(round((th.window.warmup_s + (th.window.baseline_s if baseline is None else 0.0)) / dt))
    common = dict(margin=margin_for(th.confirmation.false_isolation_level), horizon_s=design.decision_window_s,
                  size=size, pairs=pairs, pair_horizon_s=design.pair_window_s,
                  confirm=confirm_evidence(th.confirmation.confirm_nats), hidden=held_on_stop(out, th),
                  on_stop=on_end_stop(out), design=design, persist_s=th.confirmation.persist_s)
    decs = judge_alarms(out, stats, *first_alarms(stats, th.test.h), k_ready, rows=rows, k_stop=stop[rows], **common)
    todo = _withdraw(decs, decs)
    # the reference is causal: one run over each restarting run's whole record serves all its later episodes
    reference = basis = None
    for _ in range(max_episodes(T, dt, design) - 1):
        start = np.zeros(B, dtype=np.int64)
        for b in todo:  # the tests restart where the withdrawn alarm's window ended
            start[b] = decs[b].standing.window_end
        todo = [b for b in todo if start[b] < stop[b] - 1]
        if not todo:
            return decs
        if reference is None:
            reference = (np.array(todo), run_reference(out, np.array(todo), stop[todo], design))
        # what the tests share across restarts is computed once; each restart only its runs, from it on
        basis = restart_basis(out, th, baseline) if basis is None else basis
        again = restart(basis, todo, start[todo])
        nxt = judge_alarms(out, again, *first_alarms_of(again, th.test.h, todo), np.maximum(k_ready, start),
                           rows=np.array(todo), k_stop=stop[todo], reference=reference, **common)
        todo = _withdraw(nxt, decs)
    for b in todo:
        decs[b] = replace(decs[b], episodes_capped=True)
    return decs


def first_alarms_of(stats: Statistics, h: dict, rows) -> tuple[np.ndarray, tuple]:
    """:func:`fdi.alarms.first_alarms` of runs ``rows`` of restarted statistics (:func:`restart`),
    looked for from their earliest restart on (0 before it): (B,) the first alarm (-1: none or
    not in ``rows``) and per run the test (None: none or not in ``rows``)."""
    rows = np.asarray(rows, dtype=np.int64)
    B = len(stats.start)
    s0 = int(stats.start[rows].min())
    k, who_rows = first_alarms(Statistics({n: g[rows, s0:] for n, g in stats.items()}, stats.start[rows]), h)
    first = np.full(B, -1, dtype=np.int64)
    first[rows] = np.where(k >= 0, k + s0, -1)
    who = [None] * B
    for b, w in zip(rows, who_rows):
        who[b] = w
    return first, tuple(who)


def _withdraw(new: dict, decs: dict) -> list:
    """Put the decisions ``new`` into ``decs`` (run -> Decision), each carrying the run's earlier
    withdrawn alarms and its own if it is not confirmed; returns the runs withdrawn again."""
    for b, d in new.items():
        earlier = decs[b] if decs[b] is not d else replace(d, withdrawn=(), restarts=())
        mine = not d.standing.confirmed
        decs[b] = replace(d, withdrawn=earlier.withdrawn + ((d.standing.alarm,) if mine else ()),
                          restarts=earlier.restarts + ((d.standing.window_end,) if mine else ()))
    return [b for b, d in new.items() if not d.standing.confirmed]


def shown_statistics(out: FilterOutput, th: Thresholds, diag: Diagnosis, baseline=None, b: int = 0) -> dict:
    """The statistics of run b, name -> (1, T), as the detector ran them: restarted after each
    withdrawn alarm with re-learnt baselines (``diag.likelihood["tests_restarted_s"]``)."""
    one = slice(b, b + 1)
    stats = {h: g[one].copy() for h, g in statistics(out, th, baseline).items()}
    basis: RestartBasis | None = None
    for ts in diag.likelihood.get("tests_restarted_s", []):
        k = int(np.searchsorted(out.t, ts))
        basis = restart_basis(out, th, baseline) if basis is None else basis
        for h, g in restart(basis, [b], [k]).items():
            stats[h][0, k:] = g[b, k:]
    return stats


def model_fit_warning(nis_time: float | None, health: dict) -> str:
    """A warning when the model stopped fitting the recording (an NIS alarm, or the filter had to
    reset its covariance or state): a named fault may then be a symptom of a plant file that does
    not describe this machine. '' if not."""
    resets = health["covariance_resets"] + health["state_resets"]
    if nis_time is None and resets == 0:
        return ""
    why = [f"NIS alarm at t = {nis_time:.3f} s"] if nis_time is not None else []
    if resets:
        why.append(f"{health['covariance_resets']} covariance and {health['state_resets']} state resets")
    return (f"the model does not fit this recording ({'; '.join(why)}): the diagnosis may reflect a plant "
            "file that does not describe this machine rather than a fault; check the plant file "
            "(`samfdi mismatch` locates what differs)")


def diagnose(out: FilterOutput, th: Thresholds | None = None, b: int = 0, stats: Statistics | None = None,
             baseline=None, decision: Decision | None = None, design: BankDesign = DESIGN) -> Diagnosis:
    """The diagnosis of run b of the filter output ``out`` under the thresholds ``th`` (default:
    the shipped ones). ``stats``: its statistics (computed if None); ``baseline`` (B, 4): healthy
    values of the fault parameters (None: the recording's own); ``decision``: the bank's decision
    on run b if already judged (:func:`judge`); ``design``: the likelihood bank's settings."""
    th = Thresholds.shipped() if th is None else th
    stats = stats if stats is not None else statistics(out, th, baseline)
    t = out.t
    alarms = {}
    for h, g in stats.items():
        k = int(first_alarm(g[b:b + 1], th.test.h[h])[0])
        if k >= 0:
            alarms[h] = float(t[k])
    k_nis = int(nis_alarm(out, th)[b])
    nis_time = float(t[k_nis]) if k_nis >= 0 else None
    # one-sided offset: keep only the side that alarmed first
    if "offset+" in alarms and "offset-" in alarms:
        del alarms["offset+" if alarms["offset+"] > alarms["offset-"] else "offset-"]
    dt_s = t[1] - t[0] if len(t) > 1 else 0.0
    health = {"nan_samples": int(out.n_nan[b]), "jitter_events": int(out.n_jitter[b]),
              "covariance_resets": int(out.n_cov_reset[b]), "state_resets": int(out.n_state_reset[b]),
              # stalled or on an end stop at supply / tank pressure: the tests it hides are held
              "pinned_s": float(pinned(out, th)[b].any(axis=1).sum() * dt_s),
              # on an end stop with the valve at null: the K_int and offset tests are held
              "resting_on_stop_s": float(resting_on_stop(out, th)[b].sum() * dt_s),
              # in long strokes and the rest after them K_int and the offset count only large excursions
              "long_stroke_s": float(long_stroke_mask(out, th)[b].sum() * dt_s),
              # the own baseline is learnt from the first motion on; None: never moved
              "first_motion_s": first_motion_s(out, th, b)}
    names = sorted(alarms, key=alarms.get)
    if names:
        d = decision if decision is not None else judge(out, th, stats, baseline, rows=[b], design=design)[b]
        v = verdict(out, th, d, design)
    elif nis_time is not None:
        v = Verdict("fault, not isolable", [], {}, {}, None, {},
                    "the model stopped fitting the measurements (NIS alarm) but no fault parameter explains it: an "
                    "unmodelled fault, a sensor fault or a plant-file mismatch")
    else:
        v = Verdict("healthy", [], {}, {}, None, {}, "")
    note = v.note
    warning = model_fit_warning(nis_time, health)
    if warning:
        health["model_fit_warning"] = warning
        if not (v.status == "fault, not isolable" and not names):  # that note says it already
            note = f"{note}; {warning}" if note else warning
    tested = tested_seconds(out, th, baseline)[b]
    health["tested_s"] = {p: float(s) for p, s in zip(PARAMS, tested)}
    least = th.window.min_tested_s
    untested = [p for p, s in zip(PARAMS, tested) if s < least]
    if untested and v.status == "healthy":
        untested_note = (f"healthy as far as tested: {', '.join(untested)} tested for less than {least:g} s "
                         + ("(the pressures pinned at supply and tank, the recording too short after the baseline, "
                            "which is learnt from the first motion, or never in a regime where the thresholds let "
                            "that residual vote)" if health["first_motion_s"] is not None else
                            f"(the valve input never left its +-{th.regimes.band_V:g} V hold band, and the baseline "
                            "is learnt from the first motion)"))
        note = f"{untested_note}; {note}" if note else untested_note
    w, tt, dv = th.window, th.test, th.derived
    return Diagnosis(
        status=v.status, isolated=v.isolated,
        detection_time_s=(v.likelihood.get("alarm_s", alarms[names[0]]) if v.status != "healthy" and names
                          else nis_time),
        alarms=alarms, size=v.size, confidence=v.confidence, model_fit_alarm_s=nis_time, filter_health=health,
        isolation_time_s=v.isolation_time_s, likelihood=v.likelihood, detail=v.detail,
        thresholds={"drift_sigma": tt.drift, "h_sigma_s": dict(tt.h), "warmup_s": w.warmup_s,
                    "baseline": "reference recording" if baseline is not None else
                    f"own estimates over [{w.warmup_s:g}, {w.warmup_s + w.baseline_s:g}] s after the first motion "
                    f"(unpinned samples; the first {w.baseline_s:g} s of them if the record starts pinned)",
                    "false_alarm_level": dv.false_alarm_level, "trigger_level": dv.trigger_level,
                    "run_length_s": dv.run_length_s, "filter_sd_weight": {p: tt.sd_weight(p) for p in PARAMS},
                    "cusum_memory_s": tt.memory_s, "long_stroke_s": th.regimes.long_stroke_s,
                    "long_stroke_drift_sigma": tt.long_stroke_drift, "long_stroke_params": list(tt.long_stroke_params),
                    "isolation": "likelihood", "position_sensor": dv.position_sensor, "source": dv.source},
        note=note,
    )


def verdict(out: FilterOutput, th: Thresholds, d: Decision, design: BankDesign = DESIGN) -> Verdict:
    """The diagnosis of a run from the bank's decision ``d`` on its alarms: healthy when none
    stood; else the fault named (and sized), several faults, or the candidates that explain the
    data alike, with confidences (posterior probabilities with equal priors)."""
    if not d.standing.confirmed:
        return _withdrawn(out, th, d, design)
    n, sv, level = d.naming, d.several, th.confirmation.false_isolation_level
    margin = margin_for(level)
    name = hypothesis_name(n.hypothesis or (n.candidates[0] if n.candidates else "offset"), n.size)
    # +-2 sigma band: the bank filter's std and the healthy spread from model uncertainty
    size = size_entry(name, n.size, math.hypot(n.size_sd, th.test.nuisance_sd.get(name.rstrip("+-"), 0.0)))
    w = {h: math.exp(v) for h, v in n.llr.items()}
    tot = sum(w.values())
    conf = {hypothesis_name(h, n.size if h == n.hypothesis else 0.0): v / tot for h, v in w.items()}
    lik = {"log_likelihood_minus_best_nats": n.llr, "best_minus_healthy_nats": n.llr_none,
           "margin_nats": margin, "bank_start_s": float(out.t[min(n.k0, len(out.t) - 1)]),
           **_alarm_record(out, th, d)}
    pair_llr = sv.pair_llr if sv is not None else {}
    if pair_llr:
        lik["pair_minus_best_single_nats"] = pair_llr
    if sv is not None and sv.members:
        return _several(out, th, d, lik, margin)
    if sv is not None and sv.revised is not None:
        return _revised(out, th, d, lik, hypothesis_name(best_single(d), n.size))
    if sv is not None and sv.pair_candidates:
        # the member of each leading pair that is not the best single fault (either order)
        base = name.rstrip("+-")
        second = list(dict.fromkeys(m for p in sv.pair_candidates for m in p.split(PAIR_SEP) if m != base))
        pair_margin = margin_for(level, len(MULTI))
        lead = max(pair_margin, confirm_evidence(th.confirmation.confirm_nats))
        pairs = ", ".join(f"{p} ({pair_llr[p]:+.1f} nats)" if p in pair_llr else p for p in sv.pair_candidates)
        note = (f"no single fault explains the data after the alarm: the pairs {pairs} lead every single fault "
                f"by >= {lead:.3g} nats, but none leads the others by {pair_margin:.3g} nats (the margin of a "
                f"{level:g} false-isolation level): the second fault is not isolable")
        return Verdict("fault, not isolable", [name] + second, {name: size}, conf, None, lik, note)
    if n.hypothesis is not None:
        note = ""
        if sv is not None and sv.window_misfit:
            note = (f"the data after the alarm fit no constant fault or pair (every mean NIS above "
                    f"{design.fit_nis:g}, the filter's expected value): the fault may be intermittent or "
                    f"changing; the decision at the alarm stands")
        return Verdict("fault", [name], {name: size}, conf, float(out.t[n.index]), lik, note)
    cands = [hypothesis_name(h, n.size) for h in n.candidates]
    note = (f"no single-fault hypothesis beats the others by {margin:.2g} nats (the margin of a "
            f"{level:g} false-isolation level): {', '.join(cands)} explain the data alike")
    return Verdict("fault, not isolable", cands, {name: size}, conf, None, lik, note)


def _alarm_record(out: FilterOutput, th: Thresholds, d: Decision) -> dict:
    """The likelihood entries of the alarm a decision answers: its time, the confirmation (the
    evidence needed, the instant) and the run's withdrawn alarms [s]."""
    t, s, confirm = out.t, d.standing, th.confirmation.confirm_nats
    rec = {"alarm_s": float(t[s.alarm]) if s.alarm >= 0 else None,
           "confirm_nats": confirm if confirm > 0 else None,
           "confirm_persist_s": th.confirmation.persist_s if confirm > 0 and th.confirmation.persist_s > 0 else None,
           "confirmed_s": float(t[s.confirm_index]) if s.confirm_index >= 0 else None,
           "withdrawn_alarms_s": [float(t[k]) for k in d.withdrawn],
           "tests_restarted_s": [float(t[k]) for k in d.restarts if k < len(t)]}  # not at the record's end
    if d.episodes_capped:
        rec["episodes_capped"] = len(d.withdrawn)
    return rec


def _withdrawn(out: FilterOutput, th: Thresholds, d: Decision, design: BankDesign) -> Verdict:
    """A run none of whose alarms was confirmed: healthy, one plain sentence as its note and the
    evidence (times, nats, sizes) as its detail."""
    rec = _alarm_record(out, th, d)
    n = len(rec["withdrawn_alarms_s"])
    times = ", ".join(f"{s:.3f}" for s in rec["withdrawn_alarms_s"])
    least = design.min_single_size
    growing = f", that lead still growing over {rec['confirm_persist_s']:g} s," if rec["confirm_persist_s"] else ""
    detail = (f"alarm(s) at t = {times} s withdrawn: in the {design.decision_window_s:g} s after each, no fault "
              f"hypothesis explained the measurements better than the healthy model by {rec['confirm_nats']:.2g} nats"
              f"{growing} with its fault parameter moved by at least {leak_lpm(least['K_int']):.2g} L/min or "
              f"{100 * least['offset']:.2g} % (largest lead {d.standing.lead_max:.1f} nats in the last window)")
    if d.episodes_capped:
        detail += f"; the tests were not restarted after {rec['episodes_capped']} withdrawn alarms"
    note = (f"{n} brief alarm{' was' if n == 1 else 's were'} checked and withdrawn: no fault fits better than "
            "healthy (details in diagnosis.json)")
    return Verdict("healthy", [], {}, {}, None, {"best_minus_healthy_nats": d.naming.llr_none, **rec}, note, detail)


def _revised(out: FilterOutput, th: Thresholds, d: Decision, lik: dict, early: str) -> Verdict:
    """A decision the several-faults window overturned: the later single fault, sized by that
    window's filter, its confidence the posterior bound of its lead."""
    n, sv = d.naming, d.several
    name = hypothesis_name(sv.revised, sv.revised_size)
    s = math.hypot(sv.revised_size_sd, th.test.nuisance_sd.get(sv.revised, 0.0))
    lik = {**lik, "revised_from": early, "revised_lead_nats": sv.revised_llr}
    if n.index >= 0:
        first = f"first isolated as {early} at {float(out.t[n.index]):.3f} s"
    else:
        first = f"not isolable at first (best {early}; candidates {', '.join(n.candidates)})"
    note = (f"{first}; the data after the alarm (restarted filters, to {float(out.t[sv.revised_index]):.3f} s) "
            f"favour {name} over every other single fault by {sv.revised_llr:.0f} nats: revised to {name}")
    conf = {name: 1.0 - margin_level(min(sv.revised_llr, 700.0))}
    return Verdict("fault", [name], {name: size_entry(name, sv.revised_size, s)}, conf,
                   float(out.t[sv.revised_index]), lik, note)


def _several(out: FilterOutput, th: Thresholds, d: Decision, lik: dict, margin: float) -> Verdict:
    """An accepted pair: both members sized by the pair's filter (+-2 sigma with the healthy
    spread); a member's confidence is the posterior probability (equal priors) of the hypotheses
    that contain it, among the best single and the pairs."""
    sv = d.several
    names, size = [], {}
    for m in sv.members:
        nm = hypothesis_name(m, sv.size[m])
        names.append(nm)
        size[nm] = size_entry(nm, sv.size[m], math.hypot(sv.size_sd[m], th.test.nuisance_sd.get(m, 0.0)))
    h1 = best_single(d)
    w = {h1: 1.0, **{p: math.exp(min(v, 700.0)) for p, v in sv.pair_llr.items()}}
    tot = sum(w.values())
    conf = {nm: sum(v for p, v in w.items() if m in p.split(PAIR_SEP)) / tot for m, nm in zip(sv.members, names)}
    note = (f"{'+'.join(sv.members)} leads {h1} alone and the other pairs by >= {margin:.2g} nats "
            f"(the margin of a {th.confirmation.false_isolation_level:g} false-isolation level)")
    return Verdict("several faults", names, size, conf, float(out.t[sv.index]), lik, note)
