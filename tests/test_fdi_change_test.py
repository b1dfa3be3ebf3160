"""The change test of fdi.statistics: the CUSUM with memory (closed forms), and what the shipped
thresholds promise over long healthy recordings."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fdi import Thresholds
from fdi.statistics import cusum

DT = 1e-3


@given(r=st.floats(1.5, 20.0), drift=st.floats(0.0, 1.0), memory=st.floats(0.05, 2.0))
@settings(max_examples=30, deadline=None)
def test_constant_offset_saturates_at_offset_times_memory(r, drift, memory):
    """A constant residual r > drift brings g to the geometric sum (r - drift) dt (1 - a^k) / (1 - a),
    a = exp(-dt / memory): (r - drift) memory to O(dt) once k dt >> memory. Without memory g grows
    as (r - drift) k dt without bound: why a healthy run's lasting offset no longer adds up."""
    T = 5000
    g = cusum(np.full((1, T), r), drift, DT, 0, None, memory)[0]
    a = math.exp(-DT / memory)
    k = np.arange(1, T + 1)
    assert np.allclose(g, (r - drift) * DT * (1 - a**k) / (1 - a), rtol=1e-9)
    if T * DT > 10 * memory:
        assert g[-1] == pytest.approx((r - drift) * memory, rel=DT / memory + 1e-4)
    classic = cusum(np.full((1, T), r), drift, DT, 0, None, None)[0]
    assert np.allclose(classic, (r - drift) * DT * k)


def test_held_samples_neither_add_nor_forget():
    """Where the residual does not vote the statistic is held: no increment, no decay."""
    r = np.full((1, 3000), 3.0)
    active = np.ones((1, 3000), dtype=bool)
    active[0, 1000:2000] = False
    g = cusum(r, 1.0, DT, 0, active, 0.5)[0]
    assert np.all(g[1000:2000] == g[999])
    assert g[2000] > g[999]


def test_below_drift_resets_like_the_classic_cusum():
    """r below the drift drives g to 0 with or without memory (max(0, .))."""
    r = np.concatenate([np.full(500, 4.0), np.full(2000, -1.0)])[None, :]
    for memory in (None, 0.5):
        g = cusum(r, 1.0, DT, 0, None, memory)[0]
        assert g[499] > 0 and g[-1] == 0.0


def test_cusum_with_a_drift_per_sample():
    """A (B, T) drift is applied sample by sample: a constant 3 sigma residual saturates at
    (3 - 1) memory where the drift is 1 and decays towards 0 where it is 4 (a long stroke),
    and a 6 sigma residual still climbs to (6 - 4) memory there."""
    T, memory = 6000, 0.5
    drift = np.where(np.arange(T) < 3000, 1.0, 4.0)[None, :]
    g3 = cusum(np.full((1, T), 3.0), drift, DT, 0, None, memory)[0]
    g6 = cusum(np.full((1, T), 6.0), drift, DT, 0, None, memory)[0]
    assert g3[2999] == pytest.approx(2.0 * memory, rel=1e-2) and g3[-1] == 0.0
    assert g6[-1] == pytest.approx(2.0 * memory, rel=1e-2)
    # a NaN residual (a gap) counts as 0: decays, never jumps
    r = np.full((1, T), 3.0)
    r[0, 1000:1100] = np.nan
    g = cusum(r, drift, DT, 0, None, memory)[0]
    assert np.all(np.diff(g[1000:1100]) <= 0)


def test_long_strokes_mask_in_closed_form():
    """With S = 2 s the rule covers 2 s into each stroke to its end and the first 2 s of the
    rest after it, never the next stroke: +3 V 0-5 s, rest 5-10 s, -3 V 10-15 s, then +3 V
    15-20 s straight away (a reversal) is covered at (2, 7), (12, 15) and (17, 20), so the
    first 2 s of every stroke, also after a reversal, keep the normal drift."""
    from fdi.strokes import long_strokes

    dt = 0.01
    t = np.arange(2000) * dt
    u = np.select([t < 5, t < 10, t < 15], [3.0, 0.0, -3.0], 3.0)[None, :]
    S = 2.005  # between samples: no boundary rests on rounding
    m = long_strokes(u, dt, 0.3, S)[0]
    # the rest is covered until S after the stroke's last sample (4.99 s)
    want = ((t > S) & (t < 5)) | ((t >= 5) & (t < 5 - dt + S)) | ((t > 10 + S) & (t < 15)) | (t > 15 + S)
    assert np.array_equal(m, want)
    # a short cycle (2 s strokes, as in the studies and the tune) is never covered
    short = np.where(np.mod(t, 4.0) < 2.0, 3.0, -3.0)[None, :]
    assert not long_strokes(short, dt, 0.3, 2.0).any()


