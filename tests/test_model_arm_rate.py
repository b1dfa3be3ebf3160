"""Eq. (7)'s R-dot term in sam's one step: a plant-file model setting (``[equations]
arm_rate_torque``), off by default so that every result made without it stays bit for bit, and
with it on sam agrees with the rig's full Eq. (16) where Eq. (19) does not (docs/model.md, "Motion")."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from rig_cases import scenario, settings as rig_settings

import rig
import sam
from discrepancy.simulation import fit_percent
from rig.layout import C
from sam import P, S
from sam.dynamics import N_DERIVED, derive, rhs
from sam.errors import UserError
from sam.geometry import cos_joint_angle, torque_arm

#: sha256 of _reference_runs with sam/ before the setting existed (commit 5d9aea8), on the plant that
#: was the default then (the former boom convention, kept as a named plant file).
FORMER_PLANT = sam.plant.default_plant_path().parent / "sam_level_at_pi2_minus_alpha_cog_below.toml"
DIGEST_WITHOUT_THE_SETTING = "d8363eadb0b923cf0a377be8e9537ec7adf99f511b16f2373dfeb7148bff2c02"


def _reference_runs(plant) -> str:
    """Three 3 s runs (494, 250, 700 kg; from x = 0.05, 0.40, 0.2 m; 6 V, -8 V, 3 V, onto both stops)
    under Euler, Heun and RK4 at 1 ms: the sha256 of every state at every step."""
    base = plant.vector()
    cases = [(494.0, 0.05), (250.0, 0.40), (700.0, 0.2)]
    params = np.tile(base, (len(cases), 1))
    for row, (m_L, _) in zip(params, cases):
        row[P.m_L] = m_L
    x0 = sam.initial_state(params, np.array([c[1] for c in cases]))
    t = np.arange(3000) * 1e-3
    u = np.where(t < 1.0, 6.0, np.where(t < 2.0, -8.0, 3.0))
    out = []
    for scheme in ("euler", "heun", "rk4"):
        res = sam.simulate_batch(params, u, 1e-3, x0=x0, scheme=scheme)
        out.append(np.stack([res[c] for c in S.__members__]))
    return hashlib.sha256(np.ascontiguousarray(np.stack(out)).tobytes()).hexdigest()


def test_off_by_default_and_bit_for_bit():
    """The default plant neglects the term, as the paper's Eq. (19) does; without it sam simulates
    exactly as it did before the setting existed, under every scheme."""
    assert sam.load_plant().equations.arm_rate_torque is False
    plant = sam.load_plant(FORMER_PLANT)
    assert plant.equations.arm_rate_torque is False and plant.vector()[P.arm_rate_torque] == 0.0
    assert _reference_runs(plant) == DIGEST_WITHOUT_THE_SETTING
    assert _reference_runs(plant.replace(arm_rate_torque=True)) != DIGEST_WITHOUT_THE_SETTING


@pytest.mark.parametrize("x, v", [(0.40, -0.12), (0.05, 0.08), (0.25, -0.2), (0.3, 0.0)])
def test_the_term_is_r_prime_v_squared_over_r_squared(x, v):
    """At any state the acceleration gains exactly r'(theta) v^2 / r^2 (v = r omega: dv/dt = r omega'
    + r' omega^2), with r' = (L_1 L_2 cos(theta) - r^2) / (x + L_3) (Eq. (5) differentiated);
    retracting near the extended end it is some 0.03-0.1 m/s^2, extending near the retracted end
    of the other sign."""
    plant = sam.load_plant()
    b = plant.boom
    s = np.array([6e6, 2e6, 0.1, 0.0, x, v, 1e-4])
    acc = {}
    for on in (False, True):
        p = plant.replace(arm_rate_torque=on).vector()
        d, ds = np.empty(N_DERIVED), np.empty(7)
        derive(p, d)
        rhs(s, -3.0, p, d, ds)
        acc[on] = ds.copy()
    r = torque_arm(x, b.L_1, b.L_2, b.L_3)
    slope = (b.L_1 * b.L_2 * cos_joint_angle(x, b.L_1, b.L_2, b.L_3) - r * r) / (x + b.L_3)
    assert acc[True][S.v] - acc[False][S.v] == pytest.approx(slope * v * v / r**2, rel=1e-9, abs=1e-15)
    keep = [i for i in range(7) if i != S.v]
    assert np.array_equal(acc[True][keep], acc[False][keep])


@pytest.mark.parametrize("inp, x0, m_L", [
    # fast retraction near the extended end: the boom starts past vertical, held by the rod side
    ({"kind": "step", "amplitude_V": -6.0, "t0_s": 0.1}, 0.42, 494.0),
    ({"kind": "step", "amplitude_V": -5.0, "t0_s": 0.1}, 0.35, 250.0),
    ({"kind": "step", "amplitude_V": 6.0, "t0_s": 0.1}, 0.02, 494.0),
])
def test_with_the_term_sam_follows_the_rigs_full_motion(inp, x0, m_L):
    """Against the rig with its full Eq. (16) (RK4 at 0.1 ms), sam converged (RK4 at 0.05 ms) with the
    term on fits p_A to more than 99.9 %, and better than without it, where the lever turns fastest."""
    sc = scenario(duration_s=1.0, x0=x0, m_L=m_L, input=inp)
    r = rig.simulate(sc, rig_settings())
    keep = (r.truth["x"] > 2e-3) & (r.truth["x"] < r.machine[C.x_end] - 2e-3)
    fits = {}
    for on in (False, True):
        p = sc.plant.replace(arm_rate_torque=on).vector()
        p[P.m_L] = m_L
        res = sam.simulate_batch(p, sc.u, sc.dt, x0=sam.initial_state(p, x0), substeps=20, scheme="rk4")
        fits[on] = fit_percent(r.truth["p_A"][keep], res["p_A"][0][keep])
    assert fits[True] > 99.9 and fits[True] > fits[False], fits


def test_plant_file_setting(tmp_path):
    """``[equations] arm_rate_torque = true`` reaches the parameter vector; a number instead of true or
    false is refused in one line naming the file and the key."""
    good = tmp_path / "good.toml"
    good.write_text("[equations]\narm_rate_torque = true\n")
    assert sam.load_plant(good).vector()[P.arm_rate_torque] == 1.0
    bad = tmp_path / "bad.toml"
    bad.write_text("[equations]\narm_rate_torque = 1\n")
    with pytest.raises(UserError, match=r"bad.toml.*equations.arm_rate_torque.*true or false"):
        sam.load_plant(bad)
