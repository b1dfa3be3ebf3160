"""The position sensor a recording was read with, and the thresholds derived for it (session 17:
the encoder's thresholds give 3.5 % false alarms per 20 s run on a linear x sensor)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sam import load_plant
from sam.scenario import load_scenario, run_scenario
from fdi.detect import SHIPPED_BY_SENSOR, Thresholds
from fdi.replay import position_sensor, replay
from fdi.synth import POSITION_SENSORS, simulate_runs
from fdi.ukf import I_X, POS_THETA, POS_X

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios" / "faults"


@pytest.fixture(scope="module")
def cycle():
    """The shipped healthy 20 s cycle at 250 kg, measured columns only (x computed from the encoder)."""
    return run_scenario(load_scenario(SCENARIOS / "healthy_cycle_20s_250kg.toml")).measured()


def _with_x(rec, x):
    return replace(rec, signals={**{k: v for k, v in rec.signals.items() if k != "theta"}, "x": x})


def test_sensor_of_a_recording(cycle):
    """theta, and x computed from the encoder's theta (on its grid; also with 1 um of noise or
    rounded to 1 um), read as the encoder; x with 10 um of white noise reads as a linear sensor."""
    plant = load_plant()
    x = cycle.signals["x"]
    noise = np.random.default_rng(5).standard_normal(len(x))
    assert position_sensor(replace(cycle, signals={k: v for k, v in cycle.signals.items() if k != "x"}), plant) == "encoder"
    assert position_sensor(_with_x(cycle, x), plant) == "encoder"
    assert position_sensor(_with_x(cycle, x + 1e-6 * noise), plant) == "encoder"
    assert position_sensor(_with_x(cycle, np.round(x / 1e-6) * 1e-6), plant) == "encoder"
    assert position_sensor(_with_x(cycle, x + 1e-5 * noise), plant) == "linear"


def test_each_sensor_has_a_shipped_file():
    """Every simulated sensor has a shipped thresholds file derived for it, and loads as such."""
    assert set(POSITION_SENSORS) == set(SHIPPED_BY_SENSOR)
    for sensor, path in SHIPPED_BY_SENSOR.items():
        assert path.exists()
        assert Thresholds.shipped(sensor).position_sensor == sensor


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


def test_replay_picks_the_thresholds_of_the_sensor(cycle):
    """Without --thresholds, replay reads a linear x with the linear sensor's file and theta with
    the encoder's; a linear x read with the encoder's file is diagnosed with a warning that names
    the sensor and the command that derives thresholds for it."""
    plant = load_plant()
    x = cycle.signals["x"] + 1e-5 * np.random.default_rng(5).standard_normal(cycle.n)
    linear = _with_x(cycle, x)
    d = replay(linear, plant)[3]
    assert d.thresholds["position_sensor"] == "linear" and d.filter_health["position_sensor"] == "linear"
    assert "position_sensor_warning" not in d.filter_health
    enc = replay(replace(cycle, signals={k: v for k, v in cycle.signals.items() if k != "x"}), plant)[3]
    assert enc.thresholds["position_sensor"] == "encoder"
    mixed = replay(linear, plant, thresholds=Thresholds.shipped("encoder"))[3]
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
    from fdi import thresholds as T

    plant = load_plant()
    T._init(plant.vector())
    params = np.tile(plant.vector(), (2, 1))
    exp, noise = np.array([0.1, 0.5]), np.array([0.2, 0.3])
    enc = T._run_rows(params, exp, noise, Thresholds.shipped("encoder"))
    lin = T._run_rows(params, exp, noise, Thresholds.shipped("linear"))
    assert enc.inp.pos_kind == POS_THETA and lin.inp.pos_kind == POS_X
    np.testing.assert_array_equal(enc.inp.pA, lin.inp.pA)
    x_true = lin.mean[:, :, I_X]  # the filter's x follows the sensor to within its noise
    err = lin.inp.pos - x_true
    assert 0.5e-5 < np.std(err[:, 500:]) < 1.5e-5
    assert not np.array_equal(lin.inp.pos[0], lin.inp.pos[1])


def test_cli_warns_when_the_file_is_for_another_sensor(cycle, tmp_path, capsys):
    """`fdi replay --thresholds` with the encoder's file on a linear x recording: the diagnosis is
    written, and stderr names the sensors and the command that derives thresholds for it."""
    from sam import write_recording
    from samfdi.cli import main

    x = cycle.signals["x"] + 1e-5 * np.random.default_rng(5).standard_normal(cycle.n)
    path = tmp_path / "linear.csv"
    write_recording(path, _with_x(cycle, x))
    code = main(["fdi", "replay", str(path), "--thresholds", str(SHIPPED_BY_SENSOR["encoder"]),
                 "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 0 and (tmp_path / "r" / "diagnosis.json").exists()
    assert "derived for the encoder position sensor" in err and "--position-sensor linear" in err