def test_thresholds_file_memory_is_validated(tmp_path):
    for bad in ("0", "-1.0", "\"fast\"", "inf", "nan", "true"):
        f = tmp_path / "th.toml"
        f.write_text(f"[thresholds]\nmemory_s = {bad}\n")
        with pytest.raises(ValueError, match="memory_s"):
            Thresholds.load(f)
    f.write_text("[thresholds]\nmemory_s = 0.5\n")
    assert Thresholds.load(f).test.memory_s == 0.5
    f.write_text("[thresholds]\n")
    assert Thresholds.load(f).test.memory_s is None
    for bad in ("2.0", "1e9", "\"20\"", "true", "nan"):
        f.write_text(f"[thresholds]\nrun_length_s = {bad}\n")
        with pytest.raises(ValueError, match="run_length_s"):
            Thresholds.load(f)
    for bad, key in (("1.0", "filter_sd_weight"), ('{"K_ext" = 0.0}', "K_ext"), ('{"K_int" = -1.0}', "K_int"),
                     ('{"offset" = "1"}', "offset")):
        f.write_text(f"[thresholds]\nfilter_sd_weight = {bad}\n")
        with pytest.raises(ValueError, match=key):
            Thresholds.load(f)
    f.write_text("[thresholds]\nfalse_alarm_level = 0.01\ntrigger_level = 0.005\n")
    with pytest.raises(ValueError, match="below 'false_alarm_level'"):
        Thresholds.load(f)
    for key, bad in (("trigger_level", "0"), ("trigger_level", "1.5"), ("trigger_level", "true"),
                     ("long_stroke_s", "-1"), ("long_stroke_s", "true"), ("long_stroke_drift", "-0.5"),
                     ("long_stroke_drift", "\"4\""), ("drift", "nan"), ("confirm_nats", "-1"),
                     ("confirm_nats", "\"20\""), ("confirm_nats", "nan"), ("confirm_nats", "true")):
        f.write_text(f"[thresholds]\n{key} = {bad}\n")
        with pytest.raises(ValueError, match=key):
            Thresholds.load(f)


def test_thresholds_file_tables_are_validated(tmp_path):
    """The per-hypothesis tables of a thresholds file: a typo in a key, a value that is not a
    positive finite number, a list of the wrong length or a missing hypothesis is named, with
    its table and key, instead of failing later inside the detector (or, for nan, silently)."""
    from fdi.thresholds import SHIPPED_THRESHOLDS

    text = SHIPPED_THRESHOLDS.read_text()
    h_int = next(line for line in text.splitlines() if line.startswith('"K_int" = 0'))
    sigma_int = next(line for line in text.splitlines() if line.startswith('"K_int" = ['))
    h_minus = next(line for line in text.splitlines() if line.startswith('"offset-" ='))
    cases = (
        (h_int, h_int.replace('"K_int"', '"K_itn"'), r"'h': unknown key 'K_itn' \(did you mean 'K_int'\?\)"),
        (h_int, '"K_int" = "abc"', r"'h.K_int' = 'abc' is not a CUSUM threshold"),
        (h_int, '"K_int" = nan', r"'h.K_int' = nan is not"),
        (h_int, '"K_int" = -0.5', r"'h.K_int' = -0.5 is not"),
        (h_minus, "", r"'h' has no value for 'offset-'"),
        (sigma_int, '"K_int" = [1.0, 2.0]', r"'sigma.K_int' = \[1.0, 2.0\] is not a list of 5"),
        ("band_V = 0.3", "band_V = -inf", r"'band_V' = -inf is not a finite number"),
        ("band_V = 0.3", 'band_V = 0.3\nisolation = "signature"', r"'isolation' = 'signature': that option was retired"),
    )
    f = tmp_path / "th.toml"
    for old, new, message in cases:
        assert old in text
        f.write_text(text.replace(old, new, 1))
        with pytest.raises(ValueError, match=message):
            Thresholds.load(f)
    for shipped in SHIPPED_THRESHOLDS.parent.glob("thresholds*.toml"):
        Thresholds.load(shipped)


