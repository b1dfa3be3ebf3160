"""Fast checks of the mismatch diagnosis (discrepancy/): pieces, bad input, one end-to-end run."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import sam
from discrepancy import diagnose, library
from discrepancy.data import prepare
from discrepancy.simulation import MEAS_PARAMS, fit_percent
from sam.measurement import first_order_lag, time_delay
from sam.errors import UserError
from discrepancy.cases import CASES, make_recording

CASE = {c.name: c for c in CASES}


@pytest.fixture(scope="module")
def plant():
    return sam.load_plant()


@pytest.fixture(scope="module")
def air_rec():
    return make_recording(CASE["entrained_air"], duration=9.0, seed=3).measured()


def test_fit_percent_matches_matlab_convention():
    y = np.sin(np.linspace(0, 10, 500))
    assert fit_percent(y, y) == pytest.approx(100.0)
    assert fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0)
    assert fit_percent(y, y + 0.1 * (y - y.mean())) == pytest.approx(90.0)


def test_lag_and_delay_are_measurement_side():
    dt = 1e-3
    y = np.r_[np.zeros(10), np.ones(200)]
    lag = first_order_lag(y, dt, 0.01)
    assert lag[10 + 10] == pytest.approx(1 - np.exp(-1), abs=0.05)
    d = time_delay(y, dt, 0.005)
    assert d[14] == 0 and d[16] == 1
    half = time_delay(y, dt, 0.0005)
    assert half[10] == pytest.approx(0.5)


def test_library_only_uses_the_extension_point(plant):
    hyps = library(plant)
    names = {h.name for h in hyps}
    for required in ("entrained_air", "pressure_friction", "friction_level", "spool_lap", "flow_saturation",
                     "supply_droop", "bypass_leakage", "hose_compliance", "sensor_lag", "time_delay", "load_mass"):
        assert required in names
    for h in hyps:
        assert h.description and h.shows and h.starts
        for f in h.params:
            assert f.name in MEAS_PARAMS or f.name in sam.PARAM_NAMES
            assert f.lo < f.hi


def _rec(t, **signals):
    return sam.Recording(t=t, signals=signals, metadata={"plant": "sam"})


def test_too_short_is_refused(plant):
    rec = make_recording(CASE["no_mismatch"], duration=2.0)
    with pytest.raises(UserError, match="too short to separate hypotheses"):
        diagnose(rec.measured(), plant)


def test_constant_input_is_refused(plant, air_rec):
    rec = dataclasses.replace(air_rec, signals={**air_rec.signals, "u": np.full(air_rec.n, 1.5)})
    with pytest.raises(UserError, match="does not excite"):
        diagnose(rec, plant)


def test_missing_columns_are_refused(plant, air_rec):
    sig = {k: v for k, v in air_rec.signals.items() if k != "pB"}
    with pytest.raises(UserError, match="missing column 'pB'"):
        prepare(dataclasses.replace(air_rec, signals=sig), plant)
    sig = {k: v for k, v in air_rec.signals.items() if k not in ("theta", "x")}
    with pytest.raises(UserError, match="'x' or 'theta'"):
        prepare(dataclasses.replace(air_rec, signals=sig), plant)


def test_validation_from_another_plant_is_refused(plant, air_rec):
    other = dataclasses.replace(air_rec, metadata={"plant": "excavator-boom"})
    with pytest.raises(UserError, match="same machine"):
        diagnose(air_rec, plant, validate=other)
    scaled = dataclasses.replace(air_rec, signals={**air_rec.signals, "pA": air_rec.signals["pA"] * 4,
                                                   "pB": air_rec.signals["pB"] * 4}, metadata={})
    with pytest.raises(UserError, match="wrong plant|incompatible"):
        diagnose(air_rec, plant, validate=scaled)


def test_cli_end_to_end_names_entrained_air(tmp_path, air_rec):
    from samfdi.cli import main

    path = sam.write_recording(tmp_path / "air.csv", air_rec)
    out = tmp_path / "out"
    assert main(["mismatch", str(path), "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["verdict"] == "named"
    assert rep["named_effects"][0] == "entrained_air"
    assert rep["hypotheses"][0]["name"] == "entrained_air"
    assert 0.003 < rep["chosen"][0]["fitted"]["air_fraction"] < 0.03
    f = rep["fit_percent"]
    assert f["augmented"]["held"]["mean"] > f["calibrated"]["held"]["mean"]
    assert (out / "report.md").read_text().startswith("# Mismatch diagnosis")
    assert (out / "overlay.png").exists() and (out / "residual.png").exists()


def test_cli_user_errors_are_one_line(tmp_path, capsys):
    from samfdi.cli import main

    assert main(["mismatch", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "o")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_parameters_at_bounds_are_reported(plant):
    # the recording's bulk modulus is far below anything the calibration box allows
    rec = make_recording(dataclasses.replace(CASE["no_mismatch"], plant={"B_eff": 9e7}), duration=4.0, seed=5)
    rep = diagnose(rec.measured(), plant, generic=False)
    assert any("B_eff" in w and "bound" in w for w in rep.warnings)


def test_segment_start_follows_a_measurement_side_hypothesis(plant):
    # under a delay hypothesis the state at a segment start is what the sensors show `delay` later;
    # under a lag hypothesis it is y_m + tau dy_m/dt
    from discrepancy.simulation import SegmentSimulator

    rec = make_recording(CASE["no_mismatch"], duration=4.0, seed=2).measured()
    sim = SegmentSimulator(prepare(rec, plant))
    st, sm = sim.seg.starts, sim.data.smooth
    p = plant.vector()[None, :]
    x_none = sim.initial_states(p)
    x_delay = sim.initial_states(p, np.array([[0.0, 0.005]]))
    x_lag = sim.initial_states(p, np.array([[0.01, 0.0]]))
    assert np.allclose(x_none[:, sam.S.p_A], sm["pA"][st])
    assert np.allclose(x_delay[:, sam.S.p_A], sm["pA"][st + 5])
    assert np.allclose(x_lag[:, sam.S.p_A], sm["pA"][st] + 0.01 * sm["dpA"][st])


def test_heldout_cases_are_generated_by_sam():
    from discrepancy.heldout import HELDOUT, materialise

    names = {c.name for c in HELDOUT}
    assert not names & {c.name for c in CASES}
    rec = make_recording(materialise({c.name: c for c in HELDOUT}["accumulator"]), duration=1.0, seed=2)
    assert np.all(np.isfinite(rec.signals["pA"]))
