"""Replay end to end: detection, isolation and size of a known leak; healthy runs;
bad input; the CLI never shows a traceback."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sam import Recording, load_plant, write_recording
from samfdi.cli import main
from fdi import Thresholds, diagnose, run_filter
from fdi.montecarlo import TUNE, make_batch
from fdi.statistics import statistics
from fdi.synth import input_signal, lpm, profile, simulate_runs

DT = 1e-3


def _recording(faults=None, T=5001, seed=5, with_truth=True):
    p = load_plant().vector()
    t = np.arange(T) * DT
    u = input_signal("sine", t, amplitude=3.0, frequency=0.25)
    fa = None if faults is None else {k: f(t) for k, f in faults.items()}
    r = simulate_runs(p[None], u, DT, faults=fa, seed=seed)
    sig = {"u": u, "pA": r.inp.pA[0], "pB": r.inp.pB[0], "theta": r.inp.pos[0]}
    truth = {f"true_{k}": v for k, v in (fa or {}).items()} if with_truth else {}
    return Recording(t, sig, truth, {"description": "test"})


@pytest.fixture(scope="module")
def leak_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "leakA.csv"
    write_recording(path, _recording({"K_extA": lambda t: profile("step", lpm(1.0), t, t0=2.0)}))
    return path


def test_known_leak_detected_isolated_and_sized(leak_csv, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["fdi", "replay", str(leak_csv), "--out", str(out)]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["status"] == "fault"
    assert d["isolated"] == ["K_extA"]
    assert 2.0 < d["detection_time_s"] < 3.0  # within 1 s of onset
    assert d["size"]["K_extA"]["value"] == pytest.approx(1.0, abs=0.15)  # stated tolerance: 0.15 L/min
    header = (out / "estimates.csv").read_text().splitlines()[0].split(",")
    for col in ("t", "K_extA", "K_extA_lo2s", "K_extA_hi2s", "K_extA_Lpm", "offset", "F_d"):
        assert col in header
    assert (out / "residuals.csv").exists() and (out / "replay.png").stat().st_size > 1000
    # refuses to overwrite, then --force works
    assert main(["fdi", "replay", str(leak_csv), "--out", str(out)]) == 2
    assert "already holds" in capsys.readouterr().err
    assert main(["fdi", "replay", str(leak_csv), "--out", str(out), "--force"]) == 0



def test_a_leak_found_in_the_last_second_of_a_recording(tmp_path, capsys):
    """An alarm less than the bank's window before the record ends leaves no sample for the
    several-faults stage: the single decision stands (and nothing raises)."""
    path = tmp_path / "late.csv"
    write_recording(path, _recording({"K_extA": lambda t: profile("step", lpm(1.0), t, t0=3.7)}, T=4001))
    out = tmp_path / "out"
    assert main(["fdi", "replay", str(path), "--out", str(out)]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["status"] == "fault" and d["isolated"] == ["K_extA"]
    assert 3.7 < d["detection_time_s"] <= 4.0


def test_a_long_recording_is_tested_to_its_end_whatever_its_withdrawn_alarms(monkeypatch):
    """Each withdrawn alarm costs one bank, so the alarms judged per record are capped, but at
    one per decision window of the record, not at a fixed number: a 60 s, 40 s-period sine of
    2 V (its stroke below the boom's vertical; at 3 V the default plant's runs past it onto the
    stop, and an alarm of the overrun 0.2 s before the onset is confirmed by the leak after it)
    whose steady strokes trigger withdrawn alarms, with a 0.5 L/min K_extA leak from 55 s, and
    the fixed floor lowered to 1 (as if a long record had used up the old cap of 30) still
    finds the leak; with the old fixed cap it was called healthy."""
    from fdi import replay
    from fdi.bank import BankDesign
    from fdi.isolation import max_episodes

    p = load_plant().vector()
    t = np.arange(60001) * DT
    u = input_signal("sine", t, amplitude=2.0, frequency=1 / 40)
    r = simulate_runs(p[None], u, DT, faults={"K_extA": profile("step", lpm(0.5), t, t0=55.0)[None]})
    rec = Recording(t, {"u": u, "pA": r.inp.pA[0], "pB": r.inp.pB[0], "theta": r.inp.pos[0]})
    design = BankDesign(max_episodes=1)
    assert max_episodes(len(t), DT, design) == 61
    d = replay(rec, load_plant(), design=design).diagnosis
    assert len([a for a in d.likelihood["withdrawn_alarms_s"] if a < 55.0]) >= 2  # the premise
    # 1.17 s after the onset with the lead at its honest size (fdi.whiteness; within 1 s before it)
    assert d.status == "fault" and d.isolated == ["K_extA"] and 55.0 < d.detection_time_s < 56.5
    monkeypatch.setattr("fdi.diagnosis.max_episodes", lambda n, dt, design: 1)  # the fixed cap, as before
    assert replay(rec, load_plant()).diagnosis.status == "healthy"

def test_sampling_rate_must_match_the_thresholds(leak_csv, tmp_path, capsys):
    """sigma and h depend on the sampling rate (the 1 kHz thresholds give 12 % false alarms at
    500 Hz), so a 500 Hz recording is refused with the shipped 1 kHz thresholds and the command
    that makes thresholds for it; with thresholds for 500 Hz it is filtered with two 1 ms model
    steps per sample and the 1 L/min leak is found and sized."""

    from sam import read_recording
    import fdi
    from fdi.filter import model_substeps
    r = read_recording(leak_csv)
    half = Recording(r.t[::2], {k: v[::2] for k, v in r.signals.items()}, source="half.csv")
    write_recording(tmp_path / "half.csv", half)
    assert main(["fdi", "replay", str(tmp_path / "half.csv"), "--out", str(tmp_path / "o")]) == 2
    assert "samfdi fdi thresholds --sample-rate 500" in capsys.readouterr().err
    assert [model_substeps(dt) for dt in (1e-3, 1.0005e-3, 2e-3, 2.008e-3, 5e-3, 0.5e-3)] == [1, 1, 2, 2, 5, 1]
    th500 = Thresholds.shipped().with_(sample_dt_s=2e-3)
    d = fdi.replay_recording(half, load_plant(), tmp_path / "h", thresholds=th500, figure=False)
    assert d.isolated == ["K_extA"] and d.size["K_extA"]["value"] == pytest.approx(1.0, abs=0.15)


def test_faster_recording_is_decimated_and_odd_rates_get_a_way_out(leak_csv, tmp_path, capsys):
    """A 2 kHz recording (the 1 kHz one with midpoints interpolated) is decimated to the
    thresholds' 1 kHz and diagnosed as the 1 kHz one is; 497 Hz is refused with the supported
    rate to derive thresholds for (500 Hz), 700 Hz with how to resample; a baseline recording at
    2 kHz is decimated too; --sample-rate 0 / nan are refused without a traceback."""
    from sam import read_recording
    r = read_recording(leak_csv)
    t2 = np.arange(2 * r.n - 1) * r.dt / 2
    fast = Recording(t2, {c: np.interp(t2, r.t, v) for c, v in r.signals.items()}, source="fast.csv")
    write_recording(tmp_path / "fast.csv", fast)
    assert main(["fdi", "replay", str(tmp_path / "fast.csv"), "--out", str(tmp_path / "f"),
                 "--baseline", str(tmp_path / "fast.csv")]) == 0
    assert "kept 1 sample in 2" in capsys.readouterr().out
    for rate, expect in ((497.0, "--sample-rate 500 "), (700.0, "resample it")):
        tr = np.arange(0, 3.0, 1 / rate)
        odd = Recording(tr, {c: np.interp(tr, r.t, v) for c, v in r.signals.items()})
        write_recording(tmp_path / f"odd{rate:g}.csv", odd)
        assert main(["fdi", "replay", str(tmp_path / f"odd{rate:g}.csv"), "--out", str(tmp_path / "o")]) == 2
        assert expect in capsys.readouterr().err
    for bad in ("0", "nan", "-5"):
        assert main(["fdi", "thresholds", "--sample-rate", bad, "--out", str(tmp_path / "th")]) == 2
        assert "--sample-rate" in capsys.readouterr().err


def test_tune_refuses_thresholds_for_another_rate(tmp_path, capsys):
    from fdi.thresholds import to_toml
    path = tmp_path / "th500.toml"
    path.write_text(to_toml(Thresholds.shipped().with_(sample_dt_s=2e-3)))
    assert main(["fdi", "tune", "--runs", "5", "--thresholds", str(path), "--out", str(tmp_path / "t")]) == 2
    assert "1000 Hz only" in capsys.readouterr().err and not (tmp_path / "t").exists()


def test_threshold_studies_sample_like_the_logger():
    """The studies simulate at 1 ms and filter what a logger sampling every 2 ms records."""

    from fdi.study import StudyDesign, study_runs
    design = StudyDesign(sample_dt_s=2e-3)
    nominal = load_plant().vector()
    out = study_runs(np.tile(nominal, (2, 1)), np.array([0.1, 0.5]), np.array([0.2, 0.3]), nominal, design)
    assert out.inp.dt == pytest.approx(2e-3) and out.mean.shape[1] == int(round(design.leak_run_s / 2e-3)) + 1
    with pytest.raises(ValueError, match="whole multiple"):
        StudyDesign(n_leak=4, n_nuisance=4, sample_dt_s=1.5e-3)


def test_replay_never_reads_truth(leak_csv, tmp_path):
    from sam import read_recording
    import fdi
    rec = read_recording(leak_csv)
    d1 = fdi.replay_recording(rec, load_plant(), tmp_path / "a", figure=False)
    lie = Recording(rec.t, rec.signals, {k: np.zeros_like(v) + 1.0 for k, v in rec.truth.items()}, rec.metadata)
    d2 = fdi.replay_recording(lie, load_plant(), tmp_path / "b", figure=False)
    assert d1.alarms == d2.alarms and d1.size == d2.size


def test_healthy_recording_raises_no_alarm(tmp_path):
    rec = _recording(None, seed=9)
    import fdi
    d = fdi.replay_recording(rec, load_plant(), tmp_path / "h", figure=False)
    assert d.status == "healthy", d.alarms


def test_nan_gap_predicted_through_and_reported(tmp_path):
    rec = _recording({"K_extA": lambda t: profile("step", lpm(1.0), t, t0=2.0)})
    for ch in ("pA", "pB", "theta"):
        rec.signals[ch][3000:3100] = np.nan
    import fdi
    d = fdi.replay_recording(rec, load_plant(), tmp_path / "g", figure=False)
    assert d.filter_health["nan_samples"] == 100
    assert d.isolated == ["K_extA"]


def test_bad_input_messages(tmp_path, capsys):
    rec = _recording(None, T=2001)
    rec.signals["pA"][500] = 3.1e7
    path = tmp_path / "range.csv"
    write_recording(path, rec)
    assert main(["fdi", "replay", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "'pA'" in err and "outside the sensor range" in err and "row 501" in err and "Traceback" not in err
    assert main(["fdi", "replay", str(path), "--out", str(tmp_path / "o"), "--drop-out-of-range"]) == 0
    # unobservable plant: a huge dead volume swallows every leak
    plant = tmp_path / "plant.toml"
    plant.write_text("[cylinder]\nV_0A = 1e3\nV_0B = 1e3\n")
    path2 = tmp_path / "ok.csv"
    write_recording(path2, _recording(None, T=2001))
    assert main(["fdi", "replay", str(path2), "--plant", str(plant), "--out", str(tmp_path / "u")]) == 2
    assert "unobservable" in capsys.readouterr().err
    # coarse sampling: 200 Hz needs thresholds for 200 Hz; 50 Hz is refused outright
    rec3 = _recording(None, T=2001)
    for k, expect in ((5, "--sample-rate 200"), (20, "100 Hz or faster")):
        coarse = Recording(rec3.t[::k], {c: v[::k] for c, v in rec3.signals.items()})
        path3 = tmp_path / f"coarse{k}.csv"
        write_recording(path3, coarse)
        assert main(["fdi", "replay", str(path3), "--out", str(tmp_path / "c")]) == 2
        assert expect in capsys.readouterr().err
    # thresholds file: a mistyped key and an unknown method are named, not silently ignored
    shipped = (Path(__file__).resolve().parents[1] / "scenarios" / "faults" / "thresholds.toml").read_text()
    for text, expect in ((shipped.replace("false_isolation_level", "false_isolaton_level"),
                          "did you mean 'false_isolation_level'"),
                         (shipped.replace('position_sensor = "encoder"', 'position_sensor = "magic"'),
                          "'position_sensor' = 'magic'")):
        th = tmp_path / "th.toml"
        th.write_text(text)
        assert main(["fdi", "replay", str(path2), "--thresholds", str(th), "--out", str(tmp_path / "t")]) == 2
        err = capsys.readouterr().err
        assert "th.toml" in err and expect in err and "Traceback" not in err


def test_replay_refuses_what_it_cannot_diagnose(tmp_path, capsys):
    """A recording too short to test, a position outside the plant's stroke (a sensor with the
    wrong sign), and an --out under a file are refused in one line, before any output; the
    thresholds and signatures commands do not replace a user's files without --force."""
    short = tmp_path / "short.csv"
    write_recording(short, _recording(None, T=1001))
    flipped = _recording(None, T=3001)
    flipped.signals["theta"] = -flipped.signals["theta"]
    neg = tmp_path / "neg.csv"
    write_recording(neg, flipped)
    ok = tmp_path / "ok.csv"
    write_recording(ok, _recording(None, T=3001))
    for args, expect in (([str(short)], "only 1 s long; a diagnosis needs at least 2 s"),
                         ([str(neg)], "'theta': 3001 sample(s) outside the plant's stroke"),
                         ([str(ok), "--out", str(ok / "sub")], "ok.csv is a file, not a folder")):
        out = ["--out", str(tmp_path / "o")] if "--out" not in args else []
        assert main(["fdi", "replay", *args, *out]) == 2
        err = capsys.readouterr().err
        assert expect in err and "Traceback" not in err, err
    assert not (tmp_path / "o").exists()  # a refused replay leaves no empty folder behind
    for rate in ("300", "50"):  # not a whole number of 1 ms steps; below 100 Hz
        assert main(["fdi", "thresholds", "--sample-rate", rate, "--out", str(tmp_path / "th")]) == 2
        assert "--sample-rate" in capsys.readouterr().err
    for level in ("0.005", "1.5", "nan"):  # below the false-alarm level 0.01; above 1; not a number
        assert main(["fdi", "thresholds", "--trigger-level", level, "--out", str(tmp_path / "th")]) == 2
        assert "--trigger-level" in capsys.readouterr().err
    assert not (tmp_path / "th").exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    for cmd, name in ((["thresholds"], "thresholds.md"), (["signatures"], "signatures.md")):
        (mine / name).write_text("my notes")
        assert main(["fdi", *cmd, "--out", str(mine)]) == 2
        assert "use --force" in capsys.readouterr().err
        assert (mine / name).read_text() == "my notes"


