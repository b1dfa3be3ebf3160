"""The restarted change tests computed incrementally (fdi.statistics.restart: the restarting runs
alone, from their restarts on) decide exactly as the full recomputation (fdi.statistics.restarted:
every run over the whole record) did: the same Decision per run, bit for bit, and the same
statistics shown in replay's files and figure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sam import load_plant
from fdi import FilterConfig, Thresholds, run_filter
from fdi.alarms import first_alarms
from fdi.bank import DESIGN, run_reference
from fdi.conditions import held_on_stop, long_stroke_mask, on_end_stop
from fdi.diagnosis import _withdraw, diagnose, first_alarms_of, judge, shown_statistics
from fdi.filter import sample_step
from fdi.isolation import confirm_evidence, judge_alarms, margin_for, max_episodes
from fdi.statistics import baseline_values, restart, restart_basis, restarted, statistics
from fdi.synth import input_signal, lpm, profile, simulate_runs

DT = 1e-3
ONSET_S = 6.0  #: s, the K_extA step of run 1


def judge_reference(out, th, stats, baseline=None, rows=None, k_stop=None, size=True, pairs=None, design=DESIGN):
    """fdi.diagnosis.judge as it was with the full recomputation at each restart: every run's
    statistics over the whole record (:func:`restarted`) and their first alarms over it."""
    dt = sample_step(out.t)
    pairs = th.confirmation.several_faults if pairs is None else pairs
    B, T = out.mean.shape[:2]
    rows = np.arange(B) if rows is None else np.asarray(rows, dtype=np.int64)
    stop = np.full(B, T, dtype=np.int64)
    if k_stop is not None:
        stop[rows] = np.minimum(T, k_stop)
    k_ready = int(round((th.window.warmup_s + (th.window.baseline_s if baseline is None else 0.0)) / dt))
    common = dict(margin=margin_for(th.confirmation.false_isolation_level), horizon_s=design.decision_window_s,
                  size=size, pairs=pairs, pair_horizon_s=design.pair_window_s,
                  confirm=confirm_evidence(th.confirmation.confirm_nats), hidden=held_on_stop(out, th),
                  on_stop=on_end_stop(out), design=design, persist_s=th.confirmation.persist_s)
    decs = judge_alarms(out, stats, *first_alarms(stats, th.test.h), k_ready, rows=rows, k_stop=stop[rows], **common)
    todo = _withdraw(decs, decs)
    reference = None
    for _ in range(max_episodes(T, dt, design) - 1):
        start = np.zeros(B, dtype=np.int64)
        for b in todo:
            start[b] = decs[b].standing.window_end
        todo = [b for b in todo if start[b] < stop[b] - 1]
        if not todo:
            return decs
        if reference is None:
            reference = (np.array(todo), run_reference(out, np.array(todo), stop[todo], design))
        again = restarted(out, th, start, baseline)
        nxt = judge_alarms(out, again, *first_alarms(again, th.test.h), np.maximum(k_ready, start), rows=np.array(todo),
                           k_stop=stop[todo], reference=reference, **common)
        todo = _withdraw(nxt, decs)
    for b in todo:
        decs[b] = dataclasses.replace(decs[b], episodes_capped=True)
    return decs


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


def test_judge_decides_as_the_full_recomputation(alarming):
    """judge with the incremental restarts: the same Decision per run as the full recomputation,
    bit for bit (alarm times, withdrawn alarms and restarts, the named fault, its size), on runs
    with several withdrawn alarms; the leak that steps in at 6 s is isolated after them as before."""
    out, th, stats = alarming
    got, want = judge(out, th, stats), judge_reference(out, th, stats)
    assert list(got) == list(want) == [0, 1, 2]
    for b in want:
        assert_same(got[b], want[b], f"run {b}")
    assert len(want[0].withdrawn) >= 3 and len(want[2].withdrawn) >= 3  # the restarts are exercised
    assert not want[0].standing.confirmed and not want[2].standing.confirmed
    leak = want[1]
    assert leak.withdrawn and leak.standing.confirmed and leak.naming.hypothesis == "K_extA"
    assert out.t[leak.naming.index] < ONSET_S + 1.0


def test_judge_with_a_cut_and_no_sizing_decides_as_before(alarming):
    """The tune's way (fdi.scoring.bank_decisions without size): some runs only, each judged up to
    its own last sample: the same decisions as the full recomputation."""
    out, th, stats = alarming
    rows, k_stop = np.array([0, 1]), np.array([6500, 7200])
    got = judge(out, th, stats, rows=rows, k_stop=k_stop, size=False, pairs=False)
    want = judge_reference(out, th, stats, rows=rows, k_stop=k_stop, size=False, pairs=False)
    assert list(got) == list(want)
    for b in want:
        assert_same(got[b], want[b], f"run {b}")
    assert len(want[0].withdrawn) >= 2


def test_shown_statistics_are_those_of_the_full_recomputation(alarming):
    """What replay writes and plots: the first pass, then from each restart on the statistics
    restarted there, as the full recomputation gave them."""
    out, th, stats = alarming
    diag = diagnose(out, th, 0, stats)
    restarts = np.searchsorted(out.t, diag.likelihood["tests_restarted_s"])
    assert len(restarts) >= 3
    want = {h: g[0:1].copy() for h, g in stats.items()}
    for k in restarts:
        start = np.zeros(out.mean.shape[0], dtype=np.int64)
        start[0] = k
        for h, g in restarted(out, th, start).items():
            want[h][0, k:] = g[0, k:]
    got = shown_statistics(out, th, diag)
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

