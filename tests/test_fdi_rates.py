"""fdi.rates: the exact binomial intervals and the verdicts the tune gives its targets."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import beta, binom

from fdi import rates


@pytest.mark.parametrize("k, n", [(0, 46), (41, 46), (43, 46), (46, 46), (2, 1500), (190, 200)])
def test_interval_is_clopper_pearson_from_the_beta_quantiles(k, n):
    """The interval is Clopper-Pearson's: low = Beta(k, n - k + 1) at 2.5 %, high = Beta(k + 1,
    n - k) at 97.5 % (0 and 1 at the ends), written out here from its definition."""
    low = 0.0 if k == 0 else beta.ppf(0.025, k, n - k + 1)
    high = 1.0 if k == n else beta.ppf(0.975, k + 1, n - k)
    assert rates.interval(k, n) == pytest.approx((low, high), rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("n", [20, 46, 200])
def test_interval_covers_the_true_rate_in_at_least_95_percent_of_monte_carlos(n):
    """Exact coverage, summed over every outcome k of n runs: for any true rate p the interval holds
    p with probability >= 95 % (the normal approximation's does not near p = 0.95)."""
    ci = np.array([rates.interval(k, n) for k in range(n + 1)])
    for p in np.r_[np.linspace(0.005, 0.995, 199), 0.95, 0.99]:
        covers = (ci[:, 0] <= p) & (p <= ci[:, 1])
        assert binom.pmf(np.arange(n + 1), n, p)[covers].sum() >= 0.95 - 1e-12


def test_verdicts_of_the_tune_figures():
    """41 of 46 (89 %) and 43 of 46 cannot be told from 95 %; 30 of 46 can; 197 of 200 shows it (196 does not);
    a false-alarm rate needs about 370 clean runs to be shown below 1 %."""
    assert rates.verdict(41, 46, 0.95) == rates.verdict(43, 46, 0.95) == "undecided"
    assert rates.verdict(30, 46, 0.95) == "not met"
    assert rates.verdict(197, 200, 0.95) == "met" and rates.verdict(196, 200, 0.95) == "undecided"
    assert rates.verdict(0, 345, 0.01, at_least=False) == "undecided"
    assert rates.verdict(0, 400, 0.01, at_least=False) == "met"
    assert rates.verdict(40, 400, 0.01, at_least=False) == "not met"
    assert rates.verdict(0, 0, 0.95) == "undecided" and np.isnan(rates.interval(0, 0)).all()


def test_runs_to_show_is_the_first_n_whose_clean_interval_clears_the_target():
    n = rates.runs_to_show(0.95)
    assert n == 72
    assert rates.verdict(n, n, 0.95) == "met" and rates.verdict(n - 1, n - 1, 0.95) == "undecided"


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 3000), frac=st.floats(0.0, 1.0), target=st.floats(0.01, 0.99))
def test_interval_holds_the_point_rate_and_the_verdict_agrees_with_it(n, frac, target):
    """For any k of n: low <= k / n <= high within [0, 1]; 'met' (at least) implies k / n >= target,
    'not met' implies k / n < target, and the 'at most' verdicts mirror them."""
    k = int(round(frac * n))
    low, high = rates.interval(k, n)
    assert 0.0 <= low <= k / n <= high <= 1.0
    v = rates.verdict(k, n, target)
    assert v in rates.VERDICTS
    assert (v != "met" or k / n >= target) and (v != "not met" or k / n < target)
    w = rates.verdict(k, n, target, at_least=False)
    assert (w != "met" or k / n <= target) and (w != "not met" or k / n > target)