def test_untested_parameters_are_named_and_position_can_be_dropped(tmp_path, capsys):
    """The first 6 s of the healthy 60 s cycle at 800 kg on the former default plant (tests/stall_cases.py)
    are a stall with the pressures pinned
    at supply and tank: K_extB and the offset are never tested, and "healthy" says so. A
    position glitch is refused, or made a missing sample with --drop-out-of-range; a position
    column left with nothing is refused."""
    import fdi
    from stall_cases import stalled_800kg
    rec, plant = stalled_800kg("healthy_cycle_60s_800kg.toml")
    k = rec.t <= 6.0
    first = Recording(rec.t[k], {c: v[k] for c, v in rec.signals.items()})
    d = fdi.replay_recording(first, plant, tmp_path / "s", figure=False)
    assert d.status == "healthy" and "healthy as far as tested: K_extB, offset" in d.note
    assert d.filter_health["tested_s"]["K_extB"] == 0.0 and d.filter_health["tested_s"]["K_int"] > 4.0
    # a machine that never moves: no baseline (it is learnt from the first motion), nothing tested
    rest = Recording(first.t, {**first.signals, "u": np.zeros_like(first.t)})
    d = fdi.replay_recording(rest, plant, tmp_path / "r", figure=False)
    assert d.status == "healthy" and d.filter_health["first_motion_s"] is None
    assert "K_int, K_extA, K_extB, offset tested for less than" in d.note and "never left its" in d.note
    glitch = _recording(None, T=3001)
    glitch.signals["theta"][1500] = -0.2
    write_recording(tmp_path / "glitch.csv", glitch)
    assert main(["fdi", "replay", str(tmp_path / "glitch.csv"), "--out", str(tmp_path / "g")]) == 2
    assert "'theta': 1 sample(s) outside the plant's stroke" in capsys.readouterr().err
    assert main(["fdi", "replay", str(tmp_path / "glitch.csv"), "--out", str(tmp_path / "g"),
                 "--drop-out-of-range"]) == 0
    assert json.loads((tmp_path / "g" / "diagnosis.json").read_text())["filter_health"]["nan_samples"] == 1
    glitch.signals["theta"][:] = -0.2
    write_recording(tmp_path / "all.csv", glitch)
    assert main(["fdi", "replay", str(tmp_path / "all.csv"), "--out", str(tmp_path / "a"), "--drop-out-of-range"]) == 2
    assert "nothing is left to filter" in capsys.readouterr().err


