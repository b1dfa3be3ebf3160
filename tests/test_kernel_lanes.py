"""The lane kernel (sam.dynamics.step_lanes) computes what the step did before it: the frozen copy
of that step (benchmarks/kernel_before.py, one run per loop iteration, branched) and the lane
kernel agree to the last bit under every scheme and sub-step count, on end stops, on the rails,
at the cavitation floor, with leak faults and with every optional effect; the flags are the same.

The last bit needs the Stribeck exponential (sam.simd.exp) to be libm's: it is glibc's algorithm,
and glibc is what the scalar kernel called on Linux x86-64. Elsewhere (another libm) the two
kernels differ in that exponential's last bit, and a chamber resting on a rail may then rest
within DP_CONDUCTANCE_MIN / 4 = 0.25 Pa of it on another side: there the comparison is skipped."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numba
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import sam
from sam import P, S
from sam.constants import LPM
from sam.simd import exp, quot

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import kernel_before  # noqa: E402  (the step before the lane kernel, frozen)

PLANT = sam.load_plant()
DT = 1e-3

def _libm_is_glibcs() -> bool:
    """math.exp is glibc's on this platform (sam.simd.exp is, bit for bit, over 1e5 draws)."""
    xs = np.random.default_rng(0).uniform(-750.0, 0.0, 100_000)
    return bool(np.array_equal(_exps(xs), np.array([math.exp(x) for x in xs])))


@numba.njit(cache=True)
def _exp(x):
    return exp(x)


@numba.njit(cache=True)
def _exps(xs):
    out = np.empty_like(xs)
    for i in range(xs.shape[0]):
        out[i] = exp(xs[i])
    return out


GLIBC = _libm_is_glibcs()
same_libm = pytest.mark.skipif(not GLIBC, reason="the scalar kernel's libm exp is not glibc's here")


