"""The settings objects of fdi/ are data, validated once when made: a wrong value is refused
with a message naming the field, what it got and what it must be; every knob is documented
with its meaning and unit where it is defined."""

from __future__ import annotations

import pytest

from fdi import BankDesign, FilterConfig, Thresholds
from fdi.config import CalibrationStates, SigmaPoints, StopRules
from fdi.montecarlo import TuneDesign
from fdi.study import StudyDesign

from test_fdi_structure import _classes, _documented_fields


@pytest.mark.parametrize("cls", [BankDesign, StudyDesign, TuneDesign])
def test_every_knob_of_the_designs_is_documented(cls):
    for c in _classes(cls, set()):
        undocumented = [f for f, ok in _documented_fields(c).items() if not ok]
        assert not undocumented, f"{c.__name__}: {undocumented}"


@pytest.mark.parametrize("make,message", [
    (lambda: BankDesign(n_starts=0), r"BankDesign\.n_starts = 0: must be a whole number >= 1"),
    (lambda: BankDesign(onset_lead_s=-0.1), r"BankDesign\.onset_lead_s = -0\.1: must be a duration >= 0 s"),
    (lambda: BankDesign(fit_nis=float("nan")), r"BankDesign\.fit_nis = nan: must be a finite number > 0"),
    (lambda: BankDesign(prior_sd={"K_int": 1e-9}), r"BankDesign\.prior_sd = .*: must give a size > 0 \(SI\) for each"),
    (lambda: StudyDesign(n_leak=2), r"n_leak: need at least 4, got 2"),
    (lambda: StudyDesign(position_sensor="laser"), r"position_sensor: 'laser' is not one of encoder, linear"),
    (lambda: TuneDesign(target_rate=1.5), r"TuneDesign\.target_rate = 1\.5: must be a fraction of runs in \(0, 1\)"),
    (lambda: TuneDesign(onset_range_s=(1.5, 3.5)), r"TuneDesign\.onset_range_s = \(1\.5, 3\.5\): must lie in"),
    (lambda: TuneDesign(chunk_runs=2.5), r"TuneDesign\.chunk_runs = 2\.5: must be a whole number >= 1"),
    (lambda: TuneDesign(fault_sizes={"K_int": (0.0,)}), r"TuneDesign\.fault_sizes\['K_int'\] = \(0\.0,\): must be"),
    (lambda: Thresholds().with_(drift=-1.0), r"'drift' = -1\.0 is not"),
    (lambda: Thresholds().with_(dirft=1.0), r"unknown key 'dirft'.*drift"),
    (lambda: FilterConfig(sigma_points=SigmaPoints(alpha=0.0)), r"sigma_points\.alpha"),
    (lambda: FilterConfig(calibration=CalibrationStates(states=("m_L", "m_L"))), r"names a parameter twice"),
    (lambda: FilterConfig().with_process_noise(K_itn=1e-9), r"K_itn"),
    (lambda: FilterConfig(model_scheme="heum"), r"model_scheme: 'heum' is not an integration scheme.*'heun'"),
    (lambda: StopRules(contact_stiffness_N_per_m=-1.0), r"stops\.contact_stiffness_N_per_m = -1\.0: must be a stiff"),
    (lambda: StopRules(contact_damping_ratio=1.0), r"stops\.contact_damping_ratio = 1\.0: must be a damping ratio"),
    (lambda: TuneDesign(size_coverage=0.0), r"TuneDesign\.size_coverage = 0\.0: must be a fraction of runs"),
    (lambda: TuneDesign(size_bias=-0.1), r"TuneDesign\.size_bias = -0\.1: must be a relative size error > 0"),
])
def test_a_wrong_setting_is_refused_where_it_is_made(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_the_defaults_are_valid_and_immutable():
    for obj in (BankDesign(), StudyDesign(), TuneDesign(), Thresholds(), Thresholds.shipped(), FilterConfig()):
        with pytest.raises(AttributeError):
            obj.__setattr__(next(iter(obj.__dataclass_fields__)), None)


def test_the_filter_s_model_gets_the_contact_where_the_plant_s_stops_are_rigid():
    """StopRules.model_params: the plant's rigid stop (k_stop = 0) becomes the filter's contact; a
    plant file's own contact is kept; with no contact the plant vectors are passed as they are."""
    import numpy as np

    from sam import P, load_plant

    rigid, own = load_plant().vector(), load_plant().replace(k_stop=3e8, zeta_stop=0.1).vector()
    got = StopRules(contact_stiffness_N_per_m=1e9, contact_damping_ratio=0.3).model_params(np.stack([rigid, own]))
    assert tuple(got[:, P.k_stop]) == (1e9, 3e8) and tuple(got[:, P.zeta_stop]) == (0.3, 0.1)
    assert np.array_equal(np.delete(got[0], [P.k_stop, P.zeta_stop]), np.delete(rigid, [P.k_stop, P.zeta_stop]))
    plain = np.stack([rigid])
    assert StopRules.rigid().model_params(plain) is plain
