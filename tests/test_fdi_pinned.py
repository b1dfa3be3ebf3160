"""Pinned pressures (stall, end stop): which change tests are held, and the baseline that
skips them (fdi.conditions.pinned, held, baseline_window)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sam import P, load_plant
from fdi import POS_X, FilterInput, FilterOutput, Thresholds, diagnose, leak_lpm, run_filter
from fdi.conditions import baseline_window, held, held_on_stop, pinned, resting_on_stop
from fdi.faults import PARAMS
from fdi.states import I_KEXTA
from fdi.synth import simulate_runs

DT = 1e-3
SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios" / "faults"
NO_PINNING = -1.0  #: pin_margin_Pa below zero: nothing is ever pinned


def _end_stop_run():
    """Nominal plant, 494 kg, the valve driven to -3 V from 0.2 s: the piston reaches the
    retracted end stop at about 1.3 s and stays there at p_A = 0, p_B = p_S."""
    p = load_plant().vector()
    t = np.arange(8001) * DT
    u = np.where(t < 0.2, 0.0, -3.0)
    return run_filter(simulate_runs(p[None], u, DT, seed=3).inp)


def test_end_stop_creep_is_held_not_alarmed():
    """On the end stop (B at supply, A at tank) a leak from A to tank carries no flow, so K_extA
    is unobservable, and its non-negative estimate is free to creep. The pinned and held masks
    name exactly the parameters the pinned pressures hide, and the run is healthy. (This short
    creep stays below h even unheld; the case where the hold decides is the 60 s stall:
    test_the_long_stall_still_needs_the_hold.)"""
    out = _end_stop_run()
    th = Thresholds.shipped()
    pin = pinned(out, th)[0]
    assert pin[:, 0].sum() == 0 and pin[int(2 / DT):, 1].all()  # B at supply, A at tank from 2 s on
    hidden = held(out, th)[0][:, int(2 / DT):].all(axis=1)
    assert dict(zip(PARAMS, hidden)) == {"K_int": False, "K_extA": True, "K_extB": False, "offset": True}
    assert diagnose(out, th, 0).status == "healthy"
    # the bank names no fault whose test is held on the stop (fdi.isolation.decide's hidden);
    # on the way there (x > 1 mm) nothing is hidden from it
    on_stop = held_on_stop(out, th)[0]
    assert np.array_equal(on_stop[:, int(2 / DT):], held(out, th)[0][:, int(2 / DT):])
    assert not on_stop[:, out.mean[0, :, 4] > 1e-3].any() and (out.mean[0, :int(1.0 / DT), 4] > 1e-3).all()


def test_offset_and_kint_tests_are_held_while_resting_on_the_extension_stop():
    """Nominal plant, 494 kg, from x = 0.42 m: 3 V for 1 s drives the piston onto the extension
    end stop (the joint limit theta_max, x = 0.4374 m, before the 0.545 m stroke), then the valve
    input is 0 for 3 s. resting_on_stop is True from shortly after the input drops until the end
    (the piston blocked, the spool at null) and never while the valve is open; held() holds the
    K_int and offset tests there, not the external leaks' (the pressures are not pinned: A settles
    near 6.6 MPa, B near 3.7), and filter_health reports the time."""
    p = load_plant().vector()
    t = np.arange(4001) * DT
    u = np.where(t < 1.0, 3.0, 0.0)
    out = run_filter(simulate_runs(p[None], u, DT, seed=4, x0=0.42).inp)
    th = Thresholds.shipped()
    rest = resting_on_stop(out, th)[0]
    assert not rest[t < 1.0].any() and rest[t >= 1.1].all()
    assert out.mean[0, -1, 4] == pytest.approx(0.4374, abs=1e-3)
    hidden = held(out, th)[0][:, t >= 1.1].all(axis=1)
    assert dict(zip(PARAMS, hidden)) == {"K_int": True, "K_extA": False, "K_extB": False, "offset": True}
    assert diagnose(out, th, 0).filter_health["resting_on_stop_s"] == pytest.approx(rest.sum() * DT)


@pytest.mark.slow
def test_the_long_stall_still_needs_the_hold():
    """The healthy 60 s cycle at 800 kg on the former default plant (tests/stall_cases.py) stalls
    against the load with pinned pressures
    (46.7 s of its 60 s): with the shipped thresholds it is healthy; with nothing ever pinned
    an offset test alarms (measured 19-24 s), the estimate that creeps where the pinned pressures
    hide it, with or without the CUSUM's memory (the confirmation bank, whose notch flows may
    move, withdraws those alarms too). After the 0.5 s warm-up the K_extA estimate stays below
    the 0.25 L/min target size (its test triggers at 17 s when nothing is held, withdrawn by the
    bank)."""
    from fdi import replay
    from stall_cases import stalled_800kg

    rec, plant = stalled_800kg("healthy_cycle_60s_800kg.toml")
    th = Thresholds.shipped()
    r = replay(rec, plant, thresholds=th)
    out, diagnosis = r.output, r.diagnosis
    assert diagnosis.status == "healthy"
    assert leak_lpm(out.mean[0, out.t >= th.window.warmup_s, I_KEXTA]).max() < 0.25
    for memory in (th.test.memory_s, None):
        # the long-stroke rule off too: this is about what the pinned hold alone does
        unheld = replay(rec, plant, thresholds=th.with_(pin_margin_Pa=NO_PINNING, memory_s=memory,
                                                              long_stroke_s=None)).diagnosis
        assert any(k.startswith("offset") for k in unheld.alarms)


def test_fed_chamber_leak_is_still_seen_in_a_stall():
    """Pinned at 10 / 0 MPa (800 kg stalls the cylinder), a leak out of the fed chamber A is
    made up through the open P->A notch at a pressure drop dp_N (Q / (Q_N x_s))^2, 17 kPa for
    0.5 L/min: K_extA is NOT held there. The 800 kg sine on the former plant (stalled from 0.4 to 2.3 s,
    step at 2.0 s) is detected within 0.2 s and sized 0.5 L/min."""
    from fdi import replay
    from stall_cases import stalled_800kg

    rec, plant = stalled_800kg("extA_0p5lpm_step_800kg.toml")
    d = replay(rec, plant).diagnosis
    assert d.status == "fault" and d.isolated == ["K_extA"]
    assert 2.0 <= d.detection_time_s < 2.2
    assert d.size["K_extA"]["value"] == pytest.approx(0.5, abs=0.05)
    assert d.filter_health["pinned_s"] > 1.0


def _output(pA, pB, pS=None, p_S_plant=10e6):
    """A FilterOutput carrying only what pinned() reads: posterior pressures and the input."""
    B, T = pA.shape
    params = np.tile(load_plant().vector(), (B, 1))
    params[:, P.p_S] = p_S_plant
    mean = np.zeros((B, T, 12))
    mean[:, :, 0], mean[:, :, 1] = pA, pB
    inp = FilterInput(DT, np.zeros((B, T)), pA, pB, np.zeros((B, T)), POS_X, params, pS)
    z = np.zeros(B)
    return FilterOutput(np.arange(T) * DT, mean, np.ones_like(mean), np.zeros((B, T, 3)), np.zeros((B, T)),
                        z, z, z, z, u=inp.u, inp=inp)


def test_pinned_uses_the_measured_supply_when_there_is_one():
    """A supply sagging to 9.05 MPa with A at 9.0 and B at 0 MPa is a stall: pinned against the
    measured p_S, not against the plant's 10 MPa (which the recording does not reach)."""
    th = Thresholds.shipped()
    pA, pB = np.full((1, 5), 9.0e6), np.zeros((1, 5))
    assert not pinned(_output(pA, pB), th).any()
    assert pinned(_output(pA, pB, pS=np.full((1, 5), 9.05e6)), th)[..., 0].all()
    # in a gap of the measured supply, the plant's (as the filter does): 9.9 MPa is pinned there
    pS = np.array([[10e6, np.nan, np.nan, 10e6, 10e6]])
    assert pinned(_output(np.full((1, 5), 9.9e6), pB, pS=pS), th)[..., 0].all()


