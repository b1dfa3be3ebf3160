"""The notch-flow trigger of fdi.statistics: a jump of a notch-flow calibration state,
in its own std, is an alarm that the likelihood bank then names or withdraws."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from fdi import FilterConfig, FormNoise, Thresholds
from fdi.faults import HYPOTHESES, NOTCH_STATES, NOTCH_TRIGGER
from fdi.statistics import notch_jump, statistics
from fdi.states import N_AUG

DT = 1e-3


def _output(T: int, step_at: int, step: float, sd: float, state: str = "Q_N_AT"):
    """A filter output of one run whose only motion is a step of one notch-flow state."""
    cfg = FilterConfig()
    n = N_AUG + len(cfg.calibration.states)
    mean = np.zeros((1, T, n))
    mean[0, step_at:, N_AUG + cfg.calibration.states.index(state)] = step
    return SimpleNamespace(t=np.arange(T) * DT, config=cfg, mean=mean, std=np.full((1, T, n), sd))


@pytest.mark.parametrize("state", NOTCH_STATES)
def test_a_notch_state_step_is_a_jump_of_its_size_in_std_for_one_window(state):
    """A step of 0.04 with std 0.005 is a jump of 8 std, less the 1-sigma drift: 7, on exactly the
    window's samples after the step, 0 elsewhere."""
    th = Thresholds().with_(drift=1.0, notch_jump_window_s=0.2)
    out = _output(1000, 500, 0.04, 0.005, state)
    s = notch_jump(out, th, np.ones((1, 1000), dtype=bool))[0]
    w = 200
    assert s[500:500 + w] == pytest.approx(np.full(w, 7.0))
    assert not s[:500].any() and not s[500 + w:].any()


def test_the_jump_is_zero_where_not_armed_and_before_a_restart():
    th = Thresholds().with_(drift=1.0, notch_jump_window_s=0.2)
    out = _output(1000, 500, 0.04, 0.005)
    armed = np.ones((1, 1000), dtype=bool)
    armed[0, 550:600] = False
    s = notch_jump(out, th, armed)[0]
    assert not s[550:600].any() and s[600] == pytest.approx(7.0)
    # a restart at 450: the window must lie after it, so nothing until 650
    assert not notch_jump(out, th, np.ones((1, 1000), dtype=bool), np.array([450]))[0, :650].any()
    # a jump within the drift is no jump
    assert not notch_jump(_output(1000, 500, 0.004, 0.005), th, np.ones((1, 1000), dtype=bool)).any()


def test_the_trigger_runs_only_with_its_threshold_and_the_likelihood_bank():
    """A thresholds file without a notch_flow threshold gives the five CUSUMs only; with the
    threshold the trigger joins them."""
    from sam import load_plant

    from fdi.montecarlo import make_batch
    from fdi import run_filter

    runs = make_batch(load_plant(), 1, 7, fault=None, size=0.0, duration=2.0, onset=1.0)
    th = Thresholds.shipped()
    out = run_filter(runs.inp, FilterConfig())
    old = th.with_(h={k: v for k, v in th.test.h.items() if k in HYPOTHESES})
    assert set(statistics(out, old)) == set(HYPOTHESES)
    assert set(statistics(out, old.with_(h={**old.test.h, NOTCH_TRIGGER: 3.0}))) == set(HYPOTHESES) | {NOTCH_TRIGGER}


def test_thresholds_file_notch_entry_is_validated(tmp_path):
    from fdi.thresholds import to_toml

    th = Thresholds.shipped()
    good = tmp_path / "good.toml"
    good.write_text(to_toml(th.with_(h={**th.test.h, NOTCH_TRIGGER: 3.0})))
    assert Thresholds.load(good).test.h[NOTCH_TRIGGER] == 3.0
    bad = tmp_path / "bad.toml"
    bad.write_text(good.read_text().replace('"notch_flow" = 3.0', '"notch_flow" = -1.0'))
    with pytest.raises(ValueError, match=r"'h\.notch_flow' = -1\.0 is not"):
        Thresholds.load(bad)
    window = tmp_path / "window.toml"
    window.write_text(good.read_text().replace("notch_jump_window_s = 0.2", "notch_jump_window_s = 0.0"))
    with pytest.raises(ValueError, match="'notch_jump_window_s' = 0.0 is not a window in seconds"):
        Thresholds.load(window)
    # the same checks on the values themselves, not only on load
    with pytest.raises(ValueError, match=r"'h\.notch_flow' = -1\.0 is not"):
        th.with_(h={**th.test.h, NOTCH_TRIGGER: -1.0})
    with pytest.raises(ValueError, match="'notch_jump_window_s' = 0.0 is not a window in seconds"):
        th.with_(notch_jump_window_s=0.0)


