"""Scenarios, plant files and the `samfdi simulate` command, including bad input."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sam
from sam.constants import LPM
from sam.errors import UserError
from sam.plant import load_plant
from sam.scenario import load_scenario, run_scenario
from samfdi.cli import main

ROOT = Path(__file__).resolve().parents[1]
PAPER_STEP = ROOT / "scenarios" / "paper_step.toml"


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def scenario_text(**tables: str) -> str:
    base = {
        "head": 'duration_s = 2.0\nseed = 3\n',
        "input": '[input]\nkind = "step"\namplitude_V = 2.5\n',
    }
    base.update(tables)
    return "\n".join(base.values())


def test_plant_defaults_are_appendix_2():
    plant = load_plant()
    assert plant.valve.Q_N_PA == pytest.approx(24 * LPM)
    assert plant.valve.dp_N_BT == 3.5e6
    assert plant.cylinder.D_piston == 0.080 and plant.cylinder.x_max == 0.545
    assert plant.boom.m_L == 494.0 and plant.boom.theta_level == 0.415  # level at alpha1 + alpha2 (docs/model.md)
    assert plant.supply.p_S == 10e6
    assert plant.valve.omega_n == pytest.approx(2 * np.pi * 20)


def test_user_plant_overrides_only_its_keys(tmp_path):
    path = write(tmp_path, "mine.toml", 'name = "rig2"\n[fluid]\nB_eff = 1.1e9\n[boom]\nm_L = 200.0\n')
    plant = load_plant(path)
    assert plant.name == "rig2" and plant.fluid.B_eff == 1.1e9 and plant.boom.m_L == 200.0
    assert plant.valve == load_plant().valve


@pytest.mark.parametrize("text, words", [
    ("[fluid]\nB_eff = -1.0\n", ["fluid.B_eff", "> 0", "-1.0"]),
    ("[cylinder]\nV_0A = 0\n", ["cylinder.V_0A", "> 0"]),
    ("[boom]\nm_L = -5\n", ["boom.m_L", ">= 0"]),
    ("[supply]\np_S = 1e5\np_T = 2e5\n", ["supply.p_S", "above tank"]),
    ("[valve]\nQ_N_PAA = 1e-4\n", ["valve.Q_N_PAA", "unknown key", "Q_N_PA"]),
    ("[valves]\nQ_N_PA = 1e-4\n", ["valves", "unknown table"]),
    ("[cylinder]\nx_max = \"long\"\n", ["cylinder.x_max", "expected a number"]),
    ("[cylinder]\nD_rod = 0.09\n", ["cylinder.D_rod", "below piston diameter"]),
    ("[fluid\nB_eff = 1\n", ["cannot read TOML"]),
])
def test_bad_plant_values_are_named(tmp_path, text, words):
    path = write(tmp_path, "bad.toml", text)
    with pytest.raises(UserError) as err:
        load_plant(path)
    message = str(err.value)
    assert "bad.toml" in message
    for word in words:
        assert word in message


def test_paper_step_scenario_runs_to_the_shared_format(tmp_path):
    rec = run_scenario(load_scenario(PAPER_STEP))
    assert rec.t[-1] == pytest.approx(4.0) and rec.dt == pytest.approx(1e-3)
    assert np.all(rec.signals["u"] == 2.5)
    # quantised encoder: theta is the middle of a 0.007 deg pulse interval, within half a pulse
    pulses = rec.signals["theta"] / np.deg2rad(0.007) - 0.5
    np.testing.assert_allclose(pulses, np.round(pulses), atol=1e-6)
    true_theta = sam.geometry.joint_angle(rec.truth["true_x"], 0.30, 1.04, 0.84)
    assert np.max(np.abs(rec.signals["theta"] - true_theta)) <= np.deg2rad(0.007) / 2 + 1e-12
    # pressure noise is the stated 20 kPa
    noise = rec.signals["pA"] - rec.truth["true_pA"]
    assert np.std(noise) == pytest.approx(20e3, rel=0.05)
    assert np.all(rec.truth["true_K_extA"] == 0.0) and np.all(rec.truth["true_mL"] == 494.0)


def test_fault_and_load_profiles_reach_the_model(tmp_path):
    text = scenario_text(
        faults='[faults.K_extA]\nkind = "step"\nvalue = 5.27e-9\nt0_s = 1.0\n',
        load='[load]\nkind = "step"\nbefore_kg = 200.0\nafter_kg = 600.0\nt0_s = 0.5\n',
    )
    rec = run_scenario(load_scenario(write(tmp_path, "s.toml", text)))
    k = rec.truth["true_K_extA"]
    assert np.all(k[rec.t < 1.0] == 0) and np.all(k[rec.t >= 1.0] == 5.27e-9)
    assert rec.truth["true_mL"][0] == 200.0 and rec.truth["true_mL"][-1] == 600.0
    # same run without the leak: the leak lowers the piston-side pressure and the speed
    healthy = run_scenario(load_scenario(write(tmp_path, "h.toml", scenario_text(
        load='[load]\nkind = "step"\nbefore_kg = 200.0\nafter_kg = 600.0\nt0_s = 0.5\n'))))
    assert rec.truth["true_v"][-1] < healthy.truth["true_v"][-1]
    assert np.array_equal(rec.truth["true_pA"][rec.t < 1.0], healthy.truth["true_pA"][healthy.t < 1.0])


@pytest.mark.parametrize("load_kg", [0.0, 200.0, 700.0])
def test_a_held_valve_starts_at_rest_under_the_scenarios_load(tmp_path, load_kg):
    """The initial state holds the scenario's [load] at t = 0, not the plant file's m_L: at x = 0.2 m
    chamber A carries exactly the load's force, and the run is the one whose plant file has that m_L."""
    held = scenario_text(input='[input]\nkind = "step"\namplitude_V = 0.0\n', initial="[initial]\nx_m = 0.2\n",
                         sensors="[sensors]\npressure_noise_Pa = 0.0\n")
    sc = load_scenario(write(tmp_path, "load.toml", held + f"\n[load]\nm_L_kg = {load_kg}\n"))
    rec = run_scenario(sc)
    same = run_scenario(load_scenario(write(tmp_path, "plant.toml", held + f"\n[plant_overrides.boom]\nm_L = {load_kg}\n")))
    for col in ("true_pA", "true_pB", "true_x", "true_v"):
        np.testing.assert_array_equal(rec.truth[col], same.truth[col])
    boom = sc.plant.boom
    A_A, A_B = np.pi / 4 * 0.080**2, np.pi / 4 * (0.080**2 - 0.045**2)
    F = sam.geometry.external_force(0.2, 0.30, 1.04, 0.84, boom.theta_level, boom.cog_angle, 297.0, 0.2,
                                    load_kg, 0.0, 1.9)
    assert rec.truth["true_pA"][0] * A_A - rec.truth["true_pB"][0] * A_B == pytest.approx(F, rel=1e-9)
    # at rest: only the null leakage creeps it (started holding the plant file's 494 kg instead, a 200 or
    # 700 kg load made the piston jump by 10-26 mm/s on the former default plant)
    assert np.max(np.abs(rec.truth["true_v"])) < 2e-3


