"""The evidence at a known onset (fdi.bound) and its place in the tune's metrics."""

import numpy as np
import pytest

from fdi import bound, rates, tune
from fdi.montecarlo import TUNE
from fdi import Thresholds
from fdi.montecarlo import make_batch
from fdi import FilterConfig, run_filter
from sam import load_plant


def _evidence(fault, size, seed, nuisance=True):
    plant, th = load_plant(), Thresholds.shipped()
    onsets = tune.draw_onsets(3, seed)
    runs = make_batch(plant, 3, seed, fault=fault, size=size, onset=onsets, nuisance=nuisance)
    out = run_filter(runs.inp, FilterConfig())
    return bound.onset_evidence(out, runs.truth["k_onset"])


def test_injected_leak_carries_evidence_for_itself_only():
    """A 1 L/min external leak of chamber A at a random onset: within 1 s the bank started at
    that onset prefers K_extA to healthy by far (measured medians: 8000 nats at 1 L/min, 680 at
    0.25) and to every other fault by more than the isolation margin."""
    e = _evidence("K_extA", 1.0, 500_123)
    i = bound.HYPOTHESES.index("K_extA")
    assert np.all(e[:, 0] == 0.0)
    assert np.all(e[:, i] > 500.0), e
    others = np.delete(e[:, 1:], i - 1, axis=1)
    assert np.all(e[:, i] - others.max(axis=1) > 100.0), e


def test_healthy_nominal_machine_carries_no_evidence():
    """On the nominal machine (no nuisance) with no fault, no fault hypothesis beats healthy by
    more than a few nats (a free parameter only pays its prior's Occam factor, so the evidence
    is about 0 or negative)."""
    e = _evidence(None, 0.0, 1_234, nuisance=False)
    assert np.all(e[:, 1:] < 5.0), e


def test_threshold_and_verdicts():
    healthy = np.zeros((100, 5))
    healthy[:, 2] = np.arange(100.0)  # the best fault over runs: 0..99 nats
    assert bound.threshold(healthy, 0.01) == pytest.approx(np.quantile(np.arange(100.0), 0.99))
    assert bound.threshold(-healthy, 0.01) == pytest.approx(np.log(100.0))  # never below ln(1 / level)
    ev = np.array([[0, 1, 50, 40, 0], [0, 1, 50, 48, 0], [0, 1, 20, 0, 0.0]])
    det, iso = bound.verdicts(ev, "K_extA", 30.0, 5.0)
    np.testing.assert_array_equal(det, [True, True, False])
    np.testing.assert_array_equal(iso, [True, False, False])


def test_tune_reports_the_bound_next_to_our_detector(tmp_path):
    """analyse on hand-made chunks with evidence: the bound's threshold is the healthy runs'
    (1 - level) quantile of their best fault, and each fault row gets the fractions of runs the
    bound calls detectable / isolable."""
    th = Thresholds.shipped()
    n, H = 4, len(tune.HYP)
    jobs = [("healthy", None, 0.0, n, 1000)] + [(f"{f}_{s:g}", f, s, n, 500_000)
                                                  for f, sizes in TUNE.fault_sizes.items() for s in sizes]
    tag = tune.mode_tag(False, True)
    chunks = {}
    for j in jobs:
        ev = np.zeros((n, len(bound.HYPOTHESES)))
        if j[0] == "healthy":
            ev[:, 1] = [1.0, 2.0, 3.0, 4.0]
        if j[0] == "K_int_0.25":
            ev[:, 1] = [100.0, 100.0, 100.0, 2.0]  # three beat the healthy runs, one does not
            ev[:, 3] = [0.0, 99.0, 0.0, 0.0]  # ... and one of them is not isolable from K_extB
        chunks[tune.chunk_key(j, tag)] = dict(
            first=np.full((n, H), -1), max=np.zeros((n, H, 3)), m_L=np.array([100., 300, 600, 700]),
            k_onset=np.full(n, 1500), evidence=ev, iso_h=np.full(n, -1), iso_k=np.full(n, -1),
            conf_k=np.full(n, -1), n_withdrawn=np.zeros(n, dtype=int))
    m = tune.summarise(tmp_path, tune.gather(chunks, jobs, tag), th)
    # four healthy runs: their 99 % quantile (3.97 nats) is below the floor ln(1 / 0.01) = 4.6 nats
    assert m["bound"]["threshold_nats"] == pytest.approx(np.log(1 / th.derived.false_alarm_level))
    assert "**Rough:**" in (tmp_path / "metrics.md").read_text()
    row = next(r for r in m["rows"] if r["fault"] == "K_int" and r["size"] == 0.25)
    assert (row["bound_detectable"], row["bound_isolable"]) == (0.75, 0.5)
    assert row["bound_isolable_ci"] == pytest.approx(list(rates.interval(2, 4)))  # 2 of 4: 0.07-0.93
    assert "What the data carry" in (tmp_path / "metrics.md").read_text()
