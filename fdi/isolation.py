"""Isolation and sizing: the likelihood bank's verdict on one alarm per run.

For a run that alarmed at sample k_a (:mod:`fdi.alarms`):

1. **onset**: k0, one past the last zero of the alarming CUSUM before k_a, ``onset_lead_s``
   earlier, never before the baseline is learnt (:func:`onset_index`);
2. **bank** (:mod:`fdi.bank`): the healthy reference over [0, k0], then one constrained filter
   per hypothesis from k0 and from later candidate onsets, up to ``min_evidence_s`` after k0 or
   the alarm, whichever is later, and if undecided over the whole window;
3. **decision** (:func:`decide`): the first sample at which the best fault's evidence
   L_H(k) = sum log N(nu_H,i; 0, S_H,i) leads every other fault by the margin of the stated
   false-isolation level (:func:`margin_for`), causal. The alarm *stands* if the best fault beats
   the healthy hypothesis by ``confirm_nats`` with its parameter moved by the smallest size of
   interest; otherwise it is withdrawn;
4. **size**: the named hypothesis' filter alone from its onset over the window; its last
   estimate minus the healthy value;
5. **several faults** (:func:`decide_pair`): every single fault and pair restarted after the
   alarm over ``pair_window_s``, decided once at the end: a pair leading every single and every
   other pair by the margin for ten hypotheses (and its second fault by the confirmation
   evidence), or a single fault that revises the early decision.

The margin is not fitted: with equal priors, the best of n hypotheses has posterior probability
at least 1 / (1 + (n - 1) e^-margin). The evidence is the Kalman predictive p(y | H) with the
free parameters as Gaussian constants, so a pair's second parameter pays its Occam factor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .bank import (
    DESIGN, BankDesign, BankResult, bank_config, confirm_calibration, reference_rows, run_bank_starts,
    run_hypotheses, run_pairs, run_reference, start_seed,
)
from .faults import FAULTS, MULTI, PAIR_SEP, hypothesis_name
from .filter import FilterOutput, sample_step
from .statistics import Statistics


@dataclass(frozen=True)
class Naming:
    """The bank's answer to "which fault?" at one alarm."""

    hypothesis: str | None  #: the isolated fault parameter (a FAULTS name), None: not isolable
    index: int  #: recording sample of the decision (-1: none)
    candidates: tuple  #: fault hypotheses within the margin of the best at the decision (or last) sample
    llr: dict  #: hypothesis -> its log-likelihood minus the best's at that sample [nats]
    llr_none: float  #: best fault minus the healthy hypothesis there, in the naming bank [nats]
    k0: int  #: first sample of the bank
    onset: int  #: onset estimate: the start of the best hypothesis' most likely bank
    size: float  #: change of the isolated (or best) parameter, SI
    size_sd: float  #: its filter std, SI


@dataclass(frozen=True)
class Standing:
    """Whether an alarm stands."""

    alarm: int  #: the alarm's recording sample
    confirmed: bool  #: the best fault beat "none" by the confirmation evidence, moved enough
    confirm_index: int  #: recording sample of the confirmation (-1: none)
    lead_max: float  #: largest lead of the best fault over "none" from the alarm on [nats]
    window_end: int  #: one past the last recording sample the alarm was judged on


@dataclass(frozen=True)
class Several:
    """The several-faults window's verdict: restarted filters of every single fault and pair."""

    pair_llr: dict  #: pair -> its log-likelihood minus the best single's [nats]
    pair_nis: dict  #: hypothesis -> its mean NIS over the window
    window_misfit: bool  #: no hypothesis explains the window (every mean NIS above fit_nis)
    members: tuple = ()  #: the accepted pair's two FAULTS names (empty: none accepted)
    index: int = -1  #: recording sample of that decision
    size: dict = field(default_factory=dict)  #: member -> its change from the pair's filter, SI
    size_sd: dict = field(default_factory=dict)  #: member -> its std, SI
    #: pairs ahead of every single by the needed lead but not of each other (an ambiguous second fault)
    pair_candidates: tuple = ()
    revised: str | None = None  #: another single fault this window isolates (None: it confirms, or is undecided)
    revised_llr: float = math.nan  #: its lead over the other singles [nats]
    revised_size: float = math.nan  #: its change, SI
    revised_size_sd: float = math.nan
    revised_index: int = -1  #: recording sample of the revision