@pytest.mark.parametrize("kind, keys", [
    ("sine", "amplitude_V = 3.0\nfrequency_Hz = 0.5\n"),
    ("chirp", "amplitude_V = 3.0\nf0_Hz = 0.1\nf1_Hz = 2.0\n"),
    ("prbs", "amplitude_V = 3.0\nhold_s = 0.2\n"),
    ("cycle", "amplitude_V = 4.0\nperiod_s = 1.0\nramp_s = 0.1\n"),
    ("cycle", "amplitude_V = 4.0\nperiod_s = 1.0\ndwell_fraction = 0.5\n"),
    ("ramp", "start_V = -3.0\nend_V = 3.0\nt0_s = 0.0\nt1_s = 2.0\n"),
])
def test_inputs_drive_both_directions(tmp_path, kind, keys):
    text = scenario_text(input=f'[input]\nkind = "{kind}"\n{keys}', initial="[initial]\nx_m = 0.2\n")
    rec = run_scenario(load_scenario(write(tmp_path, "s.toml", text)))
    v = rec.truth["true_v"]
    assert v.max() > 1e-3 and v.min() < -1e-3
    assert np.all(np.abs(rec.signals["u"]) <= 10)


def test_pwl_csv_input(tmp_path):
    write(tmp_path, "u.csv", "t,u\n0,0\n0.5,3\n1.5,-3\n2,0\n")
    text = scenario_text(input='[input]\nkind = "pwl_csv"\nfile = "u.csv"\n')
    rec = run_scenario(load_scenario(write(tmp_path, "s.toml", text)))
    assert rec.signals["u"][500] == pytest.approx(3.0) and rec.signals["u"][1000] == pytest.approx(0.0)


