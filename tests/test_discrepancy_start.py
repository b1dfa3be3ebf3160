"""Segment starts consistent with the model judged, and what the sam-made recordings are made of."""

from __future__ import annotations

import numpy as np
import pytest

import sam
from discrepancy import Settings, diagnose
from discrepancy.cases import CASES, make_recording, simulate_closed_loop
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


def _segment_rms_Pa(sim: SegmentSimulator, params: np.ndarray, settle: float = 0.0) -> np.ndarray:
    """(n_seg,) RMS pressure error [Pa] of each segment (both chambers, the scored samples after the start)."""
    out = sim.simulate(params[None, :], full=True, settle=settle)
    L, skip = sim.seg.length, int(sim.seg.eval_idx[0])
    err = [out[k][0][:, skip:] - np.stack([sim.data.y[k][s + skip:s + L] for s in sim.seg.starts]) for k in ("pA", "pB")]
    return np.sqrt(np.mean(np.concatenate(err, axis=1) ** 2, axis=1))


def test_the_true_plant_fits_every_segment_of_the_air_recording_at_the_noise(plant, air20):
    """The 20 s air recording's 'bad segments' had two causes. The recording was made without
    Eq. (7)'s R-dot torque, which the diagnosis models: without it the long full-speed moves err by
    several times the transmitters' 20 kPa noise. Made with it, the true plant still errs by up to
    2.6 times the noise on three segments (the recording's first sample, starts in stick-slip) when
    they start from the smoothed measurement; started from the state consistent with the model (p_A,
    p_B, v and the bristles' z estimated over 3 decay times of the hydraulic mode) every segment is
    within 1.1 times the noise."""
    sim = SegmentSimulator(prepare(air20, plant), 1.0)
    true = plant.replace(air_fraction=0.01).vector()
    measured = _segment_rms_Pa(sim, true)
    assert np.sum(measured > 1.3 * NOISE_PA) == 3 and measured.max() > 2.5 * NOISE_PA
    assert _segment_rms_Pa(sim, true, Settings().start_decay_times).max() < 1.1 * NOISE_PA
    without = _segment_rms_Pa(sim, plant.replace(air_fraction=0.01, arm_rate_torque=False).vector())
    assert without.max() > 5 * NOISE_PA


def test_hydraulic_decay_rate_is_the_mode_of_the_linearised_model(plant):
    """1 / sigma of the default plant's hydraulic mode: about 0.1 s (sigma 9/s at the extended end,
    where the oil column is longest; 15/s near the retracted end); softer oil decays slower."""
    sigma = hydraulic_decay_rate(plant.vector())
    assert 7.0 < sigma < 11.0
    assert hydraulic_decay_rate(plant.replace(B_eff=3e8).vector()) < sigma


def test_the_settled_start_is_near_the_true_state(plant):
    """Against the true (simulated) state at each segment start of a healthy recording: the settled
    start from the measured one stays within 0.75 noise sigmas (15 kPa) in both chambers. From a
    start 3 sigmas high in p_A (60 kPa), 2 low in p_B and 2 mm/s off, the one Gauss-Newton step
    removes most of the p_A error (mean 60 -> below 30 kPa) and lowers every segment's error; it
    does not converge from there (every segment starts at rest, where friction is far from
    linear): the estimate refines a measured start, it does not replace one."""
    case = CASE["no_mismatch"]
    rec = make_recording(case, duration=6.0, seed=5).measured()
    sim = SegmentSimulator(prepare(rec, plant), 1.0)
    p = plant.vector()
    _, _, truth = simulate_closed_loop(p, 6.0, 1e-3, 5 + case.seed_offset)
    st, n = sim.seg.starts, Settings().start_decay_times
    x0 = sim.initial_states(p[None, :])
    settled = sim.settled_states(p[None, :], None, x0, n)
    for j, name in ((S.p_A, "p_A"), (S.p_B, "p_B")):
        assert np.all(np.abs(settled[:, j] - truth[name][st]) < 0.75 * NOISE_PA)
    bad = x0.copy()
    bad[:, S.p_A] += 3 * NOISE_PA
    bad[:, S.p_B] -= 2 * NOISE_PA
    bad[:, S.v] += 2e-3
    fixed = sim.settled_states(p[None, :], None, bad, n)
    assert np.mean(np.abs(fixed[:, S.p_A] - truth["p_A"][st])) < 1.5 * NOISE_PA

    def rms(x):
        out = sim._run(p[None, :], None, x, sim.seg.length, None, ("p_A", "p_B", "x"))
        ev = sim.seg.eval_idx
        return np.sqrt(sum(np.mean((out[k][0][:, ev] - sim.meas[k]) ** 2, axis=1) for k in ("pA", "pB")) / 2)

    assert np.all(rms(fixed) < rms(bad))


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
