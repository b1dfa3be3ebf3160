"""The rig population's sensor-drawing form: another lab's transmitters and encoder, drawn per run
from a generator of their own, so that the development and held-out forms keep every draw."""

from __future__ import annotations

import numpy as np
import pytest

from rig import population
from sam.plant import default_plant_path

PLANT = default_plant_path().resolve()


def test_forms_that_keep_the_sams_sensors_draw_them_unchanged():
    for form in (population.DEVELOPMENT, population.HELD_OUT):
        for i in range(5):
            _, settings = population.draw_run(PLANT, form, 3, i)
            s = settings.sensors
            assert (s.pressure_noise_Pa, s.adc_bits, s.encoder_deg, s.delay_s) == (15e3, 16, 0.007, 0.0)


def test_other_sensors_form_draws_within_its_ranges_and_covers_them():
    form = population.OTHER_SENSORS
    drawn = [population.draw_run(PLANT, form, 3, i)[1].sensors for i in range(40)]
    noise = np.array([s.pressure_noise_Pa for s in drawn])
    assert form.pressure_noise_Pa[0] <= noise.min() and noise.max() <= form.pressure_noise_Pa[1]
    assert noise.max() - noise.min() > 0.6 * (form.pressure_noise_Pa[1] - form.pressure_noise_Pa[0])
    assert {s.adc_bits for s in drawn} == set(form.adc_bits)
    assert {s.encoder_deg for s in drawn} == set(form.encoder_deg)
    assert all(0.0 <= s.delay_s <= form.delay_s[1] for s in drawn)
    # the rest of the run is the held-out form's: same loop, load and machine draws
    table_h, _ = population.draw_run(PLANT, population.HELD_OUT, 3, 7)
    table_o, _ = population.draw_run(PLANT, form, 3, 7)
    assert table_o == {**table_h, "description": table_o["description"]}


@pytest.mark.parametrize("i", [2, 5])
def test_other_sensors_recording_carries_the_drawn_noise_and_encoder_pulse(i):
    """The recorded pressures' white noise (from second differences, which a slow signal does not
    reach) is the drawn transmitter noise within 10 %, and every angle step is a whole number of
    the drawn encoder's pulses."""
    _, settings = population.draw_run(PLANT, population.OTHER_SENSORS, 3, i, duration_s=6.0)
    rec = population.simulate_run(PLANT, population.OTHER_SENSORS, 3, i, duration_s=6.0)
    sensors = settings.sensors
    for name in ("pA", "pB"):
        d2 = np.diff(np.asarray(rec.signals[name]), 2)
        sigma = 1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0)  # var(d2) = 6 sigma^2
        assert sigma == pytest.approx(sensors.pressure_noise_Pa, rel=0.1)
    steps = np.diff(np.degrees(np.asarray(rec.signals["theta"])))
    pulses = steps[steps != 0] / sensors.encoder_deg
    assert pulses.size > 10
    np.testing.assert_allclose(pulses, np.round(pulses), atol=1e-6)