@pytest.mark.parametrize("tables, words", [
    ({"head": "duration_s = 2.0\ndurration_s = 3\n"}, ["durration_s", "unknown key"]),
    ({"input": '[input]\nkind = "stepp"\n'}, ["input.kind", "stepp"]),
    ({"input": '[input]\nkind = "step"\namplitude = 2.5\n'}, ["input.amplitude", "unknown key"]),
    ({"input": '[input]\nkind = "step"\namplitude_V = 20.0\n'}, ["input", "10.0 V", "20 V"]),
    ({"faults": '[faults.K_leak]\nkind = "constant"\nvalue = 1e-9\n'}, ["faults.K_leak", "unknown fault"]),
    ({"faults": '[faults.K_int]\nkind = "constant"\nvalue = -1e-9\n'}, ["faults.K_int", "negative"]),
    ({"faults": '[faults.K_int]\nkind = "ramp"\nvalue = 1e-9\nt0_s = 1.0\n'}, ["faults.K_int", "t1_s"]),
    ({"sensors": "[sensors]\nnoise = 1.0\n"}, ["sensors.noise", "unknown key"]),
    ({"head": "duration_s = -1\n"}, ["duration_s", "positive"]),
    ({"head": 'duration_s = 2.0\nplant = "nope.toml"\n'}, ["nope.toml", "not found"]),
    # an L/min figure typed where K is expected: p_A reached 18.3 MPa on a 10 MPa supply, exit 0
    ({"faults": '[faults.K_extA]\nkind = "step"\nvalue = 0.5\nt0_s = 1.0\n'},
     ["'faults.K_extA'", "9.49e+07 L/min at 10 MPa", "more than the fully open valve", 'unit = "L/min"']),
    ({"faults": '[faults.K_int]\nkind = "constant"\nvalue = 50.0\nunit = "L/min"\n'},
     ["'faults.K_int'", "a leak of 50 L/min", "burst"]),
    ({"faults": '[faults.K_int]\nkind = "constant"\nvalue = 0.5\nunit = "lpm"\n'}, ["faults.K_int.unit", "'lpm'"]),
    ({"faults": '[faults.offset]\nkind = "constant"\nvalue = 150\nunit = "%"\n'}, ["faults.offset", "150 %"]),
    # dt_s = 0.5 simulated garbage (true_v 3.6e26 m/s) with exit 0
    ({"head": "duration_s = 2.0\ndt_s = 0.5\n"}, ["'dt_s'", "unstable", "largest stable step is 15.9 ms"]),
    ({"head": "duration_s = 2.0\ndt_s = 0.02\n"}, ["'dt_s'", "unstable"]),
    # a wrong type for m_L_kg was reported as 'load.value'
    ({"load": '[load]\nm_L_kg = "494"\n'}, ["'load.m_L_kg'", "expected a number of kg", "'494'"]),
    ({"load": '[load]\nkind = "step"\nafter_kg = "a lot"\nt0_s = 1.0\n'}, ["'load.after_kg'", "number of kg"]),
])
def test_bad_scenarios_are_named(tmp_path, tables, words):
    path = write(tmp_path, "bad.toml", scenario_text(**tables))
    with pytest.raises(UserError) as err:
        load_scenario(path)
    for word in words:
        assert word in str(err.value)


