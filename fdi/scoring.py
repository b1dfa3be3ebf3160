"""How a Monte Carlo run or a labelled recording is scored: per run, the change tests' first
alarms and their maxima before the onset, in the scored second and over the run, and the bank's
verdicts (the alarm that stood, the fault it named and when, and optionally its size with the
+-2 sigma band replay reports). ``fdi tune`` (:mod:`fdi.tune`) and ``fdi evaluate``
(:mod:`fdi.evaluate`) both score with these, and :mod:`fdi.metrics` turns the arrays into rates.
"""

from __future__ import annotations

import numpy as np

from .alarms import first_alarms
from .diagnosis import judge, verdict
from .faults import HYPOTHESES, hypothesis_name
from .filter import FilterOutput
from .montecarlo import TUNE
from .statistics import Statistics
from .thresholds import Thresholds

HYP = tuple(HYPOTHESES)
#: keys of the bank's verdicts (:func:`bank_decisions`)
BANK_KEYS = ("iso_h", "iso_k", "conf_k", "n_withdrawn")
#: keys of the reported size (:func:`bank_decisions` with ``size``): value and its +-2 sigma band,
#: in the units diagnosis.json reports (L/min at 10 MPa, % of spool travel); NaN: not isolated
SIZE_KEYS = ("size_value", "size_lo", "size_hi")


def window_maxima(st: Statistics, th: Thresholds, k0: np.ndarray) -> dict:
    """Per run b and hypothesis: the first alarm index (-1: none) and the maxima of g/h over
    [0, k0[b]), [k0[b], k0[b] + 1 s] and the whole run."""
    k0 = np.asarray(k0, dtype=np.int64)
    n = len(k0)
    idx = np.arange(next(iter(st.values())).shape[1])
    pre = idx[None, :] < k0[:, None]
    post = (idx[None, :] >= k0[:, None]) & (idx[None, :] <= k0[:, None] + int(round(TUNE.within_s / TUNE.dt)))
    first = np.full((n, len(HYP)), -1, dtype=np.int64)
    mx = np.zeros((n, len(HYP), 3))
    for i, h in enumerate(HYP):
        if h not in st:  # no statistic: never alarms
            continue
        r = st[h] / th.test.h[h]
        above = r > 1.0
        first[:, i] = np.where(above.any(axis=1), np.argmax(above, axis=1), -1)
        mx[:, i, 0] = np.where(pre, r, -np.inf).max(axis=1)
        mx[:, i, 1] = np.where(post, r, -np.inf).max(axis=1)
        mx[:, i, 2] = r.max(axis=1)
    return {"first": first, "max": mx}


def bank_decisions(out: FilterOutput, st: Statistics, th: Thresholds, k_onset: np.ndarray, faulty: bool,
                   size: bool = False) -> dict:
    """The bank's verdicts, per run: the isolated hypothesis (index in HYP, -1: none or not
    isolable), the sample of the decision (-1: none), the first alarm that stood (-1: none; in a
    fault run a first alarm after the scored second is not judged and counts as it stands) and
    the number of withdrawn alarms; with ``size``, also :data:`SIZE_KEYS`.

    Every alarmed run is judged as replay judges it (:func:`fdi.diagnosis.judge`). Without
    ``size`` fault runs are cut at the scored second's end (a decision is causal, so the cut
    changes no decision that counts, and the bank costs a third); with it they are judged over
    the bank's whole window, so the size is the one replay reports. The several-faults stage is
    not run: its verdict comes after the scored second."""
    n = out.mean.shape[0]
    res = {key: np.full(n, -1, dtype=np.int64) for key in ("iso_h", "iso_k", "conf_k")}
    res["n_withdrawn"] = np.zeros(n, dtype=np.int64)
    if size:
        res.update({key: np.full(n, np.nan) for key in SIZE_KEYS})
    k_end = np.asarray(k_onset, dtype=np.int64) + int(round(TUNE.within_s / TUNE.dt))
    k_alarm = first_alarms(st, th.test.h)[0]
    # a fault run whose first alarm comes after onset + 1 s cannot count within 1 s: not judged
    # (the bank would cost for nothing), its alarm taken as it stands (for the mean delay)
    late = faulty & (k_alarm > k_end)
    res["conf_k"][late] = k_alarm[late]
    rows = np.flatnonzero((k_alarm >= 0) & ~late)
    if not len(rows):
        return res
    k_stop = k_end[rows] + 1 if faulty and not size else None
    decs = judge(out, th, st, rows=rows, k_stop=k_stop, size=size, pairs=False)
    for b, d in decs.items():
        res["n_withdrawn"][b] = len(d.withdrawn)
        if d.standing.confirmed:
            res["conf_k"][b] = d.standing.alarm
        if d.naming.hypothesis is not None:
            name = hypothesis_name(d.naming.hypothesis, d.naming.size)
            res["iso_h"][b] = HYP.index(name)
            res["iso_k"][b] = d.naming.index
            if size and d.standing.confirmed:
                reported = verdict(out, th, d).size.get(name)
                if reported is not None:
                    for key, field in zip(SIZE_KEYS, ("value", "minus_2sigma", "plus_2sigma")):
                        res[key][b] = reported[field]
    return res