def _batch(n: int, seed: int, faults: bool = False, effects: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """n parameter rows over Table 1's box, loads 0-800 kg, starting on or near either stop; with
    ``faults`` leak faults up to Table 5's 5.27e-9, with ``effects`` every optional effect of
    sam.params.Effects. Returns (params, x0)."""
    rng = np.random.default_rng(seed)
    params = np.tile(PLANT.vector(), (n, 1))
    box = {"offset": (-0.05, 0.05), "Q_N_PA": (15 * LPM, 35 * LPM), "dp_N_PA": (5e5, 40e5),
           "Q_N_BT": (15 * LPM, 35 * LPM), "dp_N_BT": (5e5, 40e5), "B_eff": (3e8, 1.2e9), "b": (2000.0, 5000.0),
           "m_L": (0.0, 800.0)}
    if faults:
        box |= {"K_int": (0.0, 5.27e-9), "K_extA": (0.0, 5.27e-9), "K_extB": (0.0, 5.27e-9)}
    if effects:
        box |= {"lap": (-0.02, 0.02), "R_supply": (0.0, 2e10), "Q_sat": (20 * LPM, 60 * LPM),
                "air_fraction": (0.0, 0.02), "C_hose": (0.0, 1e-13), "k_fric_p": (0.0, 2e-6),
                "K_bypass": (0.0, 1e-13)}
    for name, (lo, hi) in box.items():
        params[:, P[name]] = rng.uniform(lo, hi, n)
    x0 = sam.initial_state(params, rng.choice([0.0, 0.005, 0.2, 0.43], n))
    return params, x0


def _states(res) -> np.ndarray:
    return np.stack([res[c] for c in S.__members__])


def _input(n_steps: int) -> np.ndarray:
    """Full opening either way, onto both stops, a slow reversal and the valve near null: the
    stops, the rails, the stiff chambers, the cavitation floor and the null leakage's band."""
    t = np.arange(n_steps) * DT
    return np.where(t < 0.5, 10.0, np.where(t < 1.2, -10.0, np.where(t < 1.6, 4.0 * np.sin(9 * t), 0.02)))


@same_libm
@pytest.mark.parametrize("scheme", tuple(sam.SCHEMES))
@pytest.mark.parametrize("substeps", [1, 3])
@pytest.mark.parametrize("kind", ["paper", "faults", "effects"])
def test_the_lane_kernel_is_the_step_before_it(scheme, substeps, kind):
    """36 runs (a block of 32 and a part block) for 2 s: every state at every step is the frozen
    step's to the last bit, the cavitation flags too; the runs meet both stops."""
    params, x0 = _batch(36, seed=len(kind) * 7 + substeps, faults=kind != "paper", effects=kind == "effects")
    u = _input(2000)
    new = sam.simulate_batch(params, u, DT, x0=x0, substeps=substeps, scheme=scheme)
    old, flags = kernel_before.simulate_batch(params, u, DT, x0=x0, substeps=substeps, scheme=scheme)
    a, b = _states(new), _states(old)
    assert np.array_equal(a, b)
    assert np.array_equal(new.cavitated, (flags & sam.dynamics.FLAG_CAVITATION) != 0)
    assert np.any(b[S.x] == 0.0) and np.any(b[S.x] == sam.stroke_ends(params)[:, None])


def test_per_run_inputs_and_a_time_varying_load_reach_each_lane():
    """A per-run input (n_runs, n_steps) and a time-varying load mass reach the right lane of a block:
    run i of the batch is run i simulated alone."""
    params, x0 = _batch(35, seed=3, faults=True)
    rng = np.random.default_rng(4)
    u = rng.uniform(-6.0, 6.0, (35, 1)) * np.ones((1, 800))
    m_L = np.linspace(0.0, 700.0, 800)[None, :] + rng.uniform(0, 100, (35, 1))
    res = _states(sam.simulate_batch(params, u, DT, x0=x0, time_varying={"m_L": m_L}))
    for i in (0, 31, 32, 34):
        alone = _states(sam.simulate_batch(params[i], u[i], DT, x0=x0[i], time_varying={"m_L": m_L[i]}))
        assert np.array_equal(alone[:, 0], res[:, i])


@pytest.mark.parametrize("scheme", tuple(sam.SCHEMES))
def test_the_filters_step_is_the_simulators_for_sigma_points(scheme):
    """step_batch over 45 sigma points (one block and a part, the filter's 37-50 lanes), differing
    in faults and load as a filter's do, is the simulator's step of each, to the last bit."""
    params, x0 = _batch(45, seed=5, faults=True)
    res = sam.simulate_batch(params, np.full(300, 3.0), DT, x0=x0, scheme=scheme, substeps=2)
    s = np.ascontiguousarray(_states(res)[:, :, 150].T)
    nxt, _ = sam.step_batch(s, np.full(45, 3.0), params, DT, 2, int(sam.SCHEMES[scheme]))
    assert np.array_equal(nxt, _states(res)[:, :, 151].T)


@pytest.mark.parametrize("scheme", ["euler", "heun"])
def test_rows_kept_in_lane_blocks_step_as_rows_do(scheme):
    """45 rows kept in lane blocks from step to step (the filter's sigma points, fdi.kernel): new
    states, inputs, leaks, load masses and notch flows written into their lanes at each step, and
    step_blocks deriving again the constants those parameters feed (derived_parts), give
    step_batch's rows to the last bit, step after step."""
    params, state = _batch(45, seed=7, faults=True)
    s, u, p, d, flags = sam.lane_blocks(params)
    changed = np.array([P.K_int, P.m_L, P.Q_N_PA, P.p_S])
    geometry, machine = sam.derived_parts(changed)
    assert (geometry, machine) == (False, True)
    assert sam.derived_parts(np.array([P.L_1])) == (True, False)
    assert sam.derived_parts(np.array([P.K_extA, P.p_S, P.F_d])) == (False, False)
    rng = np.random.default_rng(8)
    for _ in range(30):
        uk = rng.uniform(-10.0, 10.0, 45)
        params[:, changed] *= rng.uniform(0.9, 1.1, (45, len(changed)))
        for i in range(45):
            b, j = sam.block_lane(i)
            s[b, :, j], u[b, j], p[b, changed, j] = state[i], uk[i], params[i, changed]
        sam.step_blocks(s, u, p, d, DT, flags, 45, 2, int(sam.SCHEMES[scheme]), geometry, machine)
        state, _ = sam.step_batch(state, uk, params, DT, 2, int(sam.SCHEMES[scheme]))
        lanes = np.array([s[sam.block_lane(i)[0], :, sam.block_lane(i)[1]] for i in range(45)])
        assert np.array_equal(lanes, state)


@settings(max_examples=200, deadline=None)
@given(x=st.one_of(st.floats(-800.0, 800.0), st.sampled_from([0.0, -0.0, -745.2, -708.5, 709.7, -1e-300,
                                                             math.inf, -math.inf, math.nan])))
def test_the_vectorisable_exponential_is_libms(x):
    """sam.simd.exp, the Stribeck curve's exponential, is glibc's exp to the last bit over the
    whole range (subnormal results, underflow to 0, overflow to inf, NaN kept); on another libm,
    within 1 ulp of it."""
    got, want = _exp(x), math.exp(x) if x < 709.8 else math.inf
    if math.isnan(x):
        assert math.isnan(got)
    elif GLIBC or want == 0.0 or math.isinf(want):
        assert got == want
    else:
        assert abs(got - want) <= math.ulp(want)


def test_the_single_precision_exponential_is_within_two_ulp():
    """The float32 exponential (the GSA's single-precision kernel) is within 2 float32 ulp of the
    exact value over the range a Stribeck curve uses (1.14 at worst, measured), 0 below float32's underflow."""
    xs = np.concatenate([np.linspace(-110.0, 0.0, 200_001), [-150.0, -104.0, 0.0, 1e-30]]).astype(np.float32)
    got = _exps(xs).astype(np.float64)
    want = np.exp(xs.astype(np.float64))
    ulp = np.spacing(want.astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(got - want) <= 2.0 * ulp)


@numba.njit(cache=True, error_model="numpy")
def _quots(a, b, out):
    for i in range(np.uint64(len(a))):  # vectorised, as in the lane loops
        out[i] = quot(a[i], b[i])
    return out


def test_quot_divides_float64_exactly_and_float32_within_two_ulp():
    """sam.simd.quot: float64 is an IEEE division, bit for bit; float32 may use the reciprocal
    estimate and a Newton step: within 2 float32 ulp of the exact quotient (1.47 at worst,
    measured), over quotients spanning 40 decades."""
    rng = np.random.default_rng(8)
    a = rng.uniform(-1.0, 1.0, 200_000) * 10.0 ** rng.uniform(-15, 15, 200_000)
    b = rng.uniform(0.1, 1.0, 200_000) * 10.0 ** rng.uniform(-15, 15, 200_000)
    np.testing.assert_array_equal(_quots(a, b, np.empty_like(a)), a / b)
    a32, b32 = a.astype(np.float32), b.astype(np.float32)
    got = _quots(a32, b32, np.empty_like(a32)).astype(np.float64)
    want = a32.astype(np.float64) / b32.astype(np.float64)
    ulp = np.spacing(np.abs(want).astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(got - want) <= 2.0 * ulp)
    # an infinite dividend or a zero divisor (a run already gone wrong) stays non-finite, in the
    # vector body and in the scalar remainder alike (37 values: 2 x 16 lanes + 5)
    a32 = np.array([1.0, np.inf, 0.0, -1.0] * 9 + [np.inf], np.float32)
    b32 = np.array([0.0, 2.0, 0.0, -0.0] * 9 + [3.0], np.float32)
    assert not np.isfinite(_quots(a32, b32, np.empty_like(a32))).any()
    # an infinite divisor gives 0 (IEEE) or NaN (the reciprocal's Newton step): never a wrong number
    q = _quots(np.full(37, 1.0, np.float32), np.full(37, np.inf, np.float32), np.empty(37, np.float32))
    assert np.all((q == 0.0) | np.isnan(q))


def test_single_precision_follows_double_within_its_rounding():
    """The float32 kernel (the GSA's option) follows the float64 one over 2 s of the paper's batch:
    pressures within 0.5 % of the supply, velocity within 1 % of its range away from the end
    stops (where the step sets v to zero, rounding can move an arrival by one step)."""
    params, x0 = _batch(40, seed=6)
    u = _input(2000)
    a = sam.simulate_batch(params, u, DT, x0=x0, record_every=10)
    b = sam.simulate_batch(params, u, DT, x0=x0, record_every=10, precision="float32")
    for c in ("p_A", "p_B"):
        assert np.max(np.abs(a[c] - b[c])) < 0.005 * PLANT.vector()[P.p_S]
    x_end = sam.stroke_ends(params)[:, None]
    free = (np.minimum(a["x"], b["x"]) > 1e-3) & (np.maximum(a["x"], b["x"]) < x_end - 1e-3)
    assert np.count_nonzero(free) > free.size // 2  # most of the batch is off the stops
    assert np.max(np.abs(a["v"] - b["v"])[free]) < 0.01 * np.ptp(a["v"])