def test_plant_that_does_not_fit_is_flagged(tmp_path, capsys):
    """A plant file whose valve flows are a thousand times too small makes the filter reset and
    the NIS alarm; the diagnosis says so next to whatever it names (none of the shipped
    scenarios triggers either on the nominal plant)."""
    ok = tmp_path / "ok.csv"
    write_recording(ok, _recording(None, T=4001))
    plant = tmp_path / "small_valve.toml"
    plant.write_text("[valve]\n" + "".join(f"Q_N_{n} = 1e-7\n" for n in ("PA", "AT", "PB", "BT")))
    assert main(["fdi", "replay", str(ok), "--out", str(tmp_path / "nominal")]) == 0
    assert "warning" not in capsys.readouterr().out
    assert main(["fdi", "replay", str(ok), "--plant", str(plant), "--out", str(tmp_path / "o")]) == 0
    assert "the model does not fit this recording" in capsys.readouterr().out
    d = json.loads((tmp_path / "o" / "diagnosis.json").read_text())
    assert "does not describe this machine" in d["note"]
    assert "model_fit_warning" in d["filter_health"]


def test_small_leak_mid_run_detected_and_isolated():
    """Nominal plant (no model error), sine 3 V 0.25 Hz, 494 kg: a 0.25 L/min internal leak
    stepping in at 2 s is detected by the change test and isolated as K_int; the healthy
    twin (same noise) raises nothing. Measured: alarms 2.8-2.9 s after the onset, i.e. NOT
    within the 1 s target (docs/fdi.md); 0.25 L/min external leaks are not detected at all."""
    p = load_plant().vector()
    t = np.arange(5001) * DT
    u = input_signal("sine", t, amplitude=3.0, frequency=0.25)
    th = Thresholds.shipped()
    for fault, expect in (({"K_int": profile("step", lpm(0.25), t, t0=2.0)}, ["K_int"]), (None, [])):
        r = simulate_runs(np.tile(p, (2, 1)), u, DT, faults=fault, seed=5)
        out = run_filter(r.inp)
        st = statistics(out, th)
        for b in range(2):
            d = diagnose(out, th, b, st)
            assert d.isolated == expect, (d.status, d.alarms)
            if expect:
                assert 2.0 < d.detection_time_s < 5.0
                assert d.size["K_int"]["value"] == pytest.approx(0.25, abs=0.12)