@dataclass(frozen=True)
class Decision:
    """The bank's verdict on a run's alarm, and the run's earlier withdrawn alarms."""

    naming: Naming
    standing: Standing
    several: Several | None = None  #: None: the several-faults stage did not run
    withdrawn: tuple = ()  #: recording samples of the run's earlier withdrawn alarms
    restarts: tuple = ()  #: recording samples at which the tests restarted after each
    episodes_capped: bool = False  #: max_episodes alarms withdrawn: the tests were not restarted again


def margin_for(level: float, n_hypotheses: int = len(FAULTS)) -> float:
    """Log-likelihood margin [nats] such that, with equal priors, the best of ``n_hypotheses``
    has posterior >= 1 - level when it beats each other one by the margin:
    margin = ln((n - 1) (1 - level) / level)."""
    return math.log((n_hypotheses - 1) * (1.0 - level) / level)


def margin_level(margin: float, n_hypotheses: int = len(FAULTS)) -> float:
    """The false-isolation level of a margin [nats] (inverse of :func:`margin_for`)."""
    return (n_hypotheses - 1) / (n_hypotheses - 1 + math.exp(margin))


def confirm_evidence(confirm_nats: float) -> float:
    """The lead [nats] of the best fault over "none" an alarm needs to stand (0: -inf, every alarm stands)."""
    return confirm_nats if confirm_nats > 0 else -math.inf


def earliest_decision(k_alarm, k0, dt: float, design: BankDesign = DESIGN):
    """The first sample at which the bank may decide: the alarm, and ``min_evidence_s`` after the
    bank's start k0 (scalars or arrays)."""
    return np.maximum(k_alarm, k0 + int(round(design.min_evidence_s / dt)))


def onset_index(g: np.ndarray, k_alarm: int, k_ready: int, dt: float, design: BankDesign = DESIGN) -> int:
    """Change-time estimate of a CUSUM g (T,) that alarmed at k_alarm: one past its last zero
    before the alarm, ``onset_lead_s`` earlier, not before k_ready (the end of the healthy
    baseline) and never after the alarm."""
    zeros = np.flatnonzero(g[:k_alarm + 1] <= 0.0)
    k = zeros[-1] + 1 if len(zeros) else 0
    return int(min(k_alarm, max(k_ready, k - int(round(design.onset_lead_s / dt)))))


def max_episodes(n_samples: int, dt: float, design: BankDesign = DESIGN) -> int:
    """The most alarms judged in a record of ``n_samples`` of ``dt`` [s]: ``max_episodes``, or one
    per decision window of the record if more (a replay's cost grows with its length, not faster)."""
    return max(design.max_episodes, int(n_samples * dt / design.decision_window_s) + 1)


def moved_enough(fault, change, design: BankDesign = DESIGN) -> np.ndarray:
    """Whether a change (SI) of each fault parameter (FAULTS names; arrays of one shape) reaches
    its smallest size to name: leaks upwards (a leak cannot shrink below healthy), the offset
    either way."""
    fault, change = np.asarray(fault), np.asarray(change, dtype=float)
    least = np.vectorize(design.min_single_size.get, otypes=[float])(fault)
    return np.where(fault == "offset", np.abs(change), change) >= least


def best_single(d: Decision) -> str:
    """The isolated single fault, else the best of the candidates (largest llr)."""
    n = d.naming
    return n.hypothesis if n.hypothesis is not None else max(n.llr, key=n.llr.get)