def test_an_offset_the_notch_states_absorb_is_found_by_the_trigger():
    """A -1 % offset stepping in at 1.605 s of a tune run (the held-out tune's offset -1 % chunk
    500132, run 12: 413 kg, the nuisance box drawn) moves the notch-flow states at once, while the
    offset estimate hardly moves: no CUSUM alarms within 1 s of the onset (the first at 1.85 s
    after it). The notch-flow trigger alarms within 0.1 s, and the bank names offset- within the
    second. With a thresholds file without the trigger the run is not found within the second.
    The run is drawn on the former default plant, where it was found (tests/stall_cases.py); on the
    default plant the same draw is named offset- 1.7 s after the onset (issue 33: open). Judged
    with the confirmation it was found with (20 nats, no persistence); with the shipped one (50
    nats, the lead still growing over 0.3 s, chosen on rig recordings) the trigger's alarm is
    withdrawn and offset- is named 2.4 s after the onset."""
    from sam import load_plant

    from fdi import diagnose
    from fdi.alarms import first_alarm
    from fdi.montecarlo import make_batch
    from fdi.tune import draw_onsets
    from fdi import run_filter
    from fdi.bank import BankDesign

    from stall_cases import FORMER_PLANT

    n, seed, b = 21, 500132, 12
    runs = make_batch(load_plant(FORMER_PLANT), n, seed, fault="offset", size=-0.01, duration=4.0,
                      onset=draw_onsets(n, seed), position_sensor="encoder", inputs="standard")
    k0 = int(runs.truth["k_onset"][b])
    th = Thresholds.shipped().with_(confirm_nats=20.0, persist_s=0.0)
    # the filter as the run was found with: the model's form taken as exact (no FormNoise)
    out = run_filter(runs.inp, FilterConfig(form_noise=FormNoise.exact()))
    st = statistics(out, th)
    second = k0 + 1000
    cusum_first = [int(first_alarm(st[h][b:b + 1], th.test.h[h])[0]) for h in HYPOTHESES]
    assert all(k < 0 or k > second for k in cusum_first)
    k_notch = int(first_alarm(st[NOTCH_TRIGGER][b:b + 1], th.test.h[NOTCH_TRIGGER])[0])
    assert k0 <= k_notch <= k0 + 100
    legacy = BankDesign(colour_lag_s=0.0)  # the evidence as it was found with: every sample independent
    d = diagnose(out, th, b, st, design=legacy)
    assert d.isolated == ["offset-"] and d.isolation_time_s <= out.t[second]
    old = th.with_(h={k: v for k, v in th.test.h.items() if k in HYPOTHESES})
    d_old = diagnose(out, old, b, statistics(out, old), design=legacy)
    assert d_old.isolation_time_s is None or d_old.isolation_time_s > out.t[second]
    # with the lead at its honest size (fdi.whiteness) this run is not named within the second: a price
    d_honest = diagnose(out, th, b, st)
    assert d_honest.isolation_time_s is None or d_honest.isolation_time_s > out.t[second]
    # the shipped filter (FormNoise at the null band's edge, where this offset moves the valve's
    # real edge by its own size) does not name it within the second either
    shipped = run_filter(runs.inp, FilterConfig())
    d_shipped = diagnose(shipped, th, b, statistics(shipped, th))
    assert d_shipped.isolation_time_s is None or d_shipped.isolation_time_s > out.t[second]


def test_after_long_segment_marks_the_first_motion_after_a_long_rest_or_stroke_only():
    """Rest 3 s, extend 1 s, rest 1 s, retract 2.5 s then extend 0.5 s, rest 1 s, extend 0.1 s then
    retract: marked are the first 0.3 s of the first extension (after 3 s of rest) and of the
    extension that reverses the 2.5 s retraction; not the retraction after 1 s of rest, nor the last
    strokes (after 1 s of rest, and a reversal after 0.1 s)."""
    from fdi.strokes import after_long_segment

    t = np.arange(0, 10.0, DT)
    u = np.zeros_like(t)
    u[(t >= 3.0) & (t < 4.0)] = 2.0
    u[(t >= 5.0) & (t < 7.5)] = -2.0
    u[(t >= 7.5) & (t < 8.0)] = 2.0
    u[(t >= 9.0) & (t < 9.1)] = 2.0
    u[t >= 9.1] = -2.0
    m = after_long_segment(u[None, :], DT, 0.3, 2.0, 0.3)[0]
    k = np.round(t / DT).astype(int)
    expect = ((k >= 3000) & (k <= 3300)) | ((k >= 7500) & (k <= 7800))
    assert np.array_equal(m, expect)
