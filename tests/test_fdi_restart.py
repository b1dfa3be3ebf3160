"""The restarted change tests computed incrementally (fdi.statistics.restart: the restarting runs
alone, from their restarts on) decide exactly as the full recomputation (fdi.statistics.restarted:
every run over the whole record) did: the same Decision per run, bit for bit, and the same
statistics shown in replay's files and figure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import fdi.diagnosis
from sam import load_plant
from fdi import FilterConfig, Thresholds, run_filter
from fdi.alarms import first_alarms
from fdi.conditions import long_stroke_mask
from fdi.diagnosis import diagnose, first_alarms_of, judge, shown_statistics
from fdi.statistics import baseline_values, restart, restart_basis, restarted, statistics
from fdi.synth import input_signal, lpm, profile, simulate_runs

DT = 1e-3
ONSET_S = 6.0  #: s, the K_extA step of run 1


def full_recomputation(monkeypatch):
    """Make fdi.diagnosis restart the tests as it did before the incremental path: every run's
    statistics over the whole record at each restart (:func:`restarted`, runs not restarting
    from 0) and their first alarms over it (:func:`fdi.alarms.first_alarms`). Returns the list
    of the restarts it made (how many runs each)."""

    used = []

    def restart_full(basis, rows, start):
        out, th, baseline = basis
        used.append(len(rows))
        full = np.zeros(out.mean.shape[0], dtype=np.int64)
        full[rows] = start
        return restarted(out, th, full, baseline)

    monkeypatch.setattr(fdi.diagnosis, "restart_basis", lambda out, th, baseline=None: (out, th, baseline))
    monkeypatch.setattr(fdi.diagnosis, "restart", restart_full)
    monkeypatch.setattr(fdi.diagnosis, "first_alarms_of", lambda stats, h, rows: first_alarms(stats, h))
    return used


def judge_both(monkeypatch, *args, **kw) -> tuple[dict, dict]:
    """fdi.diagnosis.judge's decisions (incremental restarts) and the full recomputation's."""
    got = judge(*args, **kw)
    with monkeypatch.context() as m:
        used = full_recomputation(m)
        want = judge(*args, **kw)
    assert used  # the tests restarted, the old way
    return got, want


def assert_same(a, b, where="decision"):
    """a and b equal bit for bit: dataclasses field by field, mappings and sequences item by item,
    arrays and floats exactly (NaN equal to NaN)."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, np.generic, float)):
        np.testing.assert_array_equal(a, b, err_msg=where, strict=True)
    else:
        assert a == b, where


@pytest.fixture(scope="module")
def alarming():
    """Change tests made far too sensitive (no drift, h / 20: they alarm about every second on a
    healthy run and the bank withdraws each alarm) on three 8 s sine runs of the default plant:
    healthy, a 1 L/min K_extA leak stepping in at 6 s, healthy with other noise."""
    shipped = Thresholds.shipped()
    th = shipped.with_(drift=0.0, long_stroke_s=None, h={k: v / 20 for k, v in shipped.test.h.items()},
                       several_faults=False)
    t = np.arange(int(8.0 / DT) + 1) * DT
    u = input_signal("sine", t, amplitude=3.0, frequency=0.25)
    leak = np.stack([np.zeros(len(t)), profile("step", lpm(1.0), t, t0=ONSET_S), np.zeros(len(t))])
    runs = simulate_runs(np.tile(load_plant().vector(), (3, 1)), u, DT, faults={"K_extA": leak}, seed=5)
    out = run_filter(runs.inp, FilterConfig())
    return out, th, statistics(out, th)


def test_restart_equals_the_full_recomputation_on_its_runs(alarming):
    """restart: for the restarting runs (different samples, one of them twice) every statistic
    equals restarted's bit for bit over the whole record (0 before the restart), the other runs 0."""
    out, th, _ = alarming
    basis = restart_basis(out, th)
    for rows, start in (([0, 2], [2100, 3750]), ([1], [5000]), ([0, 1, 2], [4000, 1, 7900])):
        full = np.zeros(out.mean.shape[0], dtype=np.int64)
        full[rows] = start
        want, got = restarted(out, th, full), restart(basis, rows, start)
        assert list(got) == list(want)
        np.testing.assert_array_equal(got.start[rows], want.start[rows])
        others = [b for b in range(out.mean.shape[0]) if b not in rows]
        for h in want:
            np.testing.assert_array_equal(got[h][rows], want[h][rows], err_msg=h, strict=True)
            assert not got[h][others].any()
        k, who = first_alarms_of(got, th.test.h, rows)
        k_ref, who_ref = first_alarms(want, th.test.h)
        np.testing.assert_array_equal(k[rows], k_ref[rows])
        assert [who[b] for b in rows] == [who_ref[b] for b in rows]