def evidence(ll: np.ndarray, ll_none: np.ndarray, hidden: np.ndarray | None, k0: int) -> np.ndarray:
    """(L,) the lead of the best fault hypothesis (largest cumulative ll (F, L)) over the healthy
    one (ll_none (L,)) at each bank sample [nats]; with ``hidden`` ((F, T) recording samples from
    ``k0`` on) a hypothesis' lead grows only where its parameter can show."""
    d = ll - ll_none[None, :]
    if hidden is not None:
        inc = np.diff(d, axis=1, prepend=0.0)
        d = np.cumsum(np.where(hidden[:, k0:k0 + ll.shape[1]], 0.0, inc), axis=1)
    return d[np.argmax(ll, axis=0), np.arange(ll.shape[1])]


def credible(bank: BankResult, i: int, fi: list, ll: np.ndarray, hidden: np.ndarray | None = None,
             design: BankDesign = DESIGN) -> np.ndarray:
    """(L,) bool per bank sample: the best hypothesis' filter has moved its parameter enough
    (:func:`moved_enough`) and, with ``hidden`` ((F, T) recording samples), it can show there."""
    best = np.argmax(ll, axis=0)
    hk = np.asarray(fi)[best]
    k = np.arange(ll.shape[1])
    ok = moved_enough(np.asarray(FAULTS)[best], bank.free[i, hk, k] - bank.healthy[i, hk], design)
    if hidden is not None:
        ok &= ~hidden[best, int(bank.k0[i]) + k]
    return ok


def last_shown(ll: np.ndarray, hidden: np.ndarray | None, k0: int, on_stop: np.ndarray | None = None) -> np.ndarray:
    """(L,) per bank sample k: the sample whose data a decision at k is taken on: k itself where
    the best hypothesis (largest ll (F, L)) can show; where it cannot (``hidden``), the last sample
    before at which it could with the piston off the end stops (``on_stop`` (T,); -1: none): the
    first samples on a stop, before the test is held, carry the stop's bias."""
    k = np.arange(ll.shape[1])
    if hidden is None:
        return k
    shows = ~hidden[np.argmax(ll, axis=0), k0 + k]
    off = shows if on_stop is None else shows & ~on_stop[k0 + k]
    return np.where(shows, k, np.maximum.accumulate(np.where(off, k, -1)))


def growing(lead: np.ndarray, persist: int) -> np.ndarray:
    """(L,) bool per bank sample k: the lead (L,) [nats] is larger than ``persist`` samples before
    (than 0, the bank's start, earlier on); all True for persist = 0. A fault that is there keeps
    adding evidence; a transient the healthy model mispredicts adds it once, and the fault's
    filter then mispredicts what follows, so its lead stalls or falls."""
    if persist <= 0:
        return np.ones(len(lead), dtype=bool)
    before = np.concatenate([np.zeros(persist), lead[:-persist]]) if len(lead) > persist else np.zeros(len(lead))
    return lead > before


