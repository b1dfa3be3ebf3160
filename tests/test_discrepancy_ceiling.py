"""The noise ceiling of a recording and the gate on a calibrated model far short of it (fast)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

import rig
import sam
from discrepancy.ceiling import closest_library_effect, excess, noise_ceiling, short_of_ceiling
from sam import white_noise_std
from discrepancy.data import prepare
from discrepancy.settings import Settings
from discrepancy.simulation import SegmentSimulator
from sam.plant import default_plant_path


def test_noise_sd_reads_white_noise_under_a_smooth_signal():
    """A 2 Hz, 3 MPa swing sampled at 1 kHz with 20 kPa white noise: the median absolute second
    difference gives the noise, not the swing."""
    rng = np.random.default_rng(3)
    t = np.arange(20000) * 1e-3
    y = 3e6 * np.sin(2 * np.pi * 2.0 * t) + rng.normal(0.0, 2e4, t.size)
    assert white_noise_std(y) == pytest.approx(2e4, rel=0.03)
    # the swing alone: its second difference is at most 3 MPa (4 pi)^2 (1 ms)^2 = 0.47 kPa, 2 % of the noise
    assert white_noise_std(3e6 * np.sin(2 * np.pi * 2.0 * t)) < 0.0125 * 2e4


def test_noise_ceiling_is_the_fit_of_a_model_exact_up_to_the_noise():
    """On a rig recording with 15 kPa transmitters (the rig's default) and a 0.007 deg encoder, the
    ceiling of each pressure is 100 (1 - sqrt(n) sigma / ||y - mean y||) with sigma the transmitters'
    noise, read back within 5 %; the encoder's x is at 100 % to within 0.01 points."""
    plant = sam.load_plant().replace(arm_rate_torque=True)
    sc, settings = rig.load_rig_scenario(default_plant_path().parents[1] / "rig" / "healthy_closed_loop_steps.toml")
    rec = rig.record(sc, settings).measured()
    sim = SegmentSimulator(prepare(rec, plant), 1.0)
    ce = noise_ceiling(sim)
    segs = sim.segment_mask("held")
    sigma = settings.sensors.pressure_noise_Pa
    for k in ("pA", "pB"):
        y = sim.meas[k][segs][sim.mask[k][segs]]
        truth = 100.0 * (1.0 - math.sqrt(y.size) * sigma / np.linalg.norm(y - y.mean()))
        assert 100.0 - ce[k] == pytest.approx(100.0 - truth, rel=0.05)
    assert ce["x"] > 99.99
    assert ce["mean"] == pytest.approx(np.mean([ce[k] for k in ("pA", "pB", "x")]))


def test_excess_is_the_shortfall_in_units_of_the_noise_ceilings():
    assert excess(97.0, 99.5) == pytest.approx(6.0)
    assert excess(99.5, 99.5) == pytest.approx(1.0)
    assert short_of_ceiling(94.0, 99.5, 10.0) and not short_of_ceiling(95.5, 99.5, 10.0)


def _cand(name, before, after, dbh, physical=True, dbic=-50.0, sbh=-40.0, gh=0.3):
    return SimpleNamespace(name=name, physical=physical, delta_bic=dbic, seg_bic_held=sbh, gain_held=gh,
                           fit_before={"mean": before}, fit_after={"mean": after}, delta_bic_held=dbh)


def test_the_closest_library_effect_must_bring_the_model_back_to_its_noise():
    """Ceiling 99.5 %, limit 10 (fits below 95 % are short): an effect that lifts 90 % to 96 % explains
    it; one that lifts it to 93 % does not, however strong its BIC; a non-physical one never does."""
    kw = dict(ceiling_mean=99.5, limit=10.0, bic_strong=10.0, min_gain=0.05, min_points=0.5)
    far = _cand("far", 90.0, 93.0, -500.0)
    near = _cand("near", 90.0, 96.0, -200.0)
    assert closest_library_effect([far, near], **kw) is near
    assert closest_library_effect([far], **kw) is None
    assert closest_library_effect([_cand("lag", 90.0, 96.0, -200.0, physical=False)], **kw) is None
    assert closest_library_effect([_cand("weak", 90.0, 96.0, -200.0, sbh=-5.0)], **kw) is None


@pytest.mark.parametrize("knob, value", [("specific_share", 0.0), ("specific_share", 1.5), ("excess_limit", -1.0)])
def test_the_gates_knobs_are_validated(knob, value):
    with pytest.raises(ValueError, match=knob):
        Settings(**{knob: value})


def test_a_calibrated_model_short_of_its_ceiling_is_not_a_known_effect():
    """Nothing named, no significant generic term: at 89 % held out with a 99.45 % ceiling (excess 20)
    the verdict is 'unknown_effect', at 98.6 % (excess 2.5) 'recalibrated'."""
    from discrepancy.verdict import verdict_of

    located = {"signal_share": {"pA": 0.5, "pB": 0.3, "x": 0.2}, "regimes": []}
    calibration = [{"change": 0.2, "relative": True, "text": "load mass: 494 -> 593 kg"}]
    ceiling = {"mean": 99.45}
    for fit, short, want in ((89.0, True, "unknown_effect"), (98.6, False, "recalibrated")):
        table = {"calibrated": {"held": {"mean": fit}}}
        shortfall = {"short": short, "excess": excess(fit, ceiling["mean"]), "ceiling_held": ceiling, "limit": 11.0}
        verdict, headline = verdict_of([], calibration, {"terms": [], "significant": False}, table, located, shortfall)
        assert verdict == want
        if short:
            assert "errs 20.0 times the recording's noise" in headline
