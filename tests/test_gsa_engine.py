"""Numbers of the Sobol' engine: test functions with analytic indices, SALib agreement,
bootstrap correctness and memory, and the validation at its boundary."""

from __future__ import annotations

import copy
import subprocess
import sys
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from gsa import (
    ESTIMATORS,
    GSAError,
    NonFiniteWarning,
    Problem,
    SamplingWarning,
    ZeroVarianceWarning,
    analyze,
    bootstrap_sobol,
    resample_counts,
    saltelli_design,
    sobol_indices,
)
from gsa import testfunctions as tf
from gsa.design import Samples
from gsa.estimators import SobolStatistic

REPO = Path(__file__).resolve().parents[1]
G_A = (0.0, 1.0, 4.5, 9.0, 99.0, 99.0)


def assert_recovers(result, S1_true, ST_true, tol=0.02, j=0):
    """Each analytic value inside its CI and within tol of the estimate."""
    for name, est, lo, hi, true in (
        ("S1", result.S1[:, j], result.S1_lo[:, j], result.S1_hi[:, j], S1_true),
        ("ST", result.ST[:, j], result.ST_lo[:, j], result.ST_hi[:, j], ST_true),
    ):
        err = np.abs(est - true)
        assert np.all(err <= tol), f"{name}: estimate {est} vs analytic {true} (|err| {err})"
        inside = (lo <= true) & (true <= hi)
        assert inside.all(), f"{name}: analytic {true} outside CI [{lo}, {hi}]"


# -- test functions ------------------------------------------------------------------


@pytest.fixture(scope="module")
def ishigami_runs():
    problem = tf.ishigami_problem()
    design = saltelli_design(problem, 2**13, seed=11, with_BA=True)
    return problem, design, tf.ishigami(design.X)


def test_ishigami_analytic_values_are_the_published_ones():
    S1, ST = tf.ishigami_indices(7.0, 0.1)
    np.testing.assert_allclose(S1, [0.3139, 0.4424, 0.0], atol=5e-5)
    np.testing.assert_allclose(ST, [0.5576, 0.4424, 0.2437], atol=5e-5)


@pytest.mark.parametrize("estimator", ["saltelli2010-jansen", "janon", "azzini"])
def test_ishigami_recovered_within_ci_and_0_02(ishigami_runs, estimator):
    problem, design, Y = ishigami_runs
    result = analyze(problem, design, Y, estimator=estimator, n_boot=1000, seed=5)
    assert_recovers(result, *tf.ishigami_indices())


def test_ishigami_bca_intervals_also_cover(ishigami_runs):
    problem, design, Y = ishigami_runs
    result = analyze(problem, design, Y, n_boot=1000, ci="bca", seed=5)
    assert_recovers(result, *tf.ishigami_indices())


def test_paper_estimator_recovers_ishigami_ranking(ishigami_runs):
    problem, design, Y = ishigami_runs
    result = analyze(problem, design, Y, estimator="saltelli2002", n_boot=200, seed=5)
    assert list(result.ranking("ST")[:, 0]) == [0, 1, 2]  # x1 > x2 > x3
    assert list(result.ranking("S1")[:, 0]) == [1, 0, 2]  # x2 > x1 > x3
    S1, ST = tf.ishigami_indices()
    assert np.all(np.abs(result.S1[:, 0] - S1) <= 0.05)
    assert np.all(np.abs(result.ST[:, 0] - ST) <= 0.05)


