"""Segment starts consistent with the model judged, and what the sam-made recordings are made of."""

from __future__ import annotations

import numpy as np
import pytest

import sam
from discrepancy import Settings, diagnose
from discrepancy.cases import CASES, make_recording
from discrepancy.data import prepare
from discrepancy.diagnose import _of_form
from discrepancy.generic import _map
from discrepancy.simulation import SegmentSimulator, hydraulic_decay_rate
from sam import S

CASE = {c.name: c for c in CASES}
NOISE_PA = 20e3  #: the transmitters' noise of discrepancy.cases' recordings


@pytest.fixture(scope="module")
def plant():
    return sam.load_plant().replace(arm_rate_torque=Settings().arm_rate_torque)


@pytest.fixture(scope="module")
def air20(plant):
    """benchmarks/bench_mismatch.py's recording: 20 s, 1 % free air, seed 1."""
    return make_recording(CASE["entrained_air"], 20.0).measured()


def _segment_rms_Pa(sim: SegmentSimulator, params: np.ndarray) -> np.ndarray:
    """(n_seg,) RMS pressure error [Pa] of each segment (both chambers, every sample after the start)."""
    out = sim.simulate(params[None, :], full=True)
    L, skip = sim.seg.length, int(sim.seg.eval_idx[0])
    err = [out[k][0][:, skip:] - np.stack([sim.data.y[k][s + skip:s + L] for s in sim.seg.starts]) for k in ("pA", "pB")]
    return np.sqrt(np.mean(np.concatenate(err, axis=1) ** 2, axis=1))


def test_the_true_plant_fits_every_segment_of_the_air_recording_at_the_noise(plant, air20):
    """The '1 of 6 held-out segments worse' of the 20 s air case was not a start state: the recording
    was made without Eq. (7)'s R-dot torque, which the diagnosis models. Made with it, the true
    plant predicts every 1 s segment within 1.5 times the transmitters' 20 kPa noise; without the
    term, the long full-speed moves err by several times the noise."""
    sim = SegmentSimulator(prepare(air20, plant), 1.0)
    rms = _segment_rms_Pa(sim, plant.replace(air_fraction=0.01).vector())
    assert rms.max() < 1.5 * NOISE_PA
    without = _segment_rms_Pa(sim, plant.replace(air_fraction=0.01, arm_rate_torque=False).vector())
    assert without.max() > 5 * NOISE_PA


def test_hydraulic_decay_rate_is_the_mode_of_the_linearised_model(plant):
    """1 / sigma of the default plant's hydraulic mode: about 0.1 s (sigma 9/s at the extended end,
    where the oil column is longest; 15/s near the retracted end); softer oil (air) decays slower."""
    sigma = hydraulic_decay_rate(plant.vector())
    assert 7.0 < sigma < 11.0
    assert hydraulic_decay_rate(plant.replace(B_eff=3e8).vector()) < sigma


def test_a_start_state_off_by_kPa_and_mm_per_s_is_recovered(plant):
    """Every segment started 300 kPa high in p_A, 200 kPa low in p_B and 5 mm/s off: the settled
    start returns within 40 kPa (2 noise sigmas) and 2 mm/s of the smoothed measured start, and each
    segment's window error comes back to that of the measured start."""
    rec = make_recording(CASE["no_mismatch"], duration=6.0, seed=5).measured()
    sim = SegmentSimulator(prepare(rec, plant), 1.0)
    p = plant.vector()[None, :]
    x0 = sim.initial_states(p)
    bad = x0.copy()
    bad[:, S.p_A] += 3e5
    bad[:, S.p_B] -= 2e5
    bad[:, S.v] += 5e-3
    fixed = sim.settled_states(p, None, bad, Settings().start_decay_times)
    assert np.all(np.abs(fixed[:, S.p_A] - x0[:, S.p_A]) < 2 * NOISE_PA)
    assert np.all(np.abs(fixed[:, S.p_B] - x0[:, S.p_B]) < 2 * NOISE_PA)
    assert np.all(np.abs(fixed[:, S.v] - x0[:, S.v]) < 2e-3)
    # and the settled start of the measured start stays close to it (nothing to correct beyond noise)
    again = sim.settled_states(p, None, x0, Settings().start_decay_times)
    assert np.all(np.abs(again[:, [S.p_A, S.p_B]] - x0[:, [S.p_A, S.p_B]]) < 2 * NOISE_PA)


def test_start_decay_times_is_validated():
    with pytest.raises(ValueError, match="start_decay_times"):
        Settings(start_decay_times=-1.0)
    assert Settings(start_decay_times=0.0).start_decay_times == 0.0


def test_a_generic_term_in_a_library_effects_form_maps_to_it():
    assert _map([("F_d", "(p_A + p_B) sgn v")])[1] == "pressure_friction"
    assert _map([("Q_dA", "(p_A - p_B)"), ("Q_dB", "(p_A - p_B)")])[1] == "bypass_leakage"
    assert _map([("Q_dA", "sqrt|p_A|")])[1] is None
    assert _map([("Q_dA", "x_s")])[1] is None

    class _C:  # the parts of a first-round candidate _of_form reads
        def __init__(self, name, gain_held, before, after):
            self.name, self.gain_held = name, gain_held
            self.fit_before, self.fit_after = {"mean": before}, {"mean": after}

    cands = [_C("friction_level", 0.3, 90.0, 93.0), _C("pressure_friction", 0.2, 90.0, 92.0)]
    assert _of_form(cands, "pressure_friction") is cands[1]
    assert _of_form([_C("pressure_friction", -0.1, 90.0, 89.0)], "pressure_friction") is None
    assert _of_form(cands, None) is None


@pytest.mark.slow
def test_the_20s_air_recording_is_named_air_near_1_percent(plant, air20):
    """benchmarks/bench_mismatch.py's case end to end: entrained air named, 0.9-1.1 % (truth 1 %), and
    the held-out fit rises."""
    rep = diagnose(air20, sam.load_plant(), None, figures=False)
    assert rep.verdict == "named" and rep.named[0] == "entrained_air"
    assert 0.009 < rep.chosen[0].effect_values()["air_fraction"] < 0.011
    ft = rep.fit_table
    assert ft["augmented"]["held"]["mean"] > ft["calibrated"]["held"]["mean"] + 2.0
