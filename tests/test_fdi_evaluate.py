"""`samfdi fdi evaluate` and the rig population it scores: labels read from the true_* columns,
the tune's scoring on hand-made runs (an alarm before the onset is a false alarm, never a
detection; intervals are fdi.rates'), bad input in one line, a folder replayed end to end and
resumed, and the population's draws (seeded, labelled, two forms apart)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fdi import evaluate, rates, tune
from fdi.faults import FAULTS
from fdi.thresholds import Thresholds
from rig import population
from sam import UserError
from sam.hydraulics import leak_coefficient
from sam.plant import default_plant_path
from sam.recording import Recording, read_recording, write_recording
from sam.scenario import load_scenario, run_scenario
from samfdi.cli import main

ROOT = Path(__file__).resolve().parents[1]
HYP = tune.HYP


def _recording(n=3000, dt=1e-3, **truth) -> Recording:
    """A flat recording of n samples with the given truth columns (name -> (n,) array)."""
    t = np.arange(n) * dt
    sig = {"u": np.zeros(n), "pA": np.full(n, 5e6), "pB": np.full(n, 3e6), "x": np.full(n, 0.1)}
    return Recording(t=t, signals=sig, truth=truth, metadata={})


def test_label_reads_fault_size_onset_and_load_from_the_truth():
    """A K_extA step of 0.25 L/min at 10 MPa (given as its coefficient K) from sample 1234 under a
    load that changes before it: the fault, its size in L/min, its onset [s], the load at it."""
    n = 3000
    K = np.where(np.arange(n) >= 1234, leak_coefficient(0.25), 0.0)
    m_L = np.where(np.arange(n) >= 500, 600.0, 200.0)
    lab = evaluate.label(_recording(n, true_K_extA=K, true_K_int=np.zeros(n), true_mL=m_L), "r.csv")
    assert lab.fault == "K_extA" and lab.size == pytest.approx(0.25, abs=1e-6)
    assert lab.onset_s == pytest.approx(1.234) and lab.load_kg == 600.0
    off = np.where(np.arange(n) >= 2000, -0.01, 0.0)
    lab = evaluate.label(_recording(n, true_offset=off), "r.csv")
    assert (lab.fault, lab.size, lab.onset_s) == ("offset", -0.01, 2.0)
    healthy = evaluate.label(_recording(n, true_offset=np.zeros(n), true_mL=np.full(n, 300.0)), "r.csv")
    assert healthy.fault is None and healthy.load_kg == 300.0


@pytest.mark.parametrize("truth, words", [
    ({}, ["r.csv", "no ground truth", "true_K_int"]),
    ({"true_K_int": np.full(3000, leak_coefficient(0.5))}, ["r.csv", "true_K_int", "from the first sample", "--baseline"]),
    ({"true_K_int": np.r_[np.zeros(1000), np.full(2000, leak_coefficient(0.5))],
      "true_offset": np.r_[np.zeros(1500), np.full(1500, 0.02)]}, ["r.csv", "two faults", "K_int", "offset"]),
])
def test_label_refuses_what_it_cannot_score_naming_the_file(truth, words):
    with pytest.raises(UserError) as err:
        evaluate.label(_recording(3000, **truth), "r.csv")
    assert all(w in str(err.value) for w in words), str(err.value)


def _chunk(fault, size, k_alarm, iso, k0=5000, m_L=400.0, sized=None):
    """One scored run as evaluate.score returns it, by hand: a confirmed alarm at k_alarm (-1:
    none), the bank naming ``iso`` (None: nothing) 100 samples later; ``sized``: (value, lo, hi)."""
    H = len(HYP)
    first = np.full((1, H), -1, dtype=np.int64)
    if k_alarm >= 0 and iso is not None:
        first[0, HYP.index(iso)] = k_alarm
    named = k_alarm >= 0 and iso is not None
    value, lo, hi = sized if sized is not None else (np.nan, np.nan, np.nan)
    return {"first": first, "max": np.zeros((1, H, 3)), "m_L": np.array([m_L]), "resets": np.zeros(1),
            "k_onset": np.array([k0]), "iso_h": np.array([HYP.index(iso) if named else -1]),
            "iso_k": np.array([k_alarm + 100 if named else -1]), "conf_k": np.array([k_alarm]),
            "n_withdrawn": np.zeros(1, dtype=np.int64), "size_value": np.array([value]), "size_lo": np.array([lo]),
            "size_hi": np.array([hi]), "true_size": np.array([0.25 if fault != "offset" else 100 * size]),
            "fault": np.array([-1 if fault is None else FAULTS.index(fault)]), "size": np.array([size]),
            "onset_s": np.array([k0 * 1e-3]), "duration_s": np.array([30.0])}


def test_summary_scores_as_the_tune_does_with_intervals():
    """Four K_int 0.25 L/min runs: isolated at +0.2 s (sized 0.24, band holding the truth),
    isolated at +0.3 s (sized 0.30, band excluding it), an alarm 0.5 s BEFORE the onset (a false
    alarm, not a detection, even though the bank names K_int), and a wrong isolation (K_extA);
    three healthy runs, one with a confirmed alarm. Every rate is k of n with fdi.rates' interval."""
    runs = {"a": _chunk("K_int", 0.25, 5200, "K_int", sized=(0.24, 0.20, 0.28)),
            "b": _chunk("K_int", 0.25, 5300, "K_int", sized=(0.30, 0.27, 0.33)),
            "c": _chunk("K_int", 0.25, 4500, "K_int", sized=(0.26, 0.2, 0.3)),
            "d": _chunk("K_int", 0.25, 5100, "K_extA"),
            "h1": _chunk(None, 0.0, -1, None, k0=30000), "h2": _chunk(None, 0.0, -1, None, k0=30000),
            "h3": _chunk(None, 0.0, 12000, "offset+", k0=30000)}
    s = evaluate.summarise(runs, Thresholds.shipped())
    (row,) = s["rows"]
    assert (row["fault"], row["size"], row["runs"]) == ("K_int", 0.25, 4)
    assert row["isolated_runs"] == 2 and row["isolated_ci"] == pytest.approx(list(rates.interval(2, 4)))
    assert row["alarm_before_onset_runs"] == 1 and row["detected_within_1s"] == 0.75
    assert (row["wrong_decisions"], row["decisions_within_1s"]) == (1, 3)
    assert row["mean_delay_s"] == pytest.approx((0.2 + 0.3 + 0.1) / 3)
    assert row["sized_runs"] == 2 and row["size_error_median"] == pytest.approx((-0.04 + 0.2) / 2)
    assert row["size_inside_2sigma"] == 0.5 and row["size_inside_ci"] == pytest.approx(list(rates.interval(1, 2)))
    h = s["healthy"]
    assert (h["false_alarms"], h["runs"]) == (1, 3) and h["false_alarm_verdict"] == rates.verdict(1, 3, 0.01, False)
    assert s["alarm_before_onset"]["alarms"] == 1 and s["alarm_before_onset"]["runs"] == 4


