"""A recording's own transmitter noise: estimated from the data, and assumed by the filter and
the likelihood bank where it is above the configured 20 kPa (noisier transmitters than the
thresholds were derived with must not read as a model that does not fit, or as a fault)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sam import load_plant
from sam.scenario import load_scenario, run_scenario
from fdi import FilterConfig, Sensors, replay
from fdi import offline
from fdi.recording import filter_input, recording_sensors, white_noise_std

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