def test_paper_estimator_is_eqs_33_to_38_as_printed():
    """Eqs. (33)-(38) written out by hand with X1 = B, X2 = A, X3i = AB_i."""
    problem = tf.ishigami_problem()
    design = saltelli_design(problem, 2**8, seed=2)
    Y = tf.ishigami(design.X)
    s = design.split(Y)
    f1, f2 = s.f_B[:, 0], s.f_A[:, 0]
    f1_sq = np.mean(f1 * f2)  # (35)
    f2_sq = np.mean(f2) ** 2  # (36)
    V1 = np.mean(f1**2) - f1_sq  # (33)
    V2 = np.mean(f2**2) - f2_sq  # (34)
    for i in range(3):
        f3 = s.f_AB[i, :, 0]
        S_i = (np.mean(f1 * f3) - f1_sq) / V1  # (37)
        ST_i = 1 - (np.mean(f2 * f3) - f2_sq) / V2  # (38)
        est = sobol_indices(s, "saltelli2002")
        assert est["S1"][i, 0] == pytest.approx(S_i, rel=1e-12, abs=1e-14)
        assert est["ST"][i, 0] == pytest.approx(ST_i, rel=1e-12, abs=1e-14)


def test_ishigami_interactions_and_ranking(ishigami_runs):
    problem, design, Y = ishigami_runs
    result = analyze(problem, design, Y, n_boot=0)
    S1, _ = tf.ishigami_indices()
    assert result.interactions[0] == pytest.approx(1 - S1.sum(), abs=0.02)  # 0.2437
    assert result.ranked_factors("y0", by="ST") == ["x1", "x2", "x3"]
    assert result.ranked_factors(0, by="S1") == ["x2", "x1", "x3"]
    assert np.isnan(result.S1_lo).all()  # n_boot = 0: no intervals


def test_sobol_g_recovered_within_ci_and_0_02():
    problem = tf.sobol_g_problem(len(G_A))
    design = saltelli_design(problem, 2**13, seed=3)
    result = analyze(problem, design, tf.sobol_g(design.X, G_A), n_boot=1000, seed=1)
    assert_recovers(result, *tf.sobol_g_indices(G_A))


def test_second_order_of_sobol_g():
    """S_ij = V_i V_j / V for the G function; the pair (x1, x2) carries most."""
    problem = tf.sobol_g_problem(4)
    a = G_A[:4]
    design = saltelli_design(problem, 2**13, seed=4, second_order=True)
    result = analyze(problem, design, tf.sobol_g(design.X, a), n_boot=200, seed=1)
    Vi = 1 / (3 * (1 + np.asarray(a)) ** 2)
    V = np.prod(1 + Vi) - 1
    for i in range(4):
        for j in range(i + 1, 4):
            assert result.S2[i, j, 0] == pytest.approx(Vi[i] * Vi[j] / V, abs=0.02)
            assert result.S2_lo[i, j, 0] <= result.S2[i, j, 0] <= result.S2_hi[i, j, 0]
    assert np.isnan(result.S2[1, 0, 0]) and np.isnan(result.S2[0, 0, 0])