def test_judge_decides_as_the_full_recomputation(alarming, monkeypatch):
    """judge with the incremental restarts: the same Decision per run as the full recomputation,
    bit for bit (alarm times, withdrawn alarms and restarts, the named fault, its size), on runs
    with several withdrawn alarms; the leak that steps in at 6 s is isolated after them as before."""
    out, th, stats = alarming
    got, want = judge_both(monkeypatch, out, th, stats)
    assert list(got) == list(want) == [0, 1, 2]
    for b in want:
        assert_same(got[b], want[b], f"run {b}")
    assert len(want[0].withdrawn) >= 3 and len(want[2].withdrawn) >= 3  # the restarts are exercised
    assert not want[0].standing.confirmed and not want[2].standing.confirmed
    leak = want[1]
    assert leak.withdrawn and leak.standing.confirmed and leak.naming.hypothesis == "K_extA"
    assert out.t[leak.naming.index] < ONSET_S + 1.0


def test_judge_with_a_cut_and_no_sizing_decides_as_before(alarming, monkeypatch):
    """The tune's way (fdi.scoring.bank_decisions without size): some runs only, each judged up to
    its own last sample: the same decisions as the full recomputation."""
    out, th, stats = alarming
    rows, k_stop = np.array([0, 1]), np.array([6500, 7200])
    got, want = judge_both(monkeypatch, out, th, stats, rows=rows, k_stop=k_stop, size=False, pairs=False)
    assert list(got) == list(want)
    for b in want:
        assert_same(got[b], want[b], f"run {b}")
    assert len(want[0].withdrawn) >= 2


def test_shown_statistics_are_those_of_the_full_recomputation(alarming, monkeypatch):
    """What replay writes and plots: the first pass, then from each restart on the statistics
    restarted there, as the full recomputation gave them."""
    out, th, stats = alarming
    diag = diagnose(out, th, 0, stats)
    restarts = np.searchsorted(out.t, diag.likelihood["tests_restarted_s"])
    assert len(restarts) >= 3
    got = shown_statistics(out, th, diag)
    with monkeypatch.context() as m:
        used = full_recomputation(m)
        want = shown_statistics(out, th, diag)
    assert len(used) == len(restarts)
    assert list(got) == list(want)
    for h in want:
        np.testing.assert_array_equal(got[h], want[h], err_msg=h, strict=True)


def test_restart_with_long_strokes_and_a_given_baseline():
    """The shipped thresholds on a slow sine (long strokes: the wandering parameters' drift differs
    there) and the same with a given baseline: restart equals restarted on the restarting runs."""
    th = Thresholds.shipped()
    t = np.arange(int(16.0 / DT) + 1) * DT
    u = input_signal("sine", t, amplitude=3.0, frequency=1.0 / 10.0)
    runs = simulate_runs(np.tile(load_plant().vector(), (2, 1)), u, DT, seed=7)
    out = run_filter(runs.inp, FilterConfig())
    assert long_stroke_mask(out, th).any()
    rows, start = [1, 0], [9000, 12345]
    full = np.zeros(2, dtype=np.int64)
    full[rows] = start
    for baseline in (None, baseline_values(out, th) * 1.01):  # the own one, and one given (moved a little)
        want, got = restarted(out, th, full, baseline), restart(restart_basis(out, th, baseline), rows, start)
        for h in want:
            np.testing.assert_array_equal(got[h], want[h], err_msg=h, strict=True)




def test_a_change_after_the_cut_is_not_judged(alarming):
    """The tune's cut (k_stop) just after a withdrawn alarm's window, with the next alarm's change
    estimated beyond it: that alarm is not judged (the bank's reference ends at the cut: judging it
    read past the reference's end); the run keeps the alarms withdrawn before the cut."""
    out, th, stats = alarming
    first = judge(out, th, stats, rows=np.array([0]), size=False, pairs=False)[0]
    assert first.restarts[3] + 2 < first.withdrawn[4] - 50  # the next alarm's change lies beyond the cut
    d = judge(out, th, stats, rows=np.array([0]), k_stop=np.array([first.restarts[3] + 2]), size=False,
              pairs=False)[0]
    assert not d.standing.confirmed
    assert d.withdrawn == first.withdrawn[:4] and d.restarts == first.restarts[:4]