def test_the_cusum_memory_is_reported():
    """describe() and the diagnosis name the CUSUM the thresholds were derived for."""
    from sam import load_plant
    from fdi import diagnose
    from fdi.synth import input_signal, simulate_runs
    from fdi.thresholds import describe
    from fdi import run_filter
    assert "memory 0.5 s" in describe(Thresholds.shipped())
    assert "memory none" in describe(Thresholds())
    t = np.arange(2501) * DT
    runs = simulate_runs(load_plant().vector()[None], input_signal("sine", t), DT, seed=3)
    out = run_filter(runs.inp)
    assert diagnose(out, Thresholds.shipped(), 0).thresholds["cusum_memory_s"] == 0.5
    assert diagnose(out, Thresholds(), 0).thresholds["cusum_memory_s"] is None
    shipped = diagnose(out, Thresholds.shipped(), 0).thresholds
    assert shipped["trigger_level"] == 0.1 and shipped["false_alarm_level"] == 0.01
    assert shipped["filter_sd_weight"] == {"K_int": 1.0, "K_extA": 0.0, "K_extB": 0.0, "offset": 1.0}


def test_change_residual_spread_follows_the_weights():
    """d_p = (estimate - baseline) / sqrt((w_p sd_filter)^2 + sigma_p[regime]^2): with the
    shipped weights the external leaks' change is counted in their healthy spread alone (w = 0),
    K_int's and the offset's with the filter's std too (w = 1); a file without weights counts
    both for all."""
    from sam import load_plant
    from fdi.faults import PARAMS
    from fdi.statistics import baseline_values, change_residuals
    from fdi.conditions import held
    from fdi.synth import input_signal, simulate_runs
    from fdi import run_filter
    th = Thresholds.shipped()
    assert th.test.filter_sd_weight == {"K_int": 1.0, "K_extA": 0.0, "K_extB": 0.0, "offset": 1.0}
    assert Thresholds().test.sd_weight("K_extA") == 1.0
    t = np.arange(2501) * DT
    out = run_filter(simulate_runs(load_plant().vector()[None], input_signal("sine", t), DT, seed=3).inp)
    for weights in (th.test.filter_sd_weight, {p: 1.0 for p in PARAMS}, {p: 0.5 for p in PARAMS}):
        th_w = th.with_(filter_sd_weight=weights)
        d, reg, _ = change_residuals(out, th_w)
        base = baseline_values(out, th_w, held(out, th_w))
        k = np.flatnonzero(d["K_extA"][0] != 0.0)[::97]  # armed samples
        assert len(k) > 10
        for i, (p, j) in enumerate(PARAMS.items()):
            sigma = np.asarray(th.test.sigma[p])[reg[0, k]]
            spread = np.sqrt((weights[p] * out.std[0, k, j]) ** 2 + sigma**2)
            np.testing.assert_allclose(d[p][0, k], (out.mean[0, k, j] - base[0, i]) / spread, rtol=1e-12)


def test_restart_relearns_only_the_wandering_baselines():
    """After a withdrawn alarm the tests restart (fdi.statistics.restarted) with the baselines of
    K_int and the offset re-learnt as the run's mean estimates over the rebase_s before the restart,
    and those of the external leaks kept: each restarted statistic equals the test run from that
    sample with exactly those baselines; a run not restarted keeps all of its own."""
    from sam import load_plant
    from fdi.faults import PARAMS
    from fdi.statistics import REBASE_PARAMS, baseline_values, restarted, statistics
    from fdi.conditions import WANDERING
    from fdi.synth import input_signal, simulate_runs
    from fdi import run_filter
    th = Thresholds.shipped()
    assert REBASE_PARAMS == WANDERING == ("K_int", "offset")
    t = np.arange(6001) * DT
    params = np.tile(load_plant().vector(), (2, 1))
    out = run_filter(simulate_runs(params, input_signal("sine", t), DT, seed=4).inp)
    start = np.array([4000, 0])
    got = restarted(out, th, start)
    base = baseline_values(out, th)
    n = int(round(th.test.rebase_s / DT))
    cols = list(PARAMS.values())
    expected = np.array(base, dtype=float)
    for i, p in enumerate(PARAMS):
        if p in REBASE_PARAMS:
            expected[0, i] = out.mean[0, 4000 - n:4000, cols[i]].mean()
    assert not np.allclose(expected[0], base[0])  # the re-learnt ones moved
    want = statistics(out, th, expected, start)
    for h in got:
        np.testing.assert_array_equal(got[h], want[h])