def decide(bank: BankResult, i: int, k_from: int, margin: float, confirm: float = -math.inf,
           hidden: np.ndarray | None = None, conf: tuple | None = None, on_stop: np.ndarray | None = None,
           k_alarm: int = -1, window_end: int = -1, design: BankDesign = DESIGN, persist: int = 0) -> Decision:
    """The bank's decision for run i of ``bank``: the first sample k >= k_from at which the best
    fault beats every other fault by ``margin`` and "none" by ``confirm`` nats, its filter moved
    enough (causal: L_H(k) uses samples up to k). The alarm ``k_alarm`` stands if at some sample
    >= k_from the best fault beats "none" by ``confirm`` and moved enough, named or not.
    ``hidden`` (F, T) bool, FAULTS order, recording samples: where each fault cannot show (on an
    end stop): its evidence counts only where it can, and a decision at a sample where the best
    fault cannot show is taken on the data up to the last sample where it could, off the stops
    (``on_stop`` (T,)). Every lead is divided by the colour of the leading filter's innovations
    (:attr:`BankResult.colour`, :mod:`fdi.whiteness`): what a coloured residual adds is not
    evidence. ``conf``: ((best, runner-up), L (2, L), L_none (L,), their colour (2, L) or None) from
    :func:`confirmation_bank`: the lead that confirms is then the best fault's over that bank's
    "none" (calibration as uncertain constants), and a fault is named only where that bank ranks
    the pair as the naming bank does (there, holding the calibration would decide the name).
    ``persist`` (samples): the lead that confirms must also be still growing over that many
    samples (:func:`growing`; 0: not asked)."""
    names = list(bank.names)
    fi = [names.index(h) for h in FAULTS]
    nv = int(bank.n_valid[i])
    ll = bank.loglik[i][fi, :nv]  # (F, nv)
    start = min(max(0, k_from - int(bank.k0[i])), nv - 1)
    e = last_shown(ll, hidden, int(bank.k0[i]), on_stop)  # each sample's decision uses the data up to e
    shown, e = e >= 0, np.maximum(e, 0)
    # the evidence's honest size: divided by the best filter's innovation colour (fdi.whiteness)
    colour = np.ones(ll.shape) if bank.colour is None else bank.colour[i][fi, :nv]
    f_best = colour[np.argmax(ll[:, e], axis=0), e]
    srt = np.sort(ll[:, e], axis=0) / f_best
    agree = np.ones(len(e), dtype=bool)
    if conf is None:
        lead = evidence(ll, bank.loglik[i, names.index("none"), :nv], hidden, int(bank.k0[i]))[e] / f_best
    else:
        pair, ll_c, ll_n, c_colour = conf
        hid = None if hidden is None else hidden[[FAULTS.index(pair[0])]]
        f_conf = 1.0 if c_colour is None else c_colour[0, :nv][e]
        lead = evidence(ll_c[:1, :nv], ll_n[:nv], hid, int(bank.k0[i]))[e] / f_conf
        named_held = np.asarray(FAULTS)[np.argmax(ll[:, e], axis=0)]
        agree = named_held == np.asarray(pair)[np.argmax(ll_c[:, :nv][:, e], axis=0)]
    lead, rising = lead[start:], growing(lead, persist)[start:]
    ok_move = (credible(bank, i, fi, ll, hidden, design)[e] & shown)[start:]
    strong = (lead >= confirm) & rising
    stood = np.flatnonzero(strong & (ok_move | (confirm == -math.inf)))  # -inf: every alarm stands
    ok = np.flatnonzero((srt[-1, start:] - srt[-2, start:] >= margin) & ok_move & strong & agree[start:])
    at = start + int(ok[0]) if len(ok) else nv - 1
    best = int(np.argmax(ll[:, e[at]]))
    llr = {h: float((ll[q, e[at]] - ll[best, e[at]]) / f_best[at]) for q, h in enumerate(FAULTS)}
    llr_none = float((ll[best, e[at]] - bank.loglik[i, names.index("none"), e[at]]) / f_best[at])
    # size: the best filter's estimate of its constant parameter from all the window's data, minus healthy
    hb = fi[best]
    k0 = int(bank.k0[i])
    common = dict(llr=llr, llr_none=llr_none, k0=k0, onset=int(bank.start[i, hb]),
                  size=float(bank.free[i, hb, nv - 1] - bank.healthy[i, hb]), size_sd=float(bank.free_sd[i, hb, nv - 1]))
    if len(ok):
        naming = Naming(FAULTS[best], k0 + at, (FAULTS[best],), **common)
    else:
        naming = Naming(None, -1, tuple(h for h in FAULTS if llr[h] > -margin), **common)
    standing = Standing(alarm=int(k_alarm), confirmed=bool(len(stood)),
                        confirm_index=k0 + start + int(stood[0]) if len(stood) else -1,
                        lead_max=float(lead.max()), window_end=int(window_end))
    return Decision(naming, standing)


