"""The evidence's honest size (fdi.whiteness, BankDesign.honest in fdi.isolation.decide):
independent increments keep their evidence, an AR(1) sequence has its known integrated
autocorrelation time, the estimate is causal and about the mean, and a lead built of coloured
increments does not confirm."""

from __future__ import annotations

import numpy as np
import pytest

from fdi.bank import BANK, DESIGN, BankDesign, BankResult
from fdi.isolation import decide, margin_for
from fdi.states import K_PER_LPM
from fdi.whiteness import evidence_factor, running_iat, white_spread


def ar1(rho: float, n_runs: int, n: int, seed: int) -> np.ndarray:
    """(n_runs, n) stationary AR(1) sequences x_t = rho x_{t-1} + e_t, e ~ N(0, 1)."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((n_runs, n))
    x = np.empty_like(e)
    x[:, 0] = e[:, 0] / np.sqrt(1.0 - rho * rho)
    for t in range(1, n):
        x[:, t] = rho * x[:, t - 1] + e[:, t]
    return x


def test_independent_increments_keep_their_evidence():
    """200 white sequences of 1000 samples (the bank's decision window at 1 kHz), lag 50: the
    estimate's mean is 1 less the centring's bias (about 2 sum_j w_j / n = 0.05) within 0.03, its spread that of white_spread within 15 %. At the
    design's lag (0.1 s) and z = 2, a cumulative ratio of independent increments with a mean
    (a fault's steady gain) keeps its whole evidence in >= 95 % of the windows, its mean factor
    below 1.03."""
    x = np.random.default_rng(32).standard_normal((200, 1000))
    tau = running_iat(x, 50)[:, -1]
    assert tau.mean() == pytest.approx(1.0 - 2.0 * np.sum(1.0 - np.arange(1, 51) / 51.0) / 1000, abs=0.03)
    assert tau.std() == pytest.approx(white_spread(1000, 50), rel=0.15)
    f = evidence_factor(np.cumsum(0.3 + x, axis=1), 100, DESIGN.colour_z)[:, -1]
    assert np.all(f >= 1.0) and (f == 1.0).mean() >= 0.95 and f.mean() < 1.03
    honest = DESIGN.honest(np.cumsum(0.3 + x, axis=1), 1e-3)[:, -1]
    assert np.median(honest / np.cumsum(0.3 + x, axis=1)[:, -1]) == 1.0


@pytest.mark.parametrize("rho", [0.5, 0.9])
def test_ar1_has_its_known_integrated_autocorrelation_time(rho):
    """AR(1) of coefficient rho: with a lag window far beyond its correlation length the estimate
    is (1 + rho) / (1 - rho) within 6 %; with Bartlett weights at lag M it is
    1 + 2 sum_j (1 - j / (M + 1)) rho^j within 6 %; a mean added changes neither."""
    x = ar1(rho, 20, 40_000, seed=int(100 * rho))
    assert running_iat(x, 400)[:, -1].mean() == pytest.approx((1 + rho) / (1 - rho), rel=0.06)
    j = np.arange(1, 51)
    bartlett = 1.0 + 2.0 * np.sum((1.0 - j / 51.0) * rho ** j)
    assert running_iat(x, 50)[:, -1].mean() == pytest.approx(bartlett, rel=0.06)
    np.testing.assert_allclose(running_iat(x + 3.0, 50)[:, -1], running_iat(x, 50)[:, -1], rtol=1e-6)


def test_the_estimate_is_causal():
    """Sample k uses samples up to k only: changing later ones changes nothing before."""
    x = np.random.default_rng(7).standard_normal(2000)
    y = x.copy()
    y[1200:] += 5.0
    np.testing.assert_array_equal(running_iat(x, 50)[:1200], running_iat(y, 50)[:1200])
    np.testing.assert_array_equal(evidence_factor(np.cumsum(x), 50, 2.0)[:1200],
                                  evidence_factor(np.cumsum(y), 50, 2.0)[:1200])


def test_lag_zero_counts_every_sample_and_the_design_checks_its_knobs():
    walk = np.random.default_rng(3).standard_normal((4, 1000)).cumsum(axis=1)  # increments a random walk
    assert np.all(BankDesign(colour_lag_s=0.0).honest(walk.cumsum(axis=1), 1e-3) == walk.cumsum(axis=1))
    assert np.all(evidence_factor(walk.cumsum(axis=1), 100, 2.0)[:, -1] > 20.0)
    with pytest.raises(ValueError, match="colour_z"):
        BankDesign(colour_z=-1.0)
    with pytest.raises(ValueError, match="colour_lag_s"):
        BankDesign(colour_lag_s=-0.01)


def test_a_coloured_lead_is_divided_by_its_colour():
    """decide() on a hand-made bank of 1000 samples where K_int gains on "none" and on every
    other fault, its leak moved 0.3 L/min. Gains of 0.1 nats per sample with independent noise
    (sd 0.3): the alarm stands at a 50-nat confirmation and K_int is named, at the honest size
    as without it. The same mean gain carried by an AR(1) of coefficient 0.95 and sd 1.6 (a
    model-form error's gain, correlated over 20 ms): the raw lead passes 50 nats but its honest size does not, and the
    alarm is withdrawn."""
    L, names = 1000, tuple(BANK)
    rng = np.random.default_rng(11)
    free = np.zeros((1, len(names), L))
    free[0, names.index("K_int")] = 0.3 * K_PER_LPM

    def bank(gain):
        ll = np.zeros((1, len(names), L))
        ll[0, [names.index(h) for h in names if h not in ("none", "K_int")]] = np.cumsum(gain) / 2
        ll[0, names.index("K_int")] = np.cumsum(gain)
        return BankResult(k0=np.array([1000]), loglik=ll, free=free, free_sd=np.ones((1, len(names), L)),
                          healthy=np.zeros((1, len(names))), n_valid=np.array([L]), names=names,
                          start=np.full((1, len(names)), 1000))

    margin = margin_for(0.01)
    white = 0.1 + 0.3 * rng.standard_normal(L)
    d = decide(bank(white), 0, 1600, margin, confirm=50.0, dt=1e-3)
    assert d.standing.confirmed and d.naming.hypothesis == "K_int"
    assert d.standing.lead_max == pytest.approx(decide(bank(white), 0, 1600, margin, confirm=50.0).standing.lead_max)
    slow = 0.1 + 0.5 * ar1(0.95, 1, L, seed=12)[0]
    raw = decide(bank(slow), 0, 1600, margin, confirm=50.0)
    assert raw.standing.lead_max > 50.0
    honest = decide(bank(slow), 0, 1600, margin, confirm=50.0, dt=1e-3)
    assert not honest.standing.confirmed and honest.naming.hypothesis is None
