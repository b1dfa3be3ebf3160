"""How much a fault shows in the data: the likelihood evidence at a KNOWN onset.

The change test has to find the onset and has to decide within 1 s of it. To tell a
miss that no test could avoid from a miss of our test, :func:`onset_evidence` asks what
the data carry: a bank of constant-parameter filters (healthy, and each single fault free
with the bank's prior) started at the TRUE onset from the healthy reference filter, with
the reference's calibration (load mass, B_eff, notch flows) as uncertain CONSTANT states
(:func:`fdi.bank.pair_config`), run for ``window_s``. Its log-likelihood of each fault
hypothesis minus the healthy one's at the window's end is the evidence [nats].

Used by ``samfdi fdi tune --bound``: the healthy runs' largest evidence for any fault sets
the bound's threshold at the stated false-alarm level, and a fault run counts as "detectable"
when its own hypothesis clears it, "isolable" when it also beats every other fault by the
isolation margin. The bound knows what no detector knows (the onset), so it is an upper
reference for our detector, not a detector (docs/fdi-design.md, "The bound").

The calibration is uncertain here, not held as in the isolation bank: held at the reference's
values, its small errors show as hundreds of nats for some fault in healthy runs.
"""

from __future__ import annotations

import numpy as np

from .bank import run_bank_calibrated, run_reference
from .faults import BANK
from .filter import FilterOutput

#: The bank's hypotheses, "none" first: the evidence columns.
HYPOTHESES = tuple(BANK)


def onset_evidence(out: FilterOutput, k_onset: np.ndarray, window_s: float = 1.0) -> np.ndarray:
    """(B, len(HYPOTHESES)) log-likelihood of each hypothesis minus the healthy one's [nats]
    over [k_onset[b], k_onset[b] + window_s) of run b of the detection output ``out`` (its
    input only is used; column 0 is 0). One batched reference filter and one bank call."""
    k0 = np.asarray(k_onset, dtype=np.int64)
    B = len(k0)
    rows = np.arange(B)
    T = out.inp.u.shape[1]
    k1 = np.minimum(k0 + int(round(window_s / out.inp.dt)), T)
    ref = run_reference(out, rows, k0 + 1)  # the seed is its posterior at k0: no further
    bank = run_bank_calibrated(out, ref, rows, k0, k1, HYPOTHESES)
    ll = bank.loglik[rows, :, k1 - k0 - 1]  # the window's last valid sample
    return ll - ll[:, :1]


def threshold(healthy: np.ndarray, level: float) -> float:
    """The evidence [nats] that the healthy runs' best fault hypothesis exceeds in a fraction
    ``level`` of them (the (1 - level) empirical quantile over runs of ``healthy`` (B, H)), and
    at least ln(1 / level), a Bayes factor of 1 / level: a few healthy runs can put the quantile
    below 0, where any fault would count as detectable."""
    return float(max(np.quantile(healthy[:, 1:].max(axis=1), 1.0 - level), np.log(1.0 / level)))


def enough_healthy_runs(level: float) -> int:
    """Healthy runs needed before the (1 - level) quantile rests on a few runs beyond it (3)."""
    return int(np.ceil(3.0 / level))


def verdicts(evidence: np.ndarray, hypothesis: str, thr: float, margin: float) -> tuple:
    """(detectable, isolable) (B,) bool of fault runs whose true ``hypothesis`` (a name of
    HYPOTHESES) has evidence above ``thr``, and also beats every other fault by ``margin``."""
    i = HYPOTHESES.index(hypothesis)
    others = [j for j in range(1, len(HYPOTHESES)) if j != i]
    detectable = evidence[:, i] > thr
    return detectable, detectable & (evidence[:, i] - evidence[:, others].max(axis=1) > margin)