def decide_pair(bank: BankResult, i: int, margin: float, d: Decision, second_fault_nats: float = -math.inf,
                design: BankDesign = DESIGN) -> Several:
    """The several-faults verdict for run i of the several-faults bank (:func:`fdi.bank.run_pairs`,
    hypotheses MULTI), decided ONCE, at the window's last sample (looking at every sample would
    test many times): the best pair is accepted if it leads every single and every other pair by
    ``margin``, every single also by ``second_fault_nats`` (the second fault is held to the
    evidence the first needed), both members moved by ``min_pair_size`` and it explains the
    window (mean NIS <= fit_nis). Pairs ahead of every single but not of each other are
    candidates. The window's singles may revise the early decision ``d`` (:func:`revision`).
    Every lead is divided by the colour of the leader's innovations (:attr:`BankResult.colour`)."""
    names = bank.hyps(i)
    nv = int(bank.n_valid[i])
    ns = len(FAULTS)
    # the evidence's honest size, as in decide: the leads of the best pair (and, for a revision,
    # of the best single) divided by the colour of that leader's innovations
    colour = np.ones(len(names)) if bank.colour is None else bank.colour[i][:, nv - 1]
    raw = bank.loglik[i][:, nv - 1]  # (10,): singles, then pairs
    ll = raw / colour[ns + int(np.argmax(raw[ns:]))]
    single = ll[:ns].max()
    srt = np.sort(ll[ns:])
    pair_llr = {names[ns + q]: float(ll[ns + q] - single) for q in range(len(names) - ns)}
    pair_nis = {names[q]: float(bank.nis[i, q]) for q in range(len(names))}
    fits = bank.nis[i, :len(names)] <= design.fit_nis  # a hypothesis that explains the window
    verdict = Several(pair_llr=pair_llr, pair_nis=pair_nis, window_misfit=not fits.any())
    if fits[int(np.argmax(ll[:ns]))]:
        verdict = replace(verdict, **revision(bank, i, margin, d, raw[:ns] / colour[int(np.argmax(raw[:ns]))], design))
    big = [all(abs(bank.change[i, ns + q, FAULTS.index(m)]) >= design.min_pair_size[m]
               for m in names[ns + q].split(PAIR_SEP)) and fits[ns + q] for q in range(len(names) - ns)]
    lead = max(margin, second_fault_nats)
    if not (srt[-1] - single >= lead and srt[-1] - srt[-2] >= margin and big[int(np.argmax(ll[ns:]))]):
        return replace(verdict, pair_candidates=tuple(p for q, (p, v) in enumerate(pair_llr.items())
                                                      if v >= lead and big[q]))
    q = ns + int(np.argmax(ll[ns:]))
    members = tuple(names[q].split(PAIR_SEP))
    return replace(verdict, members=members, index=int(bank.k0[i]) + nv - 1,
                   size={m: float(bank.change[i, q, FAULTS.index(m)]) for m in members},
                   size_sd={m: float(bank.change_sd[i, q, FAULTS.index(m)]) for m in members})


def revision(bank: BankResult, i: int, margin: float, d: Decision, ll_single: np.ndarray,
             design: BankDesign = DESIGN) -> dict:
    """The revision fields of :class:`Several` when one single fault of the several-faults
    window leads every other single by ``margin``, moved enough, and is not the early decision
    (another parameter, or the other offset side) or nothing was isolated early; {} otherwise.
    The data after the alarm can overturn an early decision (a -5 % offset step fits K_int
    better in its first quarter second)."""
    srt = np.sort(ll_single)
    best = int(np.argmax(ll_single))
    change = float(bank.change[i, best, best])
    early = d.naming
    if srt[-1] - srt[-2] < margin or not moved_enough(FAULTS[best], change, design) or (
            early.hypothesis is not None
            and hypothesis_name(FAULTS[best], change) == hypothesis_name(early.hypothesis, early.size)):
        return {}
    nv = int(bank.n_valid[i])
    return {"revised": FAULTS[best], "revised_llr": float(srt[-1] - srt[-2]), "revised_size": change,
            "revised_size_sd": float(bank.change_sd[i, best, best]), "revised_index": int(bank.k0[i]) + nv - 1}