def test_fault_sizes_in_the_units_every_output_speaks(tmp_path):
    text = scenario_text(faults='[faults.K_extA]\nkind = "step"\nvalue = 0.5\nunit = "L/min"\nt0_s = 1.0\n'
                                '[faults.offset]\nkind = "constant"\nvalue = 2.0\nunit = "%"\n')
    sc = load_scenario(write(tmp_path, "units.toml", text))
    assert sc.time_varying["K_extA"][-1] == pytest.approx(0.5 * LPM / np.sqrt(10e6), rel=1e-12)
    assert sc.time_varying["offset"][0] == pytest.approx(0.02)
    text = scenario_text(faults='[faults.offset]\nkind = "constant"\nvalue = 0.5\n')  # 50 %: meant 0.5 %?
    with pytest.warns(UserWarning, match=r"'faults.offset': an offset of 50 % .*if you meant 0.5 %, write unit"):
        load_scenario(write(tmp_path, "offset.toml", text))


def test_a_diverged_run_is_caught_not_written():
    """What dt_s = 0.5 produced: finite garbage (v ~ 1e26 m/s), now recognised as divergence."""
    from sam.stability import diverged

    p = sam.load_plant().vector()
    res = sam.simulate_batch(p, np.full(8, 2.5), 0.5)
    states = {k: v[0] for k, v in res.states.items()}
    k, what = diverged(states, p)
    assert 0 < k < 8 and ("supply pressure" in what or "fully open valve" in what or "not finite" in what)
    healthy = sam.simulate_batch(p, np.full(2000, 2.5), 1e-3)
    assert diverged({k: v[0] for k, v in healthy.states.items()}, p) is None


def test_plot_name_is_checked_before_the_recording_is_written(tmp_path, capsys):
    """--plot x.jpgx failed after the CSV had been written."""
    out = tmp_path / "run.csv"
    assert main(["simulate", str(PAPER_STEP), "--out", str(out), "--plot", str(tmp_path / "x.jpgx")]) == 2
    assert "x.jpgx: --plot: the file name must end in one of" in capsys.readouterr().err
    assert not out.exists()


def test_cli_simulate_writes_csv_mat_and_plot(tmp_path, capsys):
    out, plot = tmp_path / "run.csv", tmp_path / "run.png"
    assert main(["simulate", str(PAPER_STEP), "--out", str(out), "--plot", str(plot)]) == 0
    rec = sam.read_recording(out)
    assert rec.metadata["plant"] == "sam" and "true_K_int" in rec.truth
    assert plot.stat().st_size > 10_000
    assert main(["simulate", str(PAPER_STEP), "--out", str(tmp_path / "run.mat")]) == 0
    mat = sam.read_recording(tmp_path / "run.mat")
    np.testing.assert_array_equal(mat.signals["pA"], rec.signals["pA"])  # same seed, same noise


def test_cli_refuses_to_overwrite_and_names_the_file(tmp_path, capsys):
    out = tmp_path / "run.csv"
    out.write_text("precious user data\n")
    assert main(["simulate", str(PAPER_STEP), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "run.csv" in err and "--force" in err and "Traceback" not in err
    assert out.read_text() == "precious user data\n"


def test_cli_bad_input_is_one_line_without_traceback(tmp_path):
    bad = write(tmp_path, "bad.toml", scenario_text(head="duration_s = 2.0\nseeed = 1\n"))
    done = subprocess.run([sys.executable, "-m", "samfdi", "simulate", str(bad), "--out", str(tmp_path / "x.csv")],
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert "bad.toml" in done.stderr and "seeed" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.csv").exists()
