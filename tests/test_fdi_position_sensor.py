"""The position sensor a recording was read with, and the thresholds derived for it (the
encoder's thresholds do not hold their false-alarm level on a linear x sensor)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sam import load_plant
from sam.scenario import load_scenario, run_scenario
from fdi import POS_THETA, POS_X, Thresholds, replay
from fdi.recording import detect_position_sensor, filter_input
from fdi.synth import POSITION_SENSORS, simulate_runs
from fdi.thresholds import SHIPPED_BY_SENSOR
from fdi.states import I_X

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios" / "faults"


@pytest.fixture(scope="module")
def recorded():
    """The shipped healthy 20 s cycle at 250 kg (x computed from the encoder, and the true x)."""
    return run_scenario(load_scenario(SCENARIOS / "healthy_cycle_20s_250kg.toml"))


@pytest.fixture(scope="module")
def cycle(recorded):
    """Its measured columns only."""
    return recorded.measured()


@pytest.fixture(scope="module")
def linear_x(recorded):
    """What a linear transducer with 10 um of white noise reads on that run [m]."""
    x = recorded.truth["true_x"]
    return x + 1e-5 * np.random.default_rng(5).standard_normal(len(x))


def _with_x(rec, x):
    return replace(rec, signals={**{k: v for k, v in rec.signals.items() if k != "theta"}, "x": x})


def test_sensor_of_a_recording(recorded, cycle, linear_x):
    """theta, and x computed from the encoder's theta (on its grid; also with 1 um of noise, rounded
    to 10 um, or read with the plant's L_1 1 mm off the logger's), read as the encoder; the true x,
    noise-free or with 10 um of white noise (a linear transducer), as a linear sensor; an x that
    never moves as the encoder."""
    plant = load_plant()
    off = load_plant(overrides={"boom": {"L_1": plant.boom.L_1 + 1e-3}})
    x = cycle.signals["x"]
    noise = np.random.default_rng(5).standard_normal(len(x))
    assert detect_position_sensor(replace(cycle, signals={k: v for k, v in cycle.signals.items() if k != "x"}),
                                  plant) == "encoder"
    for on_grid, p in ((x, plant), (x + 1e-6 * noise, plant), (np.round(x / 1e-5) * 1e-5, plant), (x, off),
                       (np.full_like(x, 0.1), plant)):
        assert detect_position_sensor(_with_x(cycle, on_grid), p) == "encoder"
    for continuous in (recorded.truth["true_x"], linear_x):
        assert detect_position_sensor(_with_x(cycle, continuous), plant) == "linear"
    # the filter's input says which, for its end-stop gain (fdi.config.StopRules.learners)
    assert filter_input(_with_x(cycle, linear_x), plant)[0].linear_position
    assert not filter_input(cycle, plant)[0].linear_position  # x computed from the encoder
    assert filter_input(cycle, plant, position_sensor="linear")[0].linear_position  # as the user says


def test_each_sensor_has_a_shipped_file():
    """Every simulated sensor has a shipped thresholds file derived for it, and loads as such; the
    command line offers the same sensors."""
    from fdi.cli import SENSORS

    assert set(POSITION_SENSORS) == set(SHIPPED_BY_SENSOR) == set(SENSORS)
    for sensor, path in SHIPPED_BY_SENSOR.items():
        assert path.exists()
        assert Thresholds.shipped(sensor).derived.position_sensor == sensor


def test_linear_sensor_noise_is_simulated():
    """simulate_runs(position="x", x_noise=s) adds white noise of std s to the true x (drawn after
    the pressures', so they are unchanged); the encoder channel is theta."""
    plant = load_plant()
    params = np.tile(plant.vector(), (2, 1))
    u = np.tile(np.sin(np.linspace(0.0, 6.0, 2001)) * 2.0, (2, 1))
    lin = simulate_runs(params, u, 1e-3, seed=3, **POSITION_SENSORS["linear"])
    exact = simulate_runs(params, u, 1e-3, seed=3, position="x")
    enc = simulate_runs(params, u, 1e-3, seed=3, **POSITION_SENSORS["encoder"])
    err = lin.inp.pos - lin.truth["x"]
    assert lin.inp.pos_kind == POS_X and enc.inp.pos_kind == POS_THETA
    assert np.std(err) == pytest.approx(POSITION_SENSORS["linear"]["x_noise"], rel=0.05)
    assert abs(np.mean(err)) < 1e-6
    np.testing.assert_array_equal(exact.inp.pos, exact.truth["x"])
    np.testing.assert_array_equal(lin.inp.pA, exact.inp.pA)


def test_replay_picks_the_thresholds_of_the_sensor(cycle, linear_x):
    """Without --thresholds, replay reads a linear x with the linear sensor's file and theta with
    the encoder's; a linear x read with the encoder's file is diagnosed with a warning that names
    the sensor and the command that derives thresholds for it."""
    plant = load_plant()
    linear = _with_x(cycle, linear_x)
    d = replay(linear, plant).diagnosis
    assert d.thresholds["position_sensor"] == "linear" and d.filter_health["position_sensor"] == "linear"
    assert "position_sensor_warning" not in d.filter_health
    enc = replay(replace(cycle, signals={k: v for k, v in cycle.signals.items() if k != "x"}), plant).diagnosis
    assert enc.thresholds["position_sensor"] == "encoder"
    mixed = replay(linear, plant, thresholds=Thresholds.shipped("encoder")).diagnosis
    assert "--position-sensor linear" in mixed.filter_health["position_sensor_warning"]
    assert "derived for the encoder position sensor" in mixed.note


def test_thresholds_file_names_a_known_sensor(tmp_path):
    bad = tmp_path / "th.toml"
    bad.write_text('[thresholds]\nposition_sensor = "laser"\n')
    with pytest.raises(ValueError, match="'position_sensor' = 'laser' is not one of 'encoder', 'linear'"):
        Thresholds.load(bad)


def test_threshold_studies_simulate_the_sensor():
    """The studies' runs read the position of the thresholds' sensor: theta from the encoder, or
    x with the linear sensor's white noise (each row's own draw; the pressures as for the encoder)."""
    from fdi.study import StudyDesign, study_runs

    nominal = load_plant().vector()
    params = np.tile(nominal, (2, 1))
    exp, noise = np.array([0.1, 0.1]), np.array([0.2, 0.3])  # one experiment, two noise draws
    enc = study_runs(params, exp, noise, nominal, StudyDesign(position_sensor="encoder"))
    lin = study_runs(params, exp, noise, nominal, StudyDesign(position_sensor="linear"))
    assert enc.inp.pos_kind == POS_THETA and lin.inp.pos_kind == POS_X
    np.testing.assert_array_equal(enc.inp.pA, lin.inp.pA)
    x_filter = lin.mean[:, :, I_X]  # the filter's x follows the sensor to within its noise
    err = lin.inp.pos - x_filter
    assert 0.5e-5 < np.std(err[:, 500:]) < 1.5e-5
    np.testing.assert_array_equal(enc.inp.pos[0], enc.inp.pos[1])  # the same run ...
    assert np.std(lin.inp.pos[0] - lin.inp.pos[1]) > 1e-5  # ... with the noise of its row


def test_cli_names_the_sensor_and_warns_on_another(cycle, linear_x, tmp_path, capsys):
    """`fdi replay` of a linear x recording says it uses the linear sensor's thresholds; with
    `--position-sensor encoder` it uses the encoder's (as given) and so does `--thresholds` with the
    encoder's file, whose note names the sensors and the command that derives thresholds."""
    import json

    from sam import write_recording
    from samfdi.cli import main

    path = tmp_path / "linear.csv"
    write_recording(path, _with_x(cycle, linear_x))
    assert main(["fdi", "replay", str(path), "--out", str(tmp_path / "a")]) == 0
    assert "position sensor: linear (x is not on the encoder grid)" in capsys.readouterr().out
    assert main(["fdi", "replay", str(path), "--position-sensor", "encoder", "--out", str(tmp_path / "b")]) == 0
    used = json.loads((tmp_path / "b" / "diagnosis.json").read_text())
    assert used["thresholds"]["position_sensor"] == used["filter_health"]["position_sensor"] == "encoder"
    capsys.readouterr()
    code = main(["fdi", "replay", str(path), "--thresholds", str(SHIPPED_BY_SENSOR["encoder"]),
                 "--out", str(tmp_path / "c")])
    out = capsys.readouterr().out
    assert code == 0 and (tmp_path / "c" / "diagnosis.json").exists()
    assert "derived for the encoder position sensor" in out and "--position-sensor linear" in out


def test_thresholds_and_tune_simulate_the_sensor(tmp_path, monkeypatch):
    """`fdi thresholds --position-sensor linear` derives for that sensor, and the tune's runs are
    simulated with the sensor of its thresholds file (the calls, captured)."""
    from fdi import cli, montecarlo, tune
    from samfdi.cli import main

    seen = {}

    def fake_compute(plant, design, **kw):
        seen["thresholds"] = design.position_sensor
        return Thresholds.shipped(design.position_sensor), {}

    monkeypatch.setattr(cli, "compute_thresholds", fake_compute)
    monkeypatch.setattr(cli, "write_thresholds", lambda th, rep, out: [])
    assert main(["fdi", "thresholds", "--position-sensor", "linear", "--out", str(tmp_path / "th")]) == 0
    assert seen["thresholds"] == "linear"

    def fake_batch(*a, **kw):
        seen["tune"] = kw["position_sensor"]
        raise RuntimeError("captured")

    monkeypatch.setattr(tune, "make_batch", fake_batch)
    with pytest.raises(RuntimeError, match="captured"):
        tune.chunk_job(load_plant(), Thresholds.shipped("linear"), None, 0.0, 2, 1)
    assert seen["tune"] == "linear" and montecarlo.make_batch is not fake_batch


def test_a_reading_beyond_an_end_stop_is_the_stop():
    """at_the_stops: a machine's stop gives under its load and an encoder's zero is off by part of
    a count, so a reading a little beyond a stop (here one 0.007 deg count below the retracted
    angle, 0.04 mm of x, and 0.5 mm beyond the extension end) is the stop itself, for x and for
    theta alike; readings inside the stroke, and missing ones, are left as they are."""
    from sam import P
    from sam.geometry import joint_angle, piston_position
    from fdi.recording import at_the_stops

    plant = load_plant()
    p = plant.vector()
    L = p[P.L_1], p[P.L_2], p[P.L_3]
    x_end = min(p[P.x_max], piston_position(p[P.theta_max], *L))
    count = np.deg2rad(0.007)
    theta0 = joint_angle(0.0, *L)
    x_below = piston_position(theta0 - count, *L)
    assert -1e-4 < x_below < 0.0  # one count beyond the retracted stop: a few hundredths of a mm
    x = np.array([x_below, 0.1, np.nan, x_end + 5e-4])
    np.testing.assert_array_equal(at_the_stops("x", x, plant), [0.0, 0.1, np.nan, x_end])
    theta = joint_angle(np.array([0.0, 0.1, x_end]), *L)
    beyond = theta + np.sign(theta[-1] - theta[0]) * np.array([-count, 0.0, count])
    np.testing.assert_allclose(at_the_stops("theta", beyond, plant), theta, rtol=0, atol=1e-12)