def test_thresholds_file_round_trip_and_rule(tmp_path):
    """The shipped thresholds come from the GSA rule; the TOML writer round-trips."""
    from fdi.faults import REGIMES
    from fdi.thresholds import to_toml
    th = Thresholds.shipped()
    assert "GSA" in th.derived.source
    # the five CUSUMs and the notch-flow trigger
    assert set(th.test.h) == {"K_int", "K_extA", "K_extB", "offset+", "offset-", "notch_flow"}
    for p_, s in th.test.sigma.items():
        assert len(s) == len(REGIMES) and all(v > 0 for v in s)
        assert any(th.test.votes[p_])
    path = tmp_path / "t.toml"
    path.write_text(to_toml(th))
    assert Thresholds.load(path) == th


def test_h_is_the_gumbel_quantile_of_healthy_maxima():
    """The threshold rule's quantile: a Gumbel fitted by moments to per-run maxima drawn from a
    known Gumbel (loc 2, scale 0.5) returns that Gumbel's 0.998 quantile, 2 - 0.5 ln(-ln 0.998)."""
    from fdi.study import gumbel_quantile
    x = np.random.default_rng(7).gumbel(2.0, 0.5, 20_000)
    assert gumbel_quantile(x, 0.998) == pytest.approx(2.0 - 0.5 * np.log(-np.log(0.998)), rel=0.02)