def test_linear_additive_model_with_mixed_distributions():
    """sum S1 = 1 and S1 = ST (within CIs) for y = sum c_i x_i, any marginals."""
    problem = Problem(
        names=("u", "logu", "n", "tn"),
        bounds=((1.0, 3.0), (0.1, 10.0), (2.0, 0.5), (-1.0, 1.5, 0.0, 1.0)),
        dists=("uniform", "loguniform", "normal", "truncnormal"),
    )
    c = np.array([1.0, 0.3, -2.0, 1.5])
    var = np.array(
        [
            stats.uniform(1, 2).var(),
            stats.loguniform(0.1, 10).var(),
            0.25,
            stats.truncnorm(-1, 1.5, loc=0, scale=1).var(),
        ]
    )
    design = saltelli_design(problem, 2**13, seed=9)
    result = analyze(problem, design, tf.linear(design.X, c), n_boot=1000, seed=2)
    S_true = tf.linear_indices(c, var)
    assert result.S1[:, 0].sum() == pytest.approx(1.0, abs=0.02)
    assert result.interactions[0] == pytest.approx(0.0, abs=0.02)
    np.testing.assert_allclose(result.S1[:, 0], S_true, atol=0.02)
    for i in range(4):
        assert result.S1_lo[i, 0] <= result.ST[i, 0] <= result.S1_hi[i, 0]
        assert result.ST_lo[i, 0] <= result.S1[i, 0] <= result.ST_hi[i, 0]


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    terms=st.lists(
        st.tuples(
            st.floats(-5, 5, allow_nan=False),  # c_i
            st.floats(-10, 10, allow_nan=False),  # lower bound
            st.floats(0.1, 10, allow_nan=False),  # width
        ),
        min_size=1,
        max_size=5,
    )
)
def test_property_linear_models_give_c2_var_shares(terms):
    c = np.array([t[0] for t in terms])
    var = np.array([t[2] ** 2 / 12 for t in terms])
    if (c**2 * var).sum() < 1e-6 * max(1.0, (c**2).max()):
        return  # (nearly) constant model: indices undefined
    problem = Problem(
        names=tuple(f"x{i}" for i in range(len(terms))),
        bounds=tuple((lo, lo + w) for _, lo, w in terms),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # N = 2^12: no sampling warning expected
        design = saltelli_design(problem, 2**12, seed=0)
    est = sobol_indices(design.split(tf.linear(design.X, c)))
    np.testing.assert_allclose(est["S1"][:, 0], tf.linear_indices(c, var), atol=0.05)


# -- agreement with SALib (test-only dependency) ---------------------------------------------


def _salib_order(design):
    """Permutation taking our run order [A; B; AB..; BA..] to SALib's
    per-base-row order (A, AB_1..AB_G, [BA_1..BA_G], B)."""
    blocks = [0] + list(range(2, design.n_blocks)) + [1]
    return (np.array(blocks)[None, :] * design.N + np.arange(design.N)[:, None]).ravel()


@pytest.mark.parametrize("second_order", [False, True])
def test_matches_salib_sobol_analyze_to_1e_10(second_order):
    salib_sobol = pytest.importorskip("SALib.analyze.sobol")
    problem = tf.ishigami_problem()
    design = saltelli_design(problem, 2**10, seed=5, second_order=second_order)
    Y = np.c_[tf.ishigami(design.X), tf.ishigami(design.X) ** 2 + 3e3 * design.X[:, :1] + 1e4]
    ours = analyze(problem, design, Y, n_boot=0)
    perm = _salib_order(design)
    spec = {"num_vars": 3, "names": list(problem.names), "bounds": [list(b) for b in problem.bounds]}
    for j in range(Y.shape[1]):
        S = salib_sobol.analyze(
            spec, Y[perm, j], calc_second_order=second_order, num_resamples=10, seed=1
        )
        np.testing.assert_allclose(ours.S1[:, j], S["S1"], rtol=0, atol=1e-10)
        np.testing.assert_allclose(ours.ST[:, j], S["ST"], rtol=0, atol=1e-10)
        if second_order:
            np.testing.assert_allclose(ours.S2[:, :, j], S["S2"], rtol=0, atol=1e-10)


def test_salib_sample_matrix_through_our_estimator():
    """The other direction: SALib's own sample, split into our blocks."""
    salib_sample = pytest.importorskip("SALib.sample.sobol")
    salib_sobol = pytest.importorskip("SALib.analyze.sobol")
    spec = {"num_vars": 3, "names": ["x1", "x2", "x3"], "bounds": [[-np.pi, np.pi]] * 3}
    X = salib_sample.sample(spec, 2**9, calc_second_order=False, seed=3)
    y = tf.ishigami(X)[:, 0]
    rows = y.reshape(2**9, 5)  # per base row: A, AB_1, AB_2, AB_3, B
    s = Samples(rows[:, :1], rows[:, 4:5], rows[:, 1:4].T[:, :, None], None)
    ours = sobol_indices(s)
    S = salib_sobol.analyze(spec, y, calc_second_order=False, num_resamples=10, seed=1)
    np.testing.assert_allclose(ours["S1"][:, 0], S["S1"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(ours["ST"][:, 0], S["ST"], rtol=0, atol=1e-10)


# -- bootstrap --------------------------------------------------------------------------------


def test_matrix_product_bootstrap_equals_resampling_rows():
    """C @ Q gives exactly the estimates of explicitly resampled rows (raw estimator)."""
    problem = tf.ishigami_problem()
    design = saltelli_design(problem, 2**8, seed=8)
    s = design.split(tf.ishigami(design.X))
    stat = SobolStatistic("saltelli2002", 3)
    res = bootstrap_sobol(s, stat, n_boot=200, seed=4)
    counts = resample_counts(design.N, 200, 4)
    reps = []
    for c in counts:
        rows = np.repeat(np.arange(design.N), c)
        rs = Samples(s.f_A[rows], s.f_B[rows], s.f_AB[:, rows], None)
        reps.append(sobol_indices(rs, "saltelli2002")["S1"][:, 0])
    lo, hi = np.quantile(np.array(reps), [0.025, 0.975], axis=0)
    np.testing.assert_allclose(res.lo["S1"][:, 0], lo, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.hi["S1"][:, 0], hi, rtol=0, atol=1e-12)


def test_bootstrap_is_seeded_and_independent_of_memory_budget():
    problem = tf.ishigami_problem()
    design = saltelli_design(problem, 2**9, seed=8)
    X = design.X
    Y = np.c_[tf.ishigami(X), X @ np.arange(1.0, 4.0), np.sin(X).sum(1)[:, None] ** 2]
    args = dict(n_boot=300, ci="bca", seed=7)
    big = analyze(problem, design, Y, memory_budget=2**30, **args)
    small = analyze(problem, design, Y, memory_budget=2**18, **args)  # one output per block
    again = analyze(problem, design, Y, memory_budget=2**30, **args)
    for name in ("S1", "S1_lo", "S1_hi", "ST", "ST_lo", "ST_hi"):
        np.testing.assert_allclose(getattr(small, name), getattr(big, name), rtol=1e-12, atol=1e-13)
        np.testing.assert_array_equal(getattr(again, name), getattr(big, name))
    other = analyze(problem, design, Y, memory_budget=2**30, n_boot=300, ci="bca", seed=8)
    assert not np.array_equal(other.S1_lo, big.S1_lo)


def test_bootstrap_peak_memory_stays_under_budget():
    """N=2^12, k=7, M=400: full quantities would need ~210 MB; budget 32 MB."""
    k, M, budget = 7, 400, 32 * 2**20
    problem = Problem(names=tuple(f"p{i}" for i in range(k)), bounds=((0, 1),) * k)
    design = saltelli_design(problem, 2**12, seed=1)
    W = np.random.default_rng(0).standard_normal((k, M))
    Y = design.X @ W + np.sin(3 * design.X) @ W**2
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        result = analyze(problem, design, Y, n_boot=1000, seed=1, memory_budget=budget)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak - base < budget * 1.15, f"peak extra memory {(peak - base) / 2**20:.0f} MiB"
    assert np.isfinite(result.S1_lo).all()


def test_float32_product_moves_bounds_negligibly(ishigami_runs):
    problem, design, Y = ishigami_runs
    Y2 = np.c_[Y, 1e7 + 1e4 * Y]  # a "pressure": large mean, small spread
    f64 = analyze(problem, design, Y2, n_boot=500, seed=1)
    f32 = analyze(problem, design, Y2, n_boot=500, seed=1, precision="float32")
    np.testing.assert_array_equal(f32.S1, f64.S1)  # point estimates stay float64
    for name in ("S1_lo", "S1_hi", "ST_lo", "ST_hi"):
        np.testing.assert_allclose(getattr(f32, name), getattr(f64, name), rtol=0, atol=1e-5)


# -- zero variance, NaN, warnings, validation -----------------------------------------------


def test_constant_output_gives_nan_with_one_warning_others_unchanged(ishigami_runs):
    problem, design, Y = ishigami_runs
    Y3 = np.c_[Y, np.full(len(Y), 5.0), 2 * Y]
    with pytest.warns(ZeroVarianceWarning) as record:
        result = analyze(problem, design, Y3, n_boot=100, seed=1, output_names=["a", "flat", "b"])
    assert len([w for w in record if issubclass(w.category, ZeroVarianceWarning)]) == 1
    assert "'flat'" in str(record[0].message) and "1 of 3" in str(record[0].message)
    for name in ("S1", "S1_lo", "S1_hi", "ST", "ST_lo", "ST_hi"):
        assert np.isnan(getattr(result, name)[:, 1]).all()
    single = analyze(problem, design, Y, n_boot=100, seed=1)
    np.testing.assert_allclose(result.S1[:, 0], single.S1[:, 0], rtol=1e-12)
    np.testing.assert_allclose(result.ST_hi[:, 2], single.ST_hi[:, 0], rtol=1e-12)
    assert result.constant.tolist() == [False, True, False]


def test_a_tiny_but_real_spread_is_computed_and_rounding_is_not():
    """A relative spread of 1e-12 was declared constant (NaN); SALib and scipy compute it. The
    tolerance is 10 ulps of the output (gsa.estimators.CONSTANT_ULPS): below it, rounding."""
    salib_sobol = pytest.importorskip("SALib.analyze.sobol")
    problem = tf.ishigami_problem()
    design = saltelli_design(problem, 2**10, seed=5)
    g = tf.ishigami(design.X).ravel()
    tiny = 1.0 + 0.9e-12 * (g - g.min()) / np.ptp(g)  # spread 0.9e-12 of its magnitude: ~4000 ulps
    ulps = 1.0 + np.spacing(1.0) * np.round(4 * (g - g.min()) / np.ptp(g))  # 5 levels of rounding
    with pytest.warns(ZeroVarianceWarning, match="1 of 2 outputs"):
        result = analyze(problem, design, np.c_[tiny, ulps], n_boot=0, output_names=["tiny", "ulps"])
    assert result.constant.tolist() == [False, True]
    exact = analyze(problem, design, g, n_boot=0)
    np.testing.assert_allclose(result.S1[:, 0], exact.S1[:, 0], atol=2e-3)
    S = salib_sobol.analyze({"num_vars": 3, "names": list(problem.names), "bounds": [list(b) for b in problem.bounds]},
                            tiny[_salib_order(design)], calc_second_order=False, num_resamples=10, seed=1)
    # to within the values' own quantisation (1 / 4000): both sum rounded differences of them
    np.testing.assert_allclose(result.S1[:, 0], S["S1"], atol=1e-4)
    np.testing.assert_allclose(result.ST[:, 0], S["ST"], atol=1e-4)


def test_nonfinite_outputs_refused_or_dropped_explicitly():
    problem = tf.ishigami_problem()
    design = saltelli_design(problem, 2**10, seed=1)
    Y = tf.ishigami(design.X)
    Y[[3, design.N + 3, 3 * design.N + 10]] = np.nan  # base samples 3 and 10
    with pytest.raises(GSAError, match=r"NaN/inf in 3 of 5120 runs") as err:
        analyze(problem, design, Y)
    assert "run 3 (A, sample 3): x1=" in str(err.value)
    with pytest.warns(NonFiniteWarning, match="dropped 2 of 1024 base samples"):
        result = analyze(problem, design, Y, n_boot=100, drop_nonfinite=True)
    assert result.N == 1022 and result.dropped_samples == 2
    assert np.isfinite(result.S1).all()


def test_non_power_of_two_warns_exactly_once():
    problem = tf.ishigami_problem()
    with pytest.warns(SamplingWarning) as record:
        saltelli_design(problem, 1000, seed=0)
    assert len(record) == 1
    assert "power of two" in str(record[0].message) and "N=1024" in str(record[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        saltelli_design(problem, 1024, seed=0)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(names=("a", "b"), bounds=((0, 1), (2, 1))), r"'b'.*lo=2, hi=1"),
        (dict(names=("a", "b"), bounds=((0, 1), (1, 1))), r"'b'.*lo=1, hi=1"),
        (dict(names=("a",), bounds=((0, 1),), dists=("gauss",)), r"'a'.*unknown distribution 'gauss'"),
        (dict(names=("a", "a"), bounds=((0, 1), (0, 1))), r"duplicate parameter name 'a'"),
        (dict(names=("a", ""), bounds=((0, 1), (0, 1))), r"parameter #2 needs a non-empty name"),
        (dict(names=(), bounds=()), r"at least one parameter"),
        (dict(names=("q",), bounds=((0, 1),), dists=("loguniform",)), r"'q'.*lo > 0, got lo=0"),
        (dict(names=("s",), bounds=((1, -2),), dists=("normal",)), r"'s'.*sd > 0, got sd=-2"),
        (dict(names=("t",), bounds=((3, 2, 0, 1),), dists=("truncnormal",)), r"'t'.*lo=3, hi=2"),
        # SALib's truncated-normal layout under "normal" was read as mean -0.5, sd 2
        (dict(names=("t",), bounds=((-0.5, 2, 0.5, 0.3),), dists=("normal",)),
         r"'t': normal needs bounds \(mean, sd\).*'truncnormal' with \(lo, hi, mean, sd\)"),
        (dict(names=("r",), bounds=((0, 1, 1.5),), dists=("triang",)), r"'r'.*peak's position c in \[0, 1\]"),
        (dict(names=("m",), bounds=((0, 0),), dists=("lognorm",)), r"'m'.*lognormal needs sigma > 0"),
        (dict(names=("w",), bounds=((1, 2),), dists=("weibull",)), r"'w'.*unknown distribution 'weibull'"),
        (dict(names=("a",), bounds=((0, float("nan")),)), r"'a'.*finite"),
        (dict(names=("a", "b"), bounds=((0, 1),)), r"bounds has 1 entries but there are 2"),
    ],
)
def test_problem_validation_names_parameter_and_value(kwargs, message):
    with pytest.raises(GSAError, match=message):
        Problem(**kwargs)


def test_design_validation():
    problem = tf.ishigami_problem()
    with pytest.raises(GSAError, match="N .* >= 2, got 1"):
        saltelli_design(problem, 1, seed=0)
    with pytest.raises(GSAError, match="seed"):
        saltelli_design(problem, 8, seed=-1)
    design = saltelli_design(problem, 8, seed=0)
    with pytest.raises(GSAError, match="needs the BA_i runs"):
        analyze(problem, design, tf.ishigami(design.X), estimator="azzini")
    with pytest.raises(GSAError, match="unknown estimator 'sobol'.*saltelli2010-jansen"):
        analyze(problem, design, tf.ishigami(design.X), estimator="sobol")
    with pytest.raises(GSAError, match="Y has 39 rows but the design has 40 runs"):
        analyze(problem, design, tf.ishigami(design.X)[:-1])
    assert set(ESTIMATORS) == {"saltelli2010-jansen", "janon", "azzini", "saltelli2002"}


def test_transform_applies_each_marginal():
    problem = Problem(
        names=("u", "l", "n", "t"),
        bounds=((2, 4), (1e-3, 1e-1), (5, 2), (-0.5, 0.5, 0, 1)),
        dists=("uniform", "loguniform", "normal", "truncnormal"),
    )
    X = problem.transform(np.array([[0.5] * 4, [0.0] * 4, [0.975] * 4]))
    np.testing.assert_allclose(X[0], [3.0, 1e-2, 5.0, 0.0], atol=1e-12)
    assert X[1, 0] == 2 and X[1, 1] == pytest.approx(1e-3) and X[1, 3] == pytest.approx(-0.5)
    assert np.isfinite(X[1, 2])  # U = 0 of an unbounded normal stays finite
    assert X[2, 2] == pytest.approx(5 + 2 * 1.959964, rel=1e-6)
    assert -0.5 <= X[2, 3] <= 0.5


@pytest.mark.parametrize("dist, bounds", [
    ("unif", [-1.0, 3.0]), ("logunif", [1e-3, 1e-1]), ("norm", [2.0, 0.5]),
    ("truncnorm", [-0.5, 2.0, 0.5, 0.3]), ("lognorm", [0.2, 0.4]), ("triang", [1.0, 3.0, 0.25]),
])
def test_salib_problems_mean_the_same_here(dist, bounds):
    """A SALib problem dict, its names and layouts, samples exactly as SALib samples it."""
    from SALib.util import scale_samples

    salib = {"num_vars": 2, "names": ["a", "b"], "bounds": [bounds, [0.0, 1.0]], "dists": [dist, "unif"],
             "outputs": ["y"]}
    problem = Problem.from_dict(salib)
    assert problem.dists[0] in ("uniform", "loguniform", "normal", "truncnormal", "lognormal", "triangular")
    U = np.random.default_rng(3).uniform(0.001, 0.999, (500, 2))
    np.testing.assert_allclose(problem.transform(U), scale_samples(U.copy(), copy.deepcopy(salib)), rtol=1e-12, atol=1e-12)
    assert Problem.from_dict(problem.to_salib()) == problem
    with pytest.raises(GSAError, match="num_vars is 3 but names lists 2"):
        Problem.from_dict({**salib, "num_vars": 3})


def test_lognormal_and_triangular_marginals():
    problem = Problem(names=("l", "t"), bounds=((0.5, 0.25), (2.0, 6.0, 0.75)), dists=("lognormal", "triangular"))
    X = problem.transform(np.array([[0.5, 0.0], [0.5, 1.0], [0.5, 0.75]]))
    assert X[0, 0] == pytest.approx(np.exp(0.5))  # the median of ln X ~ N(0.5, 0.25^2)
    assert (X[0, 1], X[1, 1]) == (2.0, 6.0) and X[2, 1] == pytest.approx(5.0)  # CDF 0.75 at the peak 2 + 0.75 * 4


def test_design_layout_and_groups():
    problem = Problem(names=("a", "b", "c"), bounds=((0, 1),) * 3, groups=("g1", "g2", "g1"))
    design = saltelli_design(problem, 16, seed=3, with_BA=True)
    assert problem.factor_names == ("g1", "g2") and design.G == 2
    assert design.block_names == ("A", "B", "AB_1", "AB_2", "BA_1", "BA_2")
    assert design.n_runs == 16 * 6
    U = design.U
    A, B = design.A, design.B
    np.testing.assert_array_equal(U[:16], A)
    np.testing.assert_array_equal(U[16:32], B)
    AB_1 = U[32:48]
    np.testing.assert_array_equal(AB_1[:, [0, 2]], B[:, [0, 2]])  # group g1 from B
    np.testing.assert_array_equal(AB_1[:, 1], A[:, 1])
    BA_2 = U[80:96]
    np.testing.assert_array_equal(BA_2[:, 1], A[:, 1])
    np.testing.assert_array_equal(BA_2[:, [0, 2]], B[:, [0, 2]])
    assert design.locate(50) == ("AB_2", 2)
    again = saltelli_design(problem, 16, seed=3, with_BA=True)
    np.testing.assert_array_equal(again.X, design.X)
    assert again.sha256 == design.sha256


def test_result_rows_and_csv(tmp_path, ishigami_runs):
    problem, design, Y = ishigami_runs
    result = analyze(
        problem, design, np.c_[Y, Y**2], n_boot=50, seed=1,
        output_names=["p_A", "p_A"], output_times=[0.1, 0.2],
    )
    rows = result.to_rows()
    assert len(rows) == 6
    assert rows[4] == {
        "output": "p_A", "time_s": 0.2, "parameter": "x2",
        **{c: float(getattr(result, c)[1, 1]) for c in ("S1", "S1_lo", "S1_hi", "ST", "ST_lo", "ST_hi")},
    }
    path = result.write_csv(tmp_path / "indices.csv")
    lines = path.read_text().splitlines()
    assert lines[0] == "output,time_s,parameter,S1,S1_lo,S1_hi,ST,ST_lo,ST_hi"
    assert lines[1].startswith("p_A,0.1,x1,")
    assert float(lines[1].split(",")[3]) == result.S1[0, 0]


def test_engine_does_not_import_sam():
    code = "import sys, gsa, gsa.runner, gsa.testfunctions; print('sam' in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True,
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"},
    )
    assert out.stdout.strip() == "False"