def confirmation_bank(out: FilterOutput, ref: FilterOutput, bank: BankResult, rows, k0, k1, k_alarm, kept: tuple,
                      ref_rows=None, design: BankDesign = DESIGN) -> list:
    """Per run i of ``rows`` (window [k0[i], k1[i]) of the naming ``bank``): ((best, runner-up),
    L (2, L), L_none (L,), colour (2, L)), the cumulative log-likelihoods of the bank's two best faults at its last
    sample and of "none", all with the reference's calibration states ``kept`` as uncertain
    constants (candidate onsets as the naming bank's); None per run when nothing is kept. Three
    hypotheses, not five: the replay's cost."""
    if not kept:
        return [None] * len(rows)
    names = list(bank.names)
    fi = [names.index(h) for h in FAULTS]
    last = np.asarray(bank.n_valid) - 1
    # the two best at the window's end (stable: on a tie the first, as np.argmax would name it)
    order = [np.argsort(-bank.loglik[i, fi, last[i]], kind="stable") for i in range(len(rows))]
    top = [(FAULTS[o[0]], FAULTS[o[1]]) for o in order]
    res = [None] * len(rows)
    for pair in set(top):
        g = np.array([i for i in range(len(rows)) if top[i] == pair], dtype=np.int64)
        rr = g if ref_rows is None else np.asarray(ref_rows)[g]
        cb = run_bank_starts(out, ref, rows[g], k0[g], k1[g], k_alarm[g], ("none",) + pair, ref_rows=rr, kept=kept,
                             design=design)
        for q, i in enumerate(g):
            res[i] = (pair, cb.loglik[q, 1:], cb.loglik[q, 0], None if cb.colour is None else cb.colour[q, 1:])
    return res