def test_threshold_rule_is_the_level_quantile_of_the_healthy_maxima():
    """The larger of the moment-fitted Gumbel quantile and the empirical one: on 352 Gumbel
    maxima both are within 10 % of the true quantile; a spiky sample (1 % of runs at 5, the rest
    at 0), whose Gumbel fit falls below its empirical quantile, gets the empirical one."""
    from scipy import stats
    from fdi.study import gumbel_quantile, level_threshold
    rng = np.random.default_rng(3)
    m = rng.gumbel(50.0, 20.0, 352)
    h = level_threshold(m, 1 - 0.0025)
    assert h == pytest.approx(max(gumbel_quantile(m, 1 - 0.0025), np.quantile(m, 1 - 0.0025)))
    assert h == pytest.approx(stats.gumbel_r(50.0, 20.0).ppf(1 - 0.0025), rel=0.10)
    assert h <= m.max()
    spiky = np.r_[np.zeros(990), np.full(10, 5.0)]  # 1 % of runs at 5: the 0.998 quantile is 5
    assert level_threshold(spiky, 1 - 0.002) == pytest.approx(5.0)
    assert gumbel_quantile(spiky, 0.998) < 5.0


@pytest.mark.slow
def test_held_out_healthy_false_alarms_and_large_leak_detection():
    """Reduced-size statistics on runs NOT used to set the thresholds: 40 healthy runs
    under unknown loads 0-800 kg and model uncertainty (the full-size tune's false-alarm rate:
    docs/fdi.md; target 1 %); this checks that it stays under 10 % here (binomial slack at
    n = 40). 1 L/min external leaks A are found."""
    plant = load_plant()
    th = Thresholds.shipped()
    healthy = run_filter(make_batch(plant, 40, 777).inp)
    st = statistics(healthy, th)
    alarms = sum(diagnose(healthy, th, b, st).status != "healthy" for b in range(40))
    assert alarms <= 4
    faulty = run_filter(make_batch(plant, 10, 321, fault="K_extA", size=1.0).inp)
    st = statistics(faulty, th)
    diags = [diagnose(faulty, th, b, st) for b in range(10)]
    assert sum("K_extA" in d.alarms for d in diags) >= 8