@given(sd=st.floats(0.0, 1e-8), sigma=st.floats(1e-12, 1e-8), w=st.floats(0.0, 2.0), dw=st.floats(0.0, 1.0))
@settings(max_examples=200, deadline=None)
def test_change_spread_is_the_root_sum_of_squares(sd, sigma, w, dw):
    """change_spread over a box of leak-sized spreads (SI): never below the healthy spread nor the
    weighted filter std, at most their sum, sigma itself at w = 0, and growing with w."""
    from fdi.statistics import change_spread
    s = float(change_spread(np.array(sd), np.array(sigma), w))
    assert s >= sigma and s >= w * sd * (1 - 1e-12) and s <= (sigma + w * sd) * (1 + 1e-12)
    assert float(change_spread(np.array(sd), np.array(sigma), 0.0)) == sigma
    assert float(change_spread(np.array(sd), np.array(sigma), w + dw)) >= s


def test_tune_runs_last_what_the_level_is_stated_for():
    """Healthy tune runs last the thresholds' run_length_s; fault runs the tune's 4 s."""
    from fdi.montecarlo import TUNE
    from fdi.tune import run_seconds
    th = Thresholds.shipped()
    assert run_seconds(th, None) == th.derived.run_length_s == 20.0
    assert run_seconds(th.with_(run_length_s=4.0), None) == 4.0
    assert run_seconds(th, "K_int") == TUNE.fault_run_s == 4.0


def test_random_input_draws_in_a_fixed_order():
    """The studies and the Monte Carlo share fdi.synth.random_input; it draws amplitude, frequency,
    PRBS seed and cycle period in that order, so that the shipped thresholds (seeded draws) are
    reproducible: the same signal and the same generator state as the explicit draws, with the
    ranges written out (amplitude 2-4 V, 0.25-0.6 Hz, cycle period 2-4 s)."""
    from fdi.synth import input_signal, random_input
    t = np.arange(3000) * DT
    for kind in ("sine", "cycle", "prbs"):
        a, b = np.random.default_rng(7), np.random.default_rng(7)
        got = random_input(kind, t, a)
        want = input_signal(kind, t, amplitude=b.uniform(2.0, 4.0), frequency=b.uniform(0.25, 0.6),
                            seed=int(b.integers(1 << 31)), period=b.uniform(2.0, 4.0))
        assert np.array_equal(got, want) and a.uniform() == b.uniform()


@pytest.mark.slow
def test_long_healthy_runs_stay_healthy():
    """The false-alarm level is stated per 20 s healthy run (Thresholds.run_length_s): of 30
    held-out healthy 20 s runs (unknown load 0-800 kg, nuisance parameters, encoder angle, seed
    apart from the thresholds' studies and the tune's) at most one has an alarm that stands (the
    bank confirms it, as replay and the tune judge it), and the CUSUM triggers no more runs than
    the trigger level the h were set for allows (10 % of runs; at most 7 of 30, which a rate of
    10 % exceeds with probability 0.8 %) with the filter the h were derived with, whose model's
    stops are rigid like the runs'. Thresholds for 4 s runs without the CUSUM's memory
    false-alarm on such runs (docs/fdi-design.md, "The change test"). The shipped filter's
    elastic stop errs on these rigid stops (17 of the 30 runs touch one): its CUSUM triggers in 9
    of them (the rigid model: 1), and the bank confirms none (docs/fdi.md, "An elastic end stop")."""
    from scipy.stats import binom

    from sam import load_plant
    from fdi.config import StopRules
    from fdi.statistics import statistics
    from fdi.montecarlo import make_batch
    from fdi.tune import bank_decisions
    from fdi import FilterConfig, run_filter

    th = Thresholds.shipped()
    assert th.derived.run_length_s == 20.0 and th.test.memory_s is not None
    runs = make_batch(load_plant(), 30, 424242, duration=th.derived.run_length_s)
    rigid = FilterConfig(stops=StopRules.rigid())
    for cfg, most in ((rigid, binom.isf(0.01, 30, th.derived.trigger_level)), (FilterConfig(), 9)):
        out = run_filter(runs.inp, cfg)
        st = statistics(out, th)
        triggered = np.any([(g > th.test.h[h]).any(axis=1) for h, g in st.items()], axis=0)
        assert triggered.sum() <= most
        stood = bank_decisions(out, st, th, runs.truth["k_onset"], False)["conf_k"] >= 0
        assert stood.sum() <= 1