def judge_alarms(out: FilterOutput, stats: Statistics, k_alarm: np.ndarray, who: tuple, k_ready, margin: float,
                 horizon_s, rows, k_stop, size: bool, pairs: bool, pair_horizon_s, confirm: float, hidden=None,
                 reference=None, on_stop=None, design: BankDesign = DESIGN, persist_s: float = 0.0) -> dict:
    """The first alarm of each run of ``rows`` (array), at k_alarm (B,) by the test ``who`` (B,)
    of ``stats`` (fdi.alarms.first_alarms), judged up to ``k_stop`` (one per row): run -> Decision. The stages: (1) the bank over every candidate onset up to its
    earliest decision; (2) for runs not yet decided, the bank over the whole window ([k0, alarm +
    ``horizon_s``], None: to the record's end); (3) with ``size``, the named hypothesis alone from
    its onset over the window; (4) with ``pairs`` and a confirmed alarm, every single and pair
    restarted after the window up to ``pair_horizon_s`` after the alarm. ``k_ready``: a sample, or
    one per run (B,), before which no onset is estimated. ``reference``: (runs, their reference
    filter output) already run far enough, or None to run it here. ``persist_s``: how long the
    confirming lead must have grown (:func:`growing`)."""
    dt = sample_step(out.t)
    T = out.mean.shape[1]
    persist = int(round(persist_s / dt))
    keep = k_alarm[rows] >= 0
    rows, k_stop = rows[keep], k_stop[keep]
    if not len(rows):
        return {}
    ready = np.broadcast_to(np.asarray(k_ready, dtype=np.int64), k_alarm.shape)
    ka = k_alarm[rows]
    k0 = np.array([onset_index(stats[who[b]][b], int(k_alarm[b]), int(ready[b]), dt, design) for b in rows],
                  dtype=np.int64)
    k1 = np.full(len(rows), T, dtype=np.int64)
    if horizon_s is not None:
        k1 = np.minimum(T, ka + int(round(horizon_s / dt)) + 1)
    k1 = np.minimum(k1, k_stop)
    k1 = np.maximum(k1, k0 + 1)
    ref = run_reference(out, rows, k0 + 1, design) if reference is None else reference_rows(*reference, rows)
    kd = earliest_decision(ka, k0, dt, design)
    k_a1 = np.minimum(kd + 1, k1)  # stage 1: up to and including the first sample it may decide at
    # the confirmation's own bank (calibration uncertain) when alarms are to be confirmed; then the
    # naming bank's "none" only seeds its later starts
    kept = confirm_calibration(ref.config, design) if confirm > -math.inf else ()
    hid = (lambda b: None) if hidden is None else (lambda b: hidden[b])
    stp = (lambda b: None) if on_stop is None else (lambda b: on_stop[b])

    def decisions(bank, sel, k_end, ref_rows=None):
        cb = confirmation_bank(out, ref, bank, rows[sel], k0[sel], k_end, ka[sel], kept, ref_rows, design)
        return [decide(bank, q, int(kd[i]), margin, confirm, hid(rows[i]), cb[q], stp(rows[i]), int(ka[i]), int(k1[i]),
                       design, persist) for q, i in enumerate(sel)]

    everyone = np.arange(len(rows))
    bank = run_bank_starts(out, ref, rows, k0, k_a1, ka, later_none=not kept, design=design)
    decs = decisions(bank, everyone, k_a1)
    seeds = [start_seed(bank, i, d.naming.onset) for i, d in enumerate(decs)]  # of the decided filter
    late = np.array([i for i, d in enumerate(decs) if d.naming.hypothesis is None and k1[i] > k_a1[i]], dtype=np.int64)
    if len(late):  # stage 2: the undecided runs over their whole window
        bank2 = run_bank_starts(out, ref, rows[late], k0[late], k1[late], ka[late], ref_rows=late,
                                later_none=not kept, design=design)
        for q, (i, d) in enumerate(zip(late, decisions(bank2, late, k1[late], late))):
            decs[i] = d
            seeds[i] = start_seed(bank2, q, d.naming.onset)
    if size:  # stage 3: the decided hypothesis alone from its onset estimate over the whole window
        for name in FAULTS:
            sel = np.array([i for i, d in enumerate(decs) if d.naming.hypothesis == name and k1[i] > k_a1[i]],
                           dtype=np.int64)
            if len(sel):
                onset = np.array([decs[i].naming.onset for i in sel], dtype=np.int64)
                params, z0, var = (np.stack(a) for a in zip(*[seeds[i] for i in sel]))
                one = run_hypotheses(out.inp, bank_config(ref.config), rows[sel], onset, k1[sel], params, z0, var,
                                     [(name,)] * len(sel), False, design=design)
                for q, i in enumerate(sel):
                    nv = int(one.n_valid[q])
                    decs[i] = replace(decs[i], naming=replace(decs[i].naming, size=float(one.free[q, 0, nv - 1]
                                                                                         - one.healthy[q, 0]),
                                                              size_sd=float(one.free_sd[q, 0, nv - 1])))
    sel = np.array([i for i, d in enumerate(decs) if d.standing.confirmed], dtype=np.int64)
    kp = np.full(len(sel), T, dtype=np.int64)
    if pair_horizon_s is not None:
        kp = np.minimum(T, ka[sel] + int(round(pair_horizon_s / dt)) + 1)
    kp = np.minimum(kp, k_stop[sel])
    # the pairs restart where the naming bank's window ended: a run with no sample left after it
    # (an alarm in the record's last second) keeps its single decision
    left = bank.k0[sel] + bank.n_valid[sel] < kp if len(sel) else np.zeros(0, dtype=bool)
    sel, kp = sel[left], kp[left]
    if pairs and len(sel):  # stage 4: every single and pair, restarted after the alarm, one call
        pb = run_pairs(out, ref, bank.subset(sel), rows[sel], kp, [best_single(decs[i]) for i in sel], design)
        pair_margin = margin_for(margin_level(margin), len(MULTI))
        for q, i in enumerate(sel):
            decs[i] = replace(decs[i], several=decide_pair(pb, q, pair_margin, decs[i], confirm, design))
    return {int(b): decs[i] for i, b in enumerate(rows)}
