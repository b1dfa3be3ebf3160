"""A recording's own sensor noise (its transmitters' white noise, its encoder's pulse): found in
the data, and assumed by the filter and the likelihood bank where it is above the configured one
(noisier sensors than the thresholds were derived with must not read as a model that does not
fit, or as a fault)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sam import P, load_plant
from sam.geometry import joint_angle, piston_position
from sam.scenario import load_scenario, run_scenario
from fdi import FilterConfig, Sensors, replay
from fdi import offline
from fdi.recording import detect_position_sensor, encoder_pulse, filter_input, recording_sensors, white_noise_std

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios" / "faults"


def _noisy(rec, noise_Pa: float, seed: int):
    """``rec``'s measured columns with its true pressures read through transmitters of
    ``noise_Pa`` white noise."""
    rng = np.random.default_rng(seed)
    sig = dict(rec.measured().signals)
    for ch in ("pA", "pB"):
        truth = rec.truth[f"true_{ch}"]
        sig[ch] = truth + noise_Pa * rng.standard_normal(len(truth))
    return replace(rec.measured(), signals=sig)


@pytest.fixture(scope="module")
def healthy():
    """The shipped healthy 20 s cycle at 250 kg, with its truth."""
    return run_scenario(load_scenario(SCENARIOS / "healthy_cycle_20s_250kg.toml"))


@pytest.mark.parametrize("noise", [5e3, 20e3, 80e3])
def test_white_noise_std_of_a_pressure_record(healthy, noise):
    """On a real run's pressures (steps, transients, holds) plus white noise of a known std, the
    second-difference estimate is within 4 % of it; NaN samples are skipped."""
    rec = _noisy(healthy, noise, seed=int(noise))
    pA = rec.signals["pA"].copy()
    assert white_noise_std(pA) == pytest.approx(noise, rel=0.04)
    pA[100:400] = np.nan
    assert white_noise_std(pA) == pytest.approx(noise, rel=0.04)
    assert np.isnan(white_noise_std(np.full(8, 1.0)))


def test_the_filter_takes_noisier_transmitters_never_quieter(healthy):
    """80 kPa transmitters raise the filter's pressure noise to about 80 kPa; 10 kPa ones leave the
    configured 20 kPa (the thresholds' own) in place; the encoder's position noise is never raised."""
    plant = load_plant()
    sensors = Sensors()
    loud, _ = filter_input(_noisy(healthy, 80e3, seed=1), plant)
    quiet, _ = filter_input(_noisy(healthy, 10e3, seed=2), plant)
    raised = recording_sensors(sensors, loud)
    assert raised.pressure_noise == pytest.approx(80e3, rel=0.04)
    assert raised.x_noise == sensors.x_noise
    assert recording_sensors(sensors, quiet) == sensors


def test_noisy_transmitters_are_not_a_misfit_or_a_fault(healthy, monkeypatch):
    """The healthy cycle through 80 kPa transmitters replays healthy, with the noise said in the
    note; a filter and bank held at 20 kPa read the same recording as a model that does not fit."""
    plant = load_plant()
    rec = _noisy(healthy, 80e3, seed=3)
    d = replay(rec, plant).diagnosis
    assert d.status == "healthy" and d.model_fit_alarm_s is None
    assert "pressure noise 8" in d.note and "the filter's 20" in d.note
    assert d.filter_health["pressure_noise_Pa"] == pytest.approx(80e3, rel=0.04)
    monkeypatch.setattr(offline, "recording_sensors", lambda sensors, inp: sensors)
    held = replay(rec, plant).diagnosis
    assert held.model_fit_alarm_s is not None


def test_a_leak_through_noisy_transmitters_is_found_and_sized(monkeypatch):
    """A 0.5 L/min internal leak read through 60 kPa transmitters is isolated as K_int, its size
    within 20 % (the filter and the bank both assume the recording's noise)."""
    rec = run_scenario(load_scenario(SCENARIOS / "int_0p5lpm_step.toml"))
    d = replay(_noisy(rec, 60e3, seed=4), load_plant(), cfg=FilterConfig()).diagnosis
    assert d.isolated == ["K_int"]
    assert d.size["K_int"]["value"] == pytest.approx(0.5, rel=0.2)


def _coarse_encoder(rec, pulse_deg: float, column: str):
    """``rec``'s measured columns with the position read by an encoder of ``pulse_deg`` (its
    theta, or the x computed from it with the plant's geometry)."""
    p = load_plant().vector()
    q = np.deg2rad(pulse_deg)
    theta = np.round(joint_angle(rec.truth["true_x"], p[P.L_1], p[P.L_2], p[P.L_3]) / q) * q
    pos = theta if column == "theta" else piston_position(theta, p[P.L_1], p[P.L_2], p[P.L_3])
    m = rec.measured()
    return replace(m, signals={**{k: v for k, v in m.signals.items() if k not in ("x", "theta")}, column: pos})


@pytest.mark.parametrize("pulse_deg", [0.007, 0.036, 0.09])
def test_encoder_pulse_found_in_the_data(healthy, pulse_deg):
    """The pulse of an encoder of 0.007 (the SAM's), 0.036 and 0.09 deg is found within 1 % from
    a 20 s cycle's angles; the true (continuous) angles have none."""
    rec = _coarse_encoder(healthy, pulse_deg, "theta")
    assert np.rad2deg(encoder_pulse(rec.signals["theta"])) == pytest.approx(pulse_deg, rel=0.01)
    p = load_plant().vector()
    assert np.isnan(encoder_pulse(joint_angle(healthy.truth["true_x"], p[P.L_1], p[P.L_2], p[P.L_3])))


def test_x_from_a_coarser_encoder_is_an_encoder(healthy):
    """An x computed from a 0.036 deg encoder (off the SAM encoder's grid) reads as an encoder,
    not as a linear transducer, and the filter assumes its pulse."""
    plant = load_plant()
    rec = _coarse_encoder(healthy, 0.036, "x")
    assert detect_position_sensor(rec, plant) == "encoder"
    inp, report = filter_input(rec, plant)
    assert np.rad2deg(report.encoder_pulse_rad) == pytest.approx(0.036, rel=0.01)
    assert recording_sensors(Sensors(), inp).x_noise > 4 * Sensors().x_noise


def test_a_coarser_encoder_is_not_a_misfit(monkeypatch):
    """The healthy 494 kg sine read by a 0.036 deg encoder replays healthy with the encoder's pulse
    taken from the data; a filter held at the SAM's 0.007 deg reads it as a model that does not fit."""
    rec = _coarse_encoder(run_scenario(load_scenario(SCENARIOS / "healthy_sine_494kg.toml")), 0.036, "theta")
    d = replay(rec, load_plant()).diagnosis
    assert d.status == "healthy" and d.model_fit_alarm_s is None
    assert d.filter_health["encoder_pulse_deg"] == pytest.approx(0.036, rel=0.01)
    monkeypatch.setattr(offline, "recording_sensors", lambda sensors, inp: sensors)
    assert replay(rec, load_plant()).diagnosis.model_fit_alarm_s is not None