def test_thresholds_files_of_retired_options_are_refused(tmp_path):
    """A thresholds file of an option that was retired (another filter, the GLR detector,
    signature isolation) is refused in one line that says so; the keys those files carried are
    accepted with the one value still supported. The shipped file round-trips through to_toml."""
    from fdi.thresholds import SHIPPED_THRESHOLDS
    from fdi.thresholds import to_toml
    th = Thresholds.shipped()
    path = tmp_path / "t.toml"
    path.write_text(to_toml(th))
    assert Thresholds.load(path) == th
    text = SHIPPED_THRESHOLDS.read_text()
    kept = tmp_path / "kept.toml"
    kept.write_text(text.replace("band_V = 0.3", 'band_V = 0.3\nfilter = "shipped"\nisolation = "likelihood"\n'
                                 'detector = "cusum"\nglr_window_s = 0.5\nconfusable = [["K_int", "offset-"]]'))
    assert Thresholds.load(kept) == Thresholds.load(SHIPPED_THRESHOLDS)
    rec = _recording(None, T=2001)
    write_recording(tmp_path / "x.csv", rec)
    for key, value in (("filter", '"calibrated"'), ("detector", '"glr"'), ("isolation", '"signature"')):
        bad = tmp_path / f"{key}.toml"
        bad.write_text(text.replace("band_V = 0.3", f"band_V = 0.3\n{key} = {value}"))
        with pytest.raises(ValueError, match=f"'{key}' = .*retired"):
            Thresholds.load(bad)
        assert main(["fdi", "replay", str(tmp_path / "x.csv"), "--thresholds", str(bad), "--out",
                     str(tmp_path / "o")]) == 2


@pytest.mark.parametrize("convention", ["floor+0.5", "round"])
def test_encoder_quantiser_convention_does_not_matter_for_a_large_leak(convention):
    """The encoder reading is the middle of its pulse interval; where the interval edges sit
    (sam: floor(theta/q) + 0.5, a logger may round) is a half-pulse zero shift the filter
    does not know. Either way a 1 L/min K_extA step at 2 s (nominal plant, sine 3 V 0.25 Hz)
    is detected within 1 s and isolated. (Small leaks are not convention-proof: a 0.25 L/min
    K_int on this input is isolated in 8/8 noise seeds with floor+0.5 and 2/8 with round,
    because the quantisation error pattern is the same in every seed.)"""
    from sam.measurement import ENCODER_RESOLUTION_RAD as q
    p = load_plant().vector()
    t = np.arange(5001) * DT
    u = input_signal("sine", t, amplitude=3.0, frequency=0.25)
    fault = {"K_extA": np.tile(profile("step", lpm(1.0), t, t0=2.0), (3, 1))}
    r = simulate_runs(np.tile(p, (3, 1)), u, DT, faults=fault, seed=11, quantise=False)
    theta = r.inp.pos
    inp = replace(r.inp, pos=(np.floor(theta / q) + 0.5) * q if convention == "floor+0.5" else np.round(theta / q) * q)
    th = Thresholds.shipped()
    out = run_filter(inp)
    st = statistics(out, th)
    for b in range(3):
        d = diagnose(out, th, b, st)
        assert d.isolated == ["K_extA"], (d.status, d.alarms)
        assert 2.0 < d.detection_time_s < 3.0


def test_tune_make_batch_per_run_onsets():
    """make_batch with per-run onsets: run i's fault column is 0 before onset[i] and the step
    value from its first sample at or after onset[i]; the onsets do not touch the seeded draws
    (loads, inputs, noise): the pressures before the earliest onset equal those of a fixed-onset
    batch of the same seed."""
    plant = load_plant()
    onsets = np.array([0.2, 0.3005, 0.45])
    r = make_batch(plant, 3, 42, fault="K_extA", size=0.5, duration=0.6, onset=onsets)
    T = 601
    assert r.truth["K_extA"].shape == (3, T)
    np.testing.assert_array_equal(r.truth["onset_s"], onsets)
    np.testing.assert_array_equal(r.truth["k_onset"], [200, 301, 450])  # 0.3005 s: first sample 0.301 s
    for i, k in enumerate(r.truth["k_onset"]):
        col = r.truth["K_extA"][i]
        assert np.all(col[:k] == 0.0)
        assert np.all(col[k:] == lpm(0.5))
    fixed = make_batch(plant, 3, 42, fault="K_extA", size=0.5, duration=0.6, onset=0.45)
    np.testing.assert_array_equal(fixed.truth["k_onset"], [450, 450, 450])
    np.testing.assert_array_equal(fixed.truth["m_L_kg"], r.truth["m_L_kg"])
    np.testing.assert_array_equal(fixed.inp.u, r.inp.u)
    np.testing.assert_allclose(fixed.inp.pA[:, :200], r.inp.pA[:, :200], rtol=0, atol=0)
    assert not np.allclose(fixed.inp.pA[0, 300:450], r.inp.pA[0, 300:450])  # run 0 leaks from 0.2 s
    with pytest.raises(ValueError, match="onset"):
        make_batch(plant, 3, 42, fault="K_extA", size=0.5, duration=0.6, onset=np.array([0.2, 0.3]))


