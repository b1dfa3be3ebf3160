"""A plant file's ``[uncertain]`` section: the parameters its owner does not know exactly, each with
its range (sam.Plant.uncertain). Typed and validated at the boundary, absent from the model's vector."""

from __future__ import annotations

import numpy as np
import pytest

import sam
from sam.errors import UserError


def test_the_default_plant_marks_load_geometry_flows_and_bulk_modulus():
    """The shipped plant: the load 0-800 kg, the level angle over both reconstructions (0.415 and 1.156
    rad), the notch flows +-25 % and B_eff 300 MPa to 1.9 GPa, each range holding the nominal value."""
    plant = sam.load_plant()
    u = plant.uncertain
    assert u.names == ("Q_N_PA", "Q_N_AT", "Q_N_PB", "Q_N_BT", "B_eff", "m_L", "theta_level")
    assert u["m_L"] == (0.0, 800.0) and u["theta_level"][0] < 0.415 < 1.156 < u["theta_level"][1]
    assert u["Q_N_PA"] == pytest.approx((3e-4, 5e-4)) and u["B_eff"] == pytest.approx((3e8, 1.875e9))
    assert "offset" not in u and "F_C" not in u and len(u) == 7
    lo, hi = u.box(["m_L", "B_eff"])
    assert np.array_equal(lo, [0.0, 3e8]) and hi[0] == 800.0
    with pytest.raises(KeyError, match="F_C"):
        u["F_C"]


def test_the_model_vector_does_not_change():
    """The section is not a parameter: the flat vector is the same with and without it."""
    plant = sam.load_plant()
    bare = sam.Plant(**{k: getattr(plant, k) for k in ("name", "valve", "supply", "cylinder", "fluid", "friction",
                                                        "boom", "effects", "equations")})
    assert np.array_equal(plant.vector(), bare.vector()) and len(bare.uncertain) == 0


def test_a_factor_range_follows_the_users_nominal_value(tmp_path):
    """{ factor = [low, high] } is relative to the plant's own value: a user's 40 L/min valve gets
    30-50 L/min without restating the range; a user's [uncertain] entry replaces the default's."""
    path = tmp_path / "mine.toml"
    path.write_text("[valve]\nQ_N_PA = 6.6667e-4\n[uncertain]\nm_L = [100.0, 600.0]\nr_B = [0.1, 0.3]\n")
    u = sam.load_plant(path).uncertain
    assert u["Q_N_PA"] == pytest.approx((5e-4, 8.3334e-4), rel=1e-4)
    assert u["m_L"] == (100.0, 600.0) and u["r_B"] == (0.1, 0.3)


def test_a_range_of_zero_width_marks_a_parameter_known(tmp_path):
    path = tmp_path / "known.toml"
    path.write_text("[uncertain]\ntheta_level = [0.415, 0.415]\n")  # the default plant's value
    assert "theta_level" not in sam.load_plant(path).uncertain


@pytest.mark.parametrize("text, words", [
    ("[uncertain]\nm_L = 300.0\n", ["uncertain.m_L", "[low, high]"]),
    ("[uncertain]\nm_L = [0.0, 800.0, 900.0]\n", ["uncertain.m_L", "[low, high]"]),
    ("[uncertain]\nm_L = [800.0, 100.0]\n", ["uncertain.m_L", "above"]),
    ("[uncertain]\nm_L = [-10.0, 800.0]\n", ["boom.m_L", ">= 0"]),
    ("[uncertain]\nm_L = [\"a\", 800.0]\n", ["boom.m_L", "number"]),
    ("[uncertain]\ntheta_levl = [0.3, 1.3]\n", ["uncertain.theta_levl", "not a parameter", "theta_level"]),
    ("[uncertain]\noffset = [-0.01, 0.01]\n", ["uncertain.offset", "fault input"]),
    ("[uncertain]\nK_int = [0.0, 1e-9]\n", ["uncertain.K_int", "not a parameter"]),
    ("[uncertain]\nm_L = [0.0, 300.0]\n", ["uncertain.m_L", "494", "outside"]),
    ("[boom]\nm_L = 900.0\n", ["uncertain.m_L", "900", "outside"]),
    ("[uncertain]\nB_eff = { factor = [0.0, 2.0] }\n", ["uncertain.B_eff.factor", "> 0"]),
    ("[uncertain]\nB_eff = { scale = [0.5, 2.0] }\n", ["uncertain.B_eff", "factor"]),
    ("uncertain = 3\n", ["uncertain", "table"]),
])
def test_bad_ranges_are_one_line(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(UserError) as err:
        sam.load_plant(path)
    message = str(err.value)
    assert "\n" not in message and "bad.toml" in message
    for w in words:
        assert w in message, message