def _healthy_scenarios():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "scenarios" / "faults"
    return sorted(root.glob("healthy_*.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("scenario", _healthy_scenarios(), ids=lambda f: f.stem)
def test_shipped_healthy_scenarios_are_healthy_from_the_encoder_alone(scenario):
    """The real SAM has only the encoder. Each shipped healthy scenario (4-60 s, 0-800 kg, step,
    sine, PRBS, cycles, a load change), replayed from theta alone (x dropped), is "healthy"
    (the 10 s PRBS and the 40 s cycle are the ones that need the 20 s thresholds, the encoder
    floor and the long-stroke rule)."""
    from sam import Recording, load_plant
    from sam.scenario import load_scenario, run_scenario
    from fdi import replay

    rec = run_scenario(load_scenario(scenario))
    sig = {k: v for k, v in rec.signals.items() if k != "x"}
    d = replay(Recording(rec.t, sig, {}, rec.metadata, "s"), load_plant()).diagnosis
    assert d.status == "healthy", d.alarms


def test_restarted_tests_relearn_the_baseline():
    """restarted: a healthy 5 s run (nominal plant, sine) whose K_int estimate is
    lifted by 1 L/min from 2.5 s on (as if it had wandered there). Restarted at 3.5 s with the old
    baseline the K_int test alarms again at once (within 0.2 s); restarted with the baseline
    re-learnt over the 0.5 s before 3.5 s it stays far below h for the rest of the run; either
    way g is 0 before the run's start."""
    from sam import load_plant
    from fdi.statistics import restarted, statistics
    from fdi.synth import input_signal, simulate_runs
    from fdi import K_PER_LPM, FilterConfig, run_filter
    from fdi.states import I_KINT

    th = Thresholds.shipped()
    t = np.arange(5001) * DT
    p = load_plant().vector()
    out = run_filter(simulate_runs(np.tile(p, (2, 1)), input_signal("sine", t, amplitude=3.0, frequency=0.5), DT,
                                   seed=8).inp, FilterConfig())
    out.mean[:, t >= 2.5, I_KINT] += 1.0 * K_PER_LPM
    start = np.array([3500, 0])
    plain = statistics(out, th, None, start)["K_int"]
    relearnt = restarted(out, th, start)["K_int"]
    assert (plain[0, 3500:3700] > th.test.h["K_int"]).any()
    assert relearnt[0, 3500:].max() < 0.1 * th.test.h["K_int"]
    assert not relearnt[0, :3500].any() and not plain[0, :3500].any()


@pytest.mark.parametrize("seed", [22, 31, 32])
def test_reversal_after_a_long_steady_stroke_stays_healthy(tmp_path, seed):
    """A healthy 2 V cycle of 30 s period at 650 kg from x = 50 mm (a 15 s extension at 1.6 cm/s
    that does not reach the stop, to x = 0.29 m, then a retraction), replayed from the encoder:
    healthy (at 3 V the default plant's load reaches the stop past the boom's vertical). Left
    free, the filter's calibration states drift along what a steady stroke leaves unseen and
    snap back at the reversal, which the bank reads as K_int; CalibrationStates.hold_after_s
    stops their random walk inside long strokes, in the detecting filter and the bank's reference."""
    from dataclasses import replace

    from sam import load_plant
    from sam.scenario import load_scenario, run_scenario
    from fdi import replay

    plant = Path(__file__).resolve().parents[1] / "scenarios" / "plants" / "sam.toml"
    path = tmp_path / "reversal.toml"
    path.write_text(f'description = "healthy reversal after a 15 s stroke"\nplant = "{plant.as_posix()}"\n'
                    f'duration_s = 20.0\ndt_s = 0.001\nseed = {seed}\n'
                    '[input]\nkind = "cycle"\namplitude_V = 2.0\nperiod_s = 30.0\n'
                    '[load]\nm_L_kg = 650.0\n[initial]\nx_m = 0.05\n'
                    '[sensors]\npressure_noise_Pa = 20e3\nencoder_quantisation = true\n')
    rec = run_scenario(load_scenario(path)).measured()
    d = replay(replace(rec, signals={k: v for k, v in rec.signals.items() if k != "x"}), load_plant()).diagnosis
    assert d.status == "healthy", (d.status, d.isolated, d.detection_time_s)


def test_long_cycle_population_reverses_in_mid_stroke_and_on_the_stops():
    """The tune's healthy long-cycle runs (fdi.montecarlo.LONG_CYCLES) are what they are for:
    every run starts at rest at its own position inside LONG_CYCLES' range, its input stays
    within the amplitude range, and the population holds both kinds of long stroke, those
    that reverse in mid-stroke after moving one way for over 5 s and those that end on an end
    stop (the tune's other inputs almost never give the first: docs/fdi.md, "Known limitations")."""
    from sam import load_plant
    from sam.dynamics import stroke_ends
    from fdi.montecarlo import LONG_CYCLES, make_batch
    from fdi.strokes import directions

    plant = load_plant()
    runs = make_batch(plant, 24, 31415, duration=20.0, inputs="long_cycles")
    x, v, u = runs.truth["x"], runs.truth["v"], runs.inp.u
    lo, hi = LONG_CYCLES["x0_m"]
    assert np.all((x[:, 0] >= lo) & (x[:, 0] <= hi)) and np.all(v[:, 0] == 0.0)
    assert np.abs(u).max() <= LONG_CYCLES["amplitude_V"][1] and len(np.unique(x[:, 0])) == 24
    end = stroke_ends(plant.vector())
    d, since = directions(u, DT, 0.3)
    mid_reversals = stop_ends = 0
    for b in range(len(u)):
        # the sample before each change of input direction after at least 5 s one way
        k = np.flatnonzero((d[b, 1:] != d[b, :-1]) & (d[b, :-1] != 0) & (since[b, :-1] > 5.0))
        on_stop = (x[b, k] < 1e-3) | (x[b, k] > end - 1e-3)
        mid_reversals += int((~on_stop).sum())
        stop_ends += int(on_stop.sum())
    assert mid_reversals >= 3 and stop_ends >= 3, (mid_reversals, stop_ends)


def test_before_motion_covers_the_initial_rest_and_the_warm_up_after_it():
    """The baseline of a recording that starts at rest is learnt from the first motion on
    (fdi.statistics.before_motion): the samples before the input first leaves the hold band and the
    warm-up after it are excluded, so the tests arm warmup_s + baseline_s after the first motion;
    a recording that starts moving is unchanged, one that never moves arms nothing."""
    from types import SimpleNamespace

    from fdi.conditions import before_motion, held
    from fdi.statistics import own_baseline

    th = Thresholds.shipped()
    T = 6000
    t = np.arange(T) * DT
    u = np.zeros((3, T))
    u[0, 2000:] = 1.0  # rest for 2 s, then a stroke
    u[1, :] = 2.0  # moving from the first sample
    rng = np.random.default_rng(5)
    mean = np.zeros((3, T, 18))
    mean[:, :, 0], mean[:, :, 1] = 8e6, 3e6  # p_A, p_B [Pa]: not balanced (fdi.conditions.balanced)
    mean[:, :, 7:11] = 1e-10 + 1e-12 * rng.standard_normal((3, T, 4))
    mean[0, :2500, 7] = 5e-9  # what a rest shows: not the baseline of the moving machine
    out = SimpleNamespace(t=t, u=u, mean=mean, std=np.ones_like(mean), inp=None)
    bm = before_motion(out, th)
    warm = int(round(th.window.warmup_s / DT))
    assert bm[0, : 2000 + warm].all() and not bm[0, 2000 + warm:].any()
    assert bm[1, :warm].all() and not bm[1, warm:].any() and bm[2].all()
    base, ready = own_baseline(out, th, held(out, th))
    first_armed = np.argmax(ready[:, 0], axis=1)
    n_base = int(round(th.window.baseline_s / DT))
    assert first_armed[0] == 2000 + warm + n_base and first_armed[1] == warm + n_base and not ready[2].any()
    assert base[0, 0] == pytest.approx(1e-10, rel=0.01)  # the rest's 5e-9 is not in it
    assert np.all(before_motion(SimpleNamespace(t=t, u=None, mean=mean), th) == False)  # noqa: E712


@pytest.mark.slow
def test_a_recording_that_starts_at_rest_does_not_alarm_at_its_first_motion(monkeypatch):
    """Three healthy 20 s runs of the tune's long-cycle population (fdi.montecarlo.LONG_CYCLES)
    that rest 1.6, 3.0 and 6.3 s before their first stroke, unknown load 378-524 kg, from the
    encoder, judged as replay and the tune judge them (bank confirmation): none false-alarms.
    With the baseline learnt at rest instead of from the first motion, the two K_int ones
    false-alarm within 0.2 s of their first motion (checked below). Drawn on the former default
    plant, where the runs were picked (tests/stall_cases.py); on the default plant the same draws
    do not false-alarm with the baseline learnt at rest either (issue 33: open). Judged with the
    confirmation they were picked with (20 nats, no persistence): the shipped one (50 nats, the
    lead still growing over 0.3 s) withdraws the baseline-at-rest alarms too."""
    from dataclasses import replace

    from sam import load_plant
    import fdi.statistics
    from fdi import FilterConfig, FormNoise, run_filter, tune
    from fdi.montecarlo import make_batch

    from stall_cases import FORMER_PLANT

    th = Thresholds.shipped().with_(confirm_nats=20.0, persist_s=0.0)
    picks = {300001: 21, 300002: 18, 300004: 20}
    parts = [make_batch(load_plant(FORMER_PLANT), 25, seed, duration=th.derived.run_length_s, inputs="long_cycles").inp
             for seed in picks]
    rows = list(picks.values())
    inp = replace(parts[0], **{k: np.stack([getattr(p, k)[b] for p, b in zip(parts, rows)])
                              for k in ("u", "pA", "pB", "pos", "params")})
    k_end = np.full(3, inp.u.shape[1] - 1)

    def stood(out):
        return tune.bank_decisions(out, fdi.statistics.statistics(out, th), th, k_end, False)["conf_k"] >= 0

    assert not stood(run_filter(inp, FilterConfig())).any()
    # the counterfactual on the filter the runs were picked with: the pressures' noise where the
    # model's form errs (FormNoise) withdraws one of the two baseline-at-rest alarms by itself
    exact = run_filter(inp, FilterConfig(form_noise=FormNoise.exact()))
    assert not stood(exact).any()
    monkeypatch.setattr(fdi.statistics, "before_motion", lambda out, th: np.zeros(out.mean.shape[:2], dtype=bool))
    assert stood(exact)[:2].all()


def test_internal_leak_test_is_held_where_the_chamber_pressures_balance():
    """A leak across the piston flows with the root of p_A - p_B, so where the pressures balance
    it carries nothing and K_int's estimate is free (measured: a 4 s retraction at 187 kg with
    p_A = p_B crept it 0.02 -> 0.77 L/min and false-alarmed). K_int's test is held exactly where
    |p_A - p_B| < balance_margin_Pa (fdi.conditions.balanced); the other tests are not. An estimate
    creeping up inside such a stretch alarms with the hold off and not with it."""
    from types import SimpleNamespace

    from fdi.faults import PARAMS
    from fdi.conditions import held
    from fdi.statistics import statistics
    from fdi.synth import lpm
    from fdi import FilterConfig

    th = Thresholds.shipped()
    T = 8000
    t = np.arange(T) * DT
    mean = np.zeros((1, T, 18))
    mean[0, :, 0], mean[0, :, 1] = 8e6, 3e6
    window = slice(3000, 7000)
    mean[0, window, 0] = mean[0, window, 1] = 6.65e6  # balanced
    mean[0, 3000:7000, 7] = np.linspace(0.0, lpm(0.75), 4000)  # K_int creeps inside it
    mean[0, 7000:, 7] = lpm(0.02)
    std = np.zeros_like(mean)
    std[0, :, 7:11] = [lpm(0.05), lpm(0.05), lpm(0.05), 2e-3]
    out = SimpleNamespace(t=t, u=np.full((1, T), -3.0), mean=mean, std=std, inp=None, config=FilterConfig())
    h = held(out, th)
    assert np.array_equal(np.flatnonzero(h[0, list(PARAMS).index("K_int")]), np.arange(3000, 7000))
    assert not h[0, [i for i, p in enumerate(PARAMS) if p != "K_int"]].any()
    assert th.regimes.balance_margin_Pa > 0 and (statistics(out, th)["K_int"] <= th.test.h["K_int"]).all()
    assert (statistics(out, th.with_(balance_margin_Pa=0.0))["K_int"] > th.test.h["K_int"]).any()