def test_reference_baseline_skips_what_the_pinned_reference_hides(monkeypatch):
    """`--baseline REF` with a reference that ends on the end stop (A at tank from 1.3 s on):
    K_extA is unobservable there, so the baseline takes K_extA from the samples that show it,
    not from the second half. The estimate stays put there by itself, so a creep is put in: the
    filter's K_extA estimate is raised by 0.5 L/min wherever the pinned pressures hide it."""
    from sam import Recording
    from fdi import offline as replay_module
    from fdi.faults import PARAMS
    from fdi import K_PER_LPM, FilterConfig, leak_lpm

    th = Thresholds.shipped()
    j = PARAMS["K_extA"]
    k = list(PARAMS).index("K_extA")

    def creeping_filter(*args, **kw):
        out = run_filter(*args, **kw)
        out.mean[:, :, j] += np.where(held(out, th)[:, k], 0.5 * K_PER_LPM, 0.0)
        return out

    out = _end_stop_run()
    assert held(out, th)[0, k, out.mean.shape[1] // 2:].all()  # the second half hides K_extA
    inp = out.inp
    rec = Recording(out.t, {"u": inp.u[0], "pA": inp.pA[0], "pB": inp.pB[0], "theta": inp.pos[0]})
    monkeypatch.setattr(replay_module, "run_filter", creeping_filter)
    base = replay_module.reference_baseline(rec, load_plant(), th, FilterConfig())[0]
    assert abs(leak_lpm(base[k])) < 0.05  # the second half would give 0.5


@settings(max_examples=60, deadline=None)
@given(hidden=st.lists(st.booleans(), min_size=10, max_size=120), split=st.integers(0, 60))
def test_baseline_window_skips_hidden_samples(hidden, split):
    """For any hidden pattern: the baseline never uses a hidden sample; with at least
    min_baseline_s of visible samples in [warmup, warmup + baseline_s] it is exactly those,
    armed at the window's end; otherwise it is the first baseline_s of visible samples after
    the warm-up, armed from the last of them on (never, if there are not that many)."""
    dt = 0.05
    th = Thresholds.shipped().with_(warmup_s=0.5, baseline_s=1.0)
    h = np.array(hidden + [False] * split + hidden, dtype=bool)  # visible stretches in between
    t = np.arange(len(h)) * dt
    w, ready = (a[0, 0] for a in baseline_window(t, h[None, None, :], th))
    assert not (w & h).any()
    window = (t >= th.window.warmup_s) & (t < th.window.warmup_s + th.window.baseline_s)
    n_base = int(round(th.window.baseline_s / dt))
    if (window & ~h).sum() * dt >= th.window.min_baseline_s:
        assert np.array_equal(w, window & ~h)
        assert np.array_equal(ready, t >= th.window.warmup_s + th.window.baseline_s)
        return
    visible = np.flatnonzero((t >= th.window.warmup_s) & ~h)
    assert np.array_equal(np.flatnonzero(w), visible[:n_base])
    if len(visible) >= n_base:  # armed from the sample after the last baseline sample
        armed = visible[n_base - 1] + 1
        assert np.array_equal(np.flatnonzero(ready), np.arange(armed, len(t)))
    else:
        assert not ready.any()