def test_tune_onsets_seeded_uniform_on_grid_and_windows_per_run():
    """The tune's onsets: seeded by the chunk seed, on the 1 ms grid, in [1.5, 2.5] s; the
    before / within-1-s maxima of g/h are taken from each run's own onset."""
    from types import SimpleNamespace

    from fdi import tune
    a = tune.draw_onsets(2000, 500_000)
    np.testing.assert_array_equal(a, tune.draw_onsets(2000, 500_000))
    assert not np.array_equal(a, tune.draw_onsets(2000, 500_001))
    assert a.min() >= 1.5 and a.max() <= 2.5 and a.min() < 1.51 and a.max() > 2.49
    np.testing.assert_allclose(a / 1e-3, np.round(a / 1e-3), atol=1e-9)
    T = 4001
    g = np.zeros((2, T))
    g[0, 1999] = 2.0  # run 0 (onset 2.0 s): just before its onset
    g[1, 1500 + 1000] = 3.0  # run 1 (onset 1.5 s): the last sample of its 1 s window
    g[1, 2501] = 5.0  # and just after that window
    w = tune.window_maxima({"K_int": g}, SimpleNamespace(test=SimpleNamespace(h={h: 1.0 for h in tune.HYP})), np.array([2000, 1500]))
    i = tune.HYP.index("K_int")
    np.testing.assert_array_equal(w["max"][:, i, 0], [2.0, 0.0])
    np.testing.assert_array_equal(w["max"][:, i, 1], [0.0, 3.0])
    np.testing.assert_array_equal(w["max"][:, i, 2], [2.0, 5.0])
    np.testing.assert_array_equal(w["first"][:, i], [1999, 2500])
    assert np.all(w["first"][:, [j for j in range(len(tune.HYP)) if j != i]] == -1)


def test_tune_analyse_scores_each_run_from_its_own_onset(tmp_path):
    """analyse on hand-made chunks: an alarm 1 ms before a run's own onset is an 'alarm before
    onset' (even though it is after 1.5 s), one 1 ms after it is detected and isolated within
    1 s, one 1.001 s after it is detected but not within 1 s."""
    from fdi import tune
    th = Thresholds.shipped()
    n, H = 4, len(tune.HYP)
    ki = tune.HYP.index("K_int")
    jobs = [("healthy", None, 0.0, n, 1000)] + [(f"{f}_{s:g}", f, s, n, 500_000)
                                                  for f, sizes in TUNE.fault_sizes.items() for s in sizes]
    chunks = {}
    for j in jobs:
        first = np.full((n, H), -1, dtype=np.int64)
        k_on = np.full(n, 1500, dtype=np.int64)
        iso_h = np.full(n, -1, dtype=np.int64)
        if j[0] == "K_int_0.25":
            k_on = np.array([2000, 2400, 1500, 1800])
            first[:, ki] = [1999, 2401, 1600, 2801]
            iso_h[:] = ki
        if j[0] in ("K_int_0.5", "K_int_1", "K_extA_0.5"):  # every run isolated 1 ms after its onset
            first[:, tune.HYP.index(j[1])] = 1501
            iso_h[:] = tune.HYP.index(j[1])
        chunks[tune.chunk_key(j)] = dict(first=first, max=np.zeros((n, H, 3)),
                                         m_L=np.array([100., 300, 600, 700]), k_onset=k_on, iso_h=iso_h,
                                         iso_k=np.where(iso_h >= 0, first.max(axis=1), -1), conf_k=first.max(axis=1),
                                         n_withdrawn=np.zeros(n, dtype=np.int64))
    m = tune.summarise(tmp_path, tune.gather(chunks, jobs), th)
    row = next(r for r in m["rows"] if r["fault"] == "K_int" and r["size"] == 0.25)
    assert row["alarm_before_onset"] == 0.25  # run 0
    assert row["detected_within_1s"] == 0.5  # runs 1 (1 ms) and 2 (100 ms)
    assert row["isolated_within_1s"] == 0.5
    assert row["mean_delay_s"] == pytest.approx((0.001 + 0.1 + 1.001) / 3)
    assert m["false_alarm_rate"] == 0.0
    # K_int 0.25 / 0.5 / 1: 50 / 100 / 100 % -> 0.5; K_extA 0.5 passes but 1 L/min fails -> none
    assert m["smallest_detected_and_isolated_95pct_within_1s"]["K_int"] == 0.5
    assert m["smallest_detected_and_isolated_95pct_within_1s"]["K_extA"] is None
    # loads 100 / 300 / 600 / 700 kg: the 267-534 kg third has one K_int 0.25 run, isolated: 100 %
    assert m["smallest_detected_and_isolated_95pct_within_1s_by_load"]["K_int"] == [0.5, 0.25, 0.5]
    assert "uniform in [1.5, 2.5] s" in (tmp_path / "metrics.md").read_text()
    assert tune.chunk_key(jobs[0]).endswith(f"_{tune.CHUNK_VERSION}")


