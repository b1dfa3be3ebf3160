"""Calibration from a healthy reference recording (fdi.calibration, `fdi replay --reference`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sam import P, Recording, load_plant, write_recording
from samfdi.cli import main
from fdi import calibration
from fdi.synth import input_signal, lpm, profile, simulate_runs
from fdi import FilterConfig, run_filter

DT = 1e-3
#: the machine of these tests: its A->T notch passes 2 % less and its P->B notch 2 % more
#: than the plant file says, its bulk modulus is 5 % higher
TRUE_FACTOR = {"Q_N_PA": 1.0, "Q_N_AT": 0.98, "Q_N_PB": 1.02, "Q_N_BT": 1.0, "B_eff": 1.05}


def _machine(m_L: float) -> np.ndarray:
    p = load_plant().vector()
    for name, f in TRUE_FACTOR.items():
        p[P[name]] *= f
    p[P.m_L] = m_L
    return p


def _recording(kind: str, m_L: float, seconds: float, seed: int, faults=None) -> Recording:
    t = np.arange(int(round(seconds / DT)) + 1) * DT
    u = input_signal(kind, t, amplitude=3.0, frequency=0.4, seed=seed, period=3.0)
    fa = None if faults is None else {k: f(t) for k, f in faults.items()}
    r = simulate_runs(_machine(m_L)[None], u, DT, faults=fa, nominal=load_plant().vector()[None], seed=seed)
    return Recording(t, {"u": u, "pA": r.inp.pA[0], "pB": r.inp.pB[0], "theta": r.inp.pos[0]})


def test_learn_recovers_the_machine_from_a_healthy_cycle():
    """6 s of a healthy extend/retract cycle at 300 kg: each learnt factor is within 3 of its
    posterior std (times SD_INFLATION, the std apply() carries) of the true one, and the two
    mis-rated notches are learnt to better than half their 2 % error."""
    from fdi.recording import filter_input

    cfg = FilterConfig()
    inp, _ = filter_input(_recording("cycle", 300.0, 6.0, seed=3), load_plant())
    cal = calibration.learn(run_filter(inp, cfg), cfg)
    assert set(cal.factor) == set(TRUE_FACTOR)
    factor, sd = ({k: v[0] for k, v in d.items()} for d in (cal.factor, cal.sd))  # run 0 of 1
    for name, f in TRUE_FACTOR.items():
        assert abs(factor[name] - f) < 3 * calibration.SD_INFLATION * sd[name], name
    assert abs(factor["Q_N_AT"] - 0.98) < 0.01 and abs(factor["Q_N_PB"] - 1.02) < 0.01


def test_apply_writes_the_factors_and_the_carried_priors():
    from fdi import FilterInput, POS_X

    cfg = FilterConfig()
    p = load_plant().vector()[None]
    inp = FilterInput(DT, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), POS_X, p)
    cal = calibration.Calibration(factor={"Q_N_PB": np.array([1.02]), "B_eff": np.array([0.95])},
                                  sd={"Q_N_PB": np.array([0.004]), "B_eff": np.array([0.0001])})
    inp2, cfg2 = calibration.apply(inp, cfg, cal)
    assert inp2.params[0, P.Q_N_PB] == pytest.approx(1.02 * p[0, P.Q_N_PB])
    assert inp2.params[0, P.B_eff] == pytest.approx(0.95 * p[0, P.B_eff])
    changed = np.flatnonzero(inp2.params[0] != p[0])
    assert set(changed) == {int(P.Q_N_PB), int(P.B_eff)} and inp.params[0, P.Q_N_PB] == p[0, P.Q_N_PB]
    noise, old = cfg2.calibration.noise, cfg.calibration.noise
    assert noise["Q_N_PB"] == (pytest.approx(calibration.SD_INFLATION * 0.004), cfg.calibration.walk)
    assert noise["B_eff"] == (calibration.MIN_PRIOR_SD, old["B_eff"][1])  # floored; its own walk kept
    assert noise["m_L"] == old["m_L"]  # the load is not carried over
    # a reference that taught nothing (posterior = prior) leaves the prior as it was
    _, cfg3 = calibration.apply(inp, cfg, calibration.Calibration(factor={"Q_N_PA": np.array([1.0])},
                                                                  sd={"Q_N_PA": np.array([cfg.calibration.initial_sd])}))
    assert cfg3.calibration.prior("Q_N_PA")[0] == cfg.calibration.initial_sd


def _isolated_within(d: dict, name: str, t_end: float) -> bool:
    return (d["status"] == "fault" and d["isolated"] == [name] and d["isolation_time_s"] is not None
            and d["isolation_time_s"] <= t_end)


def test_reference_calibrates_and_isolates_a_small_leak(tmp_path, capsys):
    """The mis-rated machine at 300 kg, a 0.25 L/min K_int step at 2 s under a 0.4 Hz sine.
    With `--reference` (6 s of a healthy cycle at 600 kg, another load) it is detected and
    isolated as K_int within 1 s, and the learnt notch flows are the mis-rating (Q_N_PB x 1.02,
    Q_N_AT x 0.98). The CLI prints the learnt calibration and writes it into diagnosis.json; a
    missing reference file is one line and exit 2."""
    rec = tmp_path / "leak.csv"
    ref = tmp_path / "healthy.csv"
    write_recording(rec, _recording("sine", 300.0, 4.0, seed=6,
                                    faults={"K_int": lambda t: profile("step", lpm(0.25), t, t0=2.0)}))
    write_recording(ref, _recording("cycle", 600.0, 6.0, seed=8))
    capsys.readouterr()
    assert main(["fdi", "replay", str(rec), "--reference", str(ref), "--out", str(tmp_path / "cal")]) == 0
    assert "calibrated from the reference: B_eff x" in capsys.readouterr().out
    d = json.loads((tmp_path / "cal" / "diagnosis.json").read_text())
    assert _isolated_within(d, "K_int", 3.0) and d["detection_time_s"] >= 2.0
    cal = d["filter_health"]["calibrated_from_reference"]
    assert abs(cal["Q_N_PB"]["factor"] - 1.02) < 0.01 and abs(cal["Q_N_AT"]["factor"] - 0.98) < 0.01
    assert main(["fdi", "replay", str(rec), "--reference", str(tmp_path / "none.csv"), "--out", str(tmp_path / "x")]) == 2
    assert "none.csv" in capsys.readouterr().err


def test_tune_reference_runs_are_healthy_and_leave_the_batch_alone():
    """The reference batch of `fdi tune --reference`: healthy, another input, the filter given
    the plant file; drawing it does not move the batch's own draws (paired seeds)."""
    from fdi.montecarlo import make_batch, make_reference_batch

    plant = load_plant()
    a = make_batch(plant, 6, 4321, fault="K_extA", size=0.5)
    ref = make_reference_batch(plant, a.truth["params"], 4321)
    b = make_batch(plant, 6, 4321, fault="K_extA", size=0.5)
    assert np.array_equal(a.inp.pA, b.inp.pA) and np.array_equal(a.truth["params"], b.truth["params"])
    assert np.array_equal(ref.inp.params, np.tile(plant.vector(), (6, 1)))
    assert not np.allclose(ref.inp.u, a.inp.u)
    assert not any(k.startswith("K_") or k == "offset" for k in ref.truth)