def test_cli_refuses_bad_folders_in_one_line(tmp_path, capsys):
    """A missing folder, a folder without recordings, and a recording without true_* columns:
    exit 2, one line naming the folder or the file."""
    assert main(["fdi", "evaluate", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "nope" in err and "no such folder" in err and len(err.splitlines()) == 1
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("hello")
    assert main(["fdi", "evaluate", str(empty), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "no recordings" in err and len(err.splitlines()) == 1
    folder = tmp_path / "recs"
    write_recording(folder / "labelled.csv", _recording(3000, true_offset=np.zeros(3000)))
    write_recording(folder / "unlabelled.csv", _recording(3000))
    assert main(["fdi", "evaluate", str(folder), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "unlabelled.csv" in err and "no ground truth" in err and len(err.splitlines()) == 1
    (folder / "unlabelled.csv").unlink()  # what replay refuses is refused before any filtering too
    high = _recording(3000, true_offset=np.zeros(3000))
    high.signals["pA"][100] = 30e6
    write_recording(folder / "over_range.csv", high)
    assert main(["fdi", "evaluate", str(folder), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "over_range.csv" in err and "'pA'" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()  # refused before any work


def test_a_recording_at_another_rate_gets_advice_that_works(tmp_path, capsys):
    """A 500 Hz recording in the folder: one line saying evaluate scores 1000 Hz only and what the
    user can do (move it out; replay it alone with 500 Hz thresholds), never "pass --thresholds" to
    evaluate, which refuses 500 Hz thresholds in one line that says what to give instead."""
    folder = tmp_path / "recs"
    write_recording(folder / "r500.csv", _recording(3000, dt=2e-3, true_offset=np.zeros(3000)))
    assert main(["fdi", "evaluate", str(folder), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "r500.csv" in err and "500 Hz" in err, err
    assert "move it out of the folder" in err and "samfdi fdi replay" in err and "--sample-rate 500" in err, err
    assert "leakage GSA" not in err  # how the shipped thresholds were made is not the user's next step
    shipped = Thresholds.shipped()
    th500 = replace(shipped, derived=replace(shipped.derived, sample_dt_s=2e-3))
    with pytest.raises(UserError) as e:
        evaluate.check_rate(th500)
    assert "leave --thresholds out" in str(e.value) and "leakage GSA" not in str(e.value), str(e.value)


def test_healthy_only_evaluation_reads_naturally():
    """Three healthy 20 s runs at 494 kg: one duration (not "20-20 s"), no rate for the empty load
    thirds ("-"), and a sentence instead of a fault table with only its header."""
    runs = {f"h{i}": {**_chunk(None, 0.0, -1, None, k0=20000, m_L=494.0), "duration_s": np.array([20.0])}
            for i in range(3)}
    md = "\n".join(evaluate.markdown(evaluate.summarise(runs, Thresholds.shipped())))
    assert "per healthy run of 20 s)" in md and "20-20 s" not in md, md
    assert "-, " not in md and ", -" not in md, md
    assert "| fault |" not in md and "No fault runs" in md and "'isolated within 1 s'" not in md, md
    mixed = {**runs, "h9": {**_chunk(None, 0.0, -1, None, k0=20000, m_L=100.0), "duration_s": np.array([10.0])}}
    md = "\n".join(evaluate.markdown(evaluate.summarise(mixed, Thresholds.shipped())))
    assert "per healthy run of 10-20 s)" in md and "0-267 kg: 0.0 %, 267-534 kg: 0.0 %)" in md, md


@pytest.mark.slow
def test_evaluate_replays_a_folder_end_to_end_and_resumes(tmp_path, capsys):
    """Two of sam's shipped scenarios as a lab's labelled folder: a healthy sine and a 0.5 L/min
    K_extA step at 2 s. The healthy one raises no alarm that stands; the leak is isolated within
    1 s and sized as replay sizes it. A second run reuses both chunks; a recording added to the
    folder is scored then, alone."""
    folder = tmp_path / "recs"
    for name in ("healthy_sine_494kg", "extA_0p5lpm_step"):
        write_recording(folder / f"{name}.csv", run_scenario(load_scenario(ROOT / "scenarios" / "faults" / f"{name}.toml")))
    out = tmp_path / "ev"
    assert main(["fdi", "evaluate", str(folder), "--out", str(out)]) == 0
    s = json.loads((out / "evaluation.json").read_text())
    assert s["recordings"] == 2 and s["healthy"]["false_alarms"] == 0
    (row,) = s["rows"]
    assert (row["fault"], row["size"], row["isolated_runs"]) == ("K_extA", 0.5, 1)
    assert abs(row["size_error_median"]) < 0.1 and row["size_inside_2sigma"] == 1.0
    assert (out / "evaluation.png").stat().st_size > 10_000 and "| K_extA | 0.5 L/min | 1 |" in (
        out / "evaluation.md").read_text()
    chunks = sorted((out / "chunks").glob("*.npz"))
    stamps = [c.stat().st_mtime_ns for c in chunks]
    write_recording(folder / "int_0p5lpm_step.csv", run_scenario(load_scenario(ROOT / "scenarios" / "faults" / "int_0p5lpm_step.toml")))
    capsys.readouterr()
    assert main(["fdi", "evaluate", str(folder), "--out", str(out)]) == 0
    assert [c.stat().st_mtime_ns for c in chunks] == stamps  # reused, not recomputed
    assert len(list((out / "chunks").glob("*.npz"))) == 3
    assert json.loads((out / "evaluation.json").read_text())["recordings"] == 3


def test_population_runs_are_seeded_labelled_and_two_forms_apart(tmp_path):
    """A run is a function of (seed, index, form): drawn twice it is the same recording; its
    truth columns carry its case (fault, size in the plant's units, onset inside the form's
    range) for fdi.evaluate.label; the held-out form draws another run from the same seed."""
    plant = default_plant_path()
    a = population.simulate_run(plant, population.DEVELOPMENT, 11, 3, "K_extB", 0.25)
    b = population.simulate_run(plant, population.DEVELOPMENT, 11, 3, "K_extB", 0.25)
    assert np.array_equal(a.signals["pA"], b.signals["pA"]) and np.array_equal(a.truth["true_K_extB"], b.truth["true_K_extB"])
    lab = evaluate.label(a, "a")
    assert lab.fault == "K_extB" and lab.size == pytest.approx(0.25)
    assert population.DEVELOPMENT.onset_s[0] <= lab.onset_s <= population.DEVELOPMENT.onset_s[1]
    assert 0.0 <= lab.load_kg <= 800.0
    c = population.simulate_run(plant, population.HELD_OUT, 11, 3, "K_extB", 0.25)
    assert not np.array_equal(a.signals["u"], c.signals["u"])
    off = population.simulate_run(plant, population.DEVELOPMENT, 11, 4, "offset", -1.0)
    assert evaluate.label(off, "off").size == pytest.approx(-0.01)
    path = population.write_population(tmp_path, plant, population.DEVELOPMENT, 11,
                                       population.cases(1, 0), progress=False)[0]
    assert path.name == "0000_healthy.mat" and evaluate.label(read_recording(path), "h").fault is None
    lo, hi = population.DEVELOPMENT.healthy_s
    assert lo <= read_recording(path).t[-1] <= hi


def _sam_recorder(fault, size, n, seed, inputs="standard"):
    """A stand-in for the rig's recorder: n copies of a shipped sam scenario of the case."""
    name = "healthy_sine_494kg" if fault is None else "extA_0p5lpm_step"
    return [run_scenario(load_scenario(ROOT / "scenarios" / "faults" / f"{name}.toml"))] * n


@pytest.mark.slow
def test_a_recorded_tune_chunk_is_scored_as_evaluate_scores_and_gathered(tmp_path):
    """fdi tune with a recorder (--source rig): each recording of a chunk scored by
    fdi.evaluate.score, the chunk joined with the tune's keys and the reported sizes, and the
    tune's metrics row states the sizes; --reference is refused with a recorder, and a folder
    made from one source is refused for another."""
    from sam import load_plant

    plant, th = load_plant(), Thresholds.shipped()
    chunk = tune.recorded_chunk_job(_sam_recorder, plant, th, "K_extA", 0.5, 2, 500_000)
    assert all(chunk[k].shape[0] == 2 for k in tune.CHUNK_KEYS + tune.BANK_KEYS + ("size_value", "true_size"))
    job = ("K_extA_0.5", "K_extA", 0.5, 2, 500_000, "standard")
    cases = tune.gather({tune.chunk_key(job): chunk}, [job])
    from fdi.metrics import fault_row
    row = fault_row(cases["K_extA_0.5"], "K_extA", 0.5, None)
    assert row["isolated_runs"] == 2 and row["sized_runs"] == 2 and abs(row["size_error_median"]) < 0.1
    with pytest.raises(UserError, match="--source sam only"):
        tune.run_tune(plant, tmp_path / "t", n_runs=5, recorder=_sam_recorder, source="rig", reference=True,
                      progress=False)
    made = tune.fingerprint(plant, th, 5)
    assert "--source sam there, rig now" in tune._differences(made, tune.fingerprint(plant, th, 5, "rig"))