def test_tune_chunk_job_random_onsets_real_runs():
    """One real fault chunk: each run's onset index comes from its drawn onset, and a 1 L/min
    external leak A is alarmed after (never before) its own onset, within 1 s, and isolated. The
    filter's model has the runs' own rigid stops (sam made them): with the shipped contact, the
    third run, pressed onto the retracted stop by 10 MPa and then reversed, confirms K_extA 0.58 s
    before its onset (docs/fdi.md, "An elastic end stop in the filter's model")."""
    from fdi import FilterConfig, tune
    from fdi.config import StopRules
    plant, th = load_plant(), Thresholds.shipped()
    seed = 500_000 + 10_000
    rigid = FilterConfig(stops=StopRules.rigid())
    res = tune.chunk_job(plant, th, "K_extA", 1.0, 4, seed, cfg=rigid)
    k0 = np.round(tune.draw_onsets(4, seed) / 1e-3).astype(int)
    np.testing.assert_array_equal(res["k_onset"], k0)
    assert len(set(k0)) == 4
    ka = np.where(res["first"] >= 0, res["first"], 10**9).min(axis=1)
    assert np.all(ka >= k0) and np.all(ka - k0 <= 1000), (ka, k0)
    np.testing.assert_array_equal(res["iso_h"], tune.HYP.index("K_extA"))
    assert np.all(res["iso_k"] >= k0)


def test_vote_rules_follow_the_sensitivity_studies():
    """compute_thresholds at a tiny size: a residual votes exactly where the fault's share of it
    over the leakage box is >= VOTE_SNR healthy spreads (read back from the report of the same
    studies); h is set for the trigger level asked for."""
    from fdi.study import StudyDesign, compute_thresholds
    from fdi.thresholds import describe
    plant = load_plant()
    for trigger in (StudyDesign.trigger_level, 0.3):
        design = StudyDesign(n_leak=4, n_nuisance=4, run_length_s=4.0, trigger_level=trigger)
        th, rep = compute_thresholds(plant, design)
        # h is set for the trigger level: at most that fraction of the study's own healthy runs
        # alarms (each h is at least the empirical 1 - level/6 quantile of its maxima: the five
        # CUSUMs and the notch-flow trigger, whose h the same studies set)
        assert th.derived.trigger_level == trigger and rep["healthy_trigger_fraction"] <= trigger
        assert "notch_flow" in th.test.h and "notch_flow" in rep["healthy_maxima_quantiles"]
        assert f"CUSUM alarms at {trigger:g} per run" in describe(th)
        for p_, votes in th.test.votes.items():
            expect = [s >= design.vote_snr for s in rep["votes_snr_own"][p_]]
            if any(expect):  # (a hypothesis is never silenced: then it votes where it shows most)
                assert votes == expect, p_
            assert all(np.isfinite(rep["votes_snr_own"][p_]))
        assert th.test.memory_s == design.memory_s and th.derived.run_length_s == 4.0 and "healthy runs 4 s" in th.derived.source
    with pytest.raises(ValueError, match="trigger_level"):
        StudyDesign(n_leak=4, n_nuisance=4, trigger_level=0.001)
    with pytest.raises(ValueError, match="memory_s"):
        StudyDesign(n_leak=4, n_nuisance=4, memory_s=0.0)
    with pytest.raises(ValueError, match="run_length_s"):
        StudyDesign(n_leak=4, n_nuisance=4, run_length_s=1.0)


@pytest.mark.parametrize("drop", ["theta", "x"])
def test_a_quarter_litre_leak_out_of_a_is_named_within_a_second(drop):
    """The shipped 0.25 L/min K_extA step at 2 s (sine, 494 kg, default noise): isolated within
    1 s of the onset from x and from the encoder alone, its size band holding the truth (the
    external leaks' change residual is not divided by the filter's std, 4-8 times its healthy
    spread: docs/fdi-design.md, "The change test")."""
    from sam.scenario import load_scenario, run_scenario
    from fdi import replay

    root = Path(__file__).resolve().parents[1] / "scenarios" / "faults"
    rec = run_scenario(load_scenario(root / "extA_0p25lpm_step.toml"))
    sig = {k: v for k, v in rec.signals.items() if k != drop}
    d = replay(Recording(rec.t, sig, {}, rec.metadata, "test"), load_plant()).diagnosis
    assert d.status == "fault" and d.isolated == ["K_extA"]
    assert 2.0 < d.detection_time_s <= d.isolation_time_s <= 3.0
    size = d.size["K_extA"]
    assert size["minus_2sigma"] <= 0.25 <= size["plus_2sigma"] and size["value"] == pytest.approx(0.25, rel=0.2)
