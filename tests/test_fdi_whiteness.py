"""The evidence's honest size (fdi.whiteness, BankResult.colour in fdi.isolation.decide): white
innovations keep their evidence, an AR(1) sequence has its known integrated autocorrelation
time, the estimate is causal, and a lead made of coloured innovations does not confirm."""

from __future__ import annotations

import numpy as np
import pytest

from fdi.bank import BANK, CHANNELS, DESIGN, BankDesign, BankResult
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


def test_white_innovations_keep_their_evidence():
    """200 white sequences of 1000 samples (the bank's decision window at 1 kHz), lag 50: the
    estimate's mean is 1 within 0.03 and its spread that of white_spread within 15 %. At the
    design's lag (0.5 s) and z = 2, the factor of two white channels is 1 in >= 93 % of the
    sequences and averages below 1.05: white residuals keep today's evidence."""
    x = np.random.default_rng(32).standard_normal((200, 1000))
    tau = running_iat(x, 50)[:, -1]
    assert tau.mean() == pytest.approx(1.0, abs=0.03)
    assert tau.std() == pytest.approx(white_spread(1000, 50), rel=0.15)
    nu = np.stack([x, np.random.default_rng(33).standard_normal((200, 1000)), x], axis=-1)
    f = DESIGN.colour(nu, 1e-3)[:, -1]
    assert np.all(f >= 1.0) and (f == 1.0).mean() >= 0.93 and f.mean() < 1.05
    assert np.all(evidence_factor(nu, 50, (0, 1), 0.0) >= 1.0)


@pytest.mark.parametrize("rho", [0.5, 0.9])
def test_ar1_has_its_known_integrated_autocorrelation_time(rho):
    """AR(1) of coefficient rho: with a lag window far beyond its correlation length the estimate
    is (1 + rho) / (1 - rho) within 6 %; with Bartlett weights at lag M it is
    1 + 2 sum_j (1 - j / (M + 1)) rho^j within 6 %."""
    x = ar1(rho, 20, 40_000, seed=int(100 * rho))
    assert running_iat(x, 400)[:, -1].mean() == pytest.approx((1 + rho) / (1 - rho), rel=0.06)
    j = np.arange(1, 51)
    bartlett = 1.0 + 2.0 * np.sum((1.0 - j / 51.0) * rho ** j)
    assert running_iat(x, 50)[:, -1].mean() == pytest.approx(bartlett, rel=0.06)


def test_the_estimate_is_causal_and_counts_a_mean_as_colour():
    """Sample k uses samples up to k only (changing later ones changes nothing before); a
    constant bias b on white noise (taken about 0, as model error) gives about 1 + M b^2 / (1 + b^2)."""
    x = np.random.default_rng(7).standard_normal(2000)
    y = x.copy()
    y[1200:] += 5.0
    np.testing.assert_array_equal(running_iat(x, 50)[:1200], running_iat(y, 50)[:1200])
    b = 0.5
    tau = running_iat(np.random.default_rng(8).standard_normal((50, 5000)) + b, 50)[:, -1].mean()
    assert tau == pytest.approx(1.0 + 50 * b * b / (1 + b * b), rel=0.1)


def test_lag_zero_counts_every_sample_and_the_design_checks_its_knobs():
    nu = np.random.default_rng(3).standard_normal((4, 100, 3)).cumsum(axis=1)  # strongly coloured
    assert np.all(BankDesign(colour_lag_s=0.0).colour(nu, 1e-3) == 1.0)
    assert np.all(DESIGN.colour(nu, 1e-3)[:, -1] > 10.0)
    with pytest.raises(ValueError, match="colour_z"):
        BankDesign(colour_z=-1.0)
    with pytest.raises(ValueError, match="colour_channels"):
        BankDesign(colour_channels=("pC",))
    with pytest.raises(ValueError, match="colour_lag_s"):
        BankDesign(colour_lag_s=-0.01)
    assert set(DESIGN.colour_channels) <= set(CHANNELS)


def test_a_coloured_lead_is_divided_by_its_colour():
    """decide() on a hand-made bank where K_int leads "none" by 60 nats and every other fault by
    30, its leak moved 0.3 L/min: with white innovations (colour 1) the alarm stands at a 50-nat
    confirmation and K_int is named; with colour 3 (60 / 3 = 20 < 50) it is withdrawn, and the
    lead it reports is 20 nats (a fault is named only where its alarm stands)."""
    L, names = 12, tuple(BANK)
    ll = np.zeros((1, len(names), L))
    ll[0, [names.index(h) for h in names if h not in ("none", "K_int")]] = 30.0
    ll[0, names.index("K_int")] = 60.0
    free = np.zeros((1, len(names), L))
    free[0, names.index("K_int")] = 0.3 * K_PER_LPM

    def bank(colour):
        return BankResult(k0=np.array([1000]), loglik=ll, free=free, free_sd=np.ones((1, len(names), L)),
                          healthy=np.zeros((1, len(names))), n_valid=np.array([L]), names=names,
                          start=np.full((1, len(names)), 1000), colour=np.full((1, len(names), L), colour))

    margin = margin_for(0.01)
    white = decide(bank(1.0), 0, 1000, margin, confirm=50.0)
    assert white.standing.confirmed and white.naming.hypothesis == "K_int"
    coloured = decide(bank(3.0), 0, 1000, margin, confirm=50.0)
    assert not coloured.standing.confirmed
    assert coloured.standing.lead_max == pytest.approx(20.0)
    assert coloured.naming.hypothesis is None  # named only where the alarm is confirmed
