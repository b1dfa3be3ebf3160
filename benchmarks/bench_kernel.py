"""Benchmark: the simulation kernel against what a competent user writes, side by side in one run.

The paper's batch: parameter sets of the Table 1 box, each 4 s at T = 1 ms under 2.5 V, keeping
p_A, p_B and v every 10 ms. Timed, interleaved over the repeats (medians, and the ratios of each
round's pairs):

(a) numpy: Eq. (22) written with numpy over a batch of runs (one thread, as numpy runs), the same
    model as sam's step: the four metering edges, the null leakage, the leak faults, the chambers,
    the spool, the boom and LuGre friction, the stiff chambers' semi-implicit update, the end stops
    and the cavitation floor. Its result is checked against sam's (printed);
(b) before: the step before the lane kernel (benchmarks/kernel_before.py): one run per loop
    iteration, scalar and branched, numba, both threads;
(c) lanes: sam.simulate_batch, blocks of sam.dynamics.LANES runs in one vectorised loop, both
    threads; in float64 (bit for bit (b)'s numbers) and float32 (the GSA's option).

Then the estimated limit of this machine for this step, and how it was estimated (the
instructions of the compiled lane loop over the cores' vector throughput), and what the kernel
runs at on one block kept in the first-level cache (no memory traffic, one thread).

Usage::

    python benchmarks/bench_kernel.py [--runs 90000] [--numpy-runs 20000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import re
import time

import numba
import numpy as np

import kernel_before
import sam
from bench_simulate import table1_params
from sam import P
from sam.constants import G, P_CAVITATION
from sam.dynamics import D, N_DERIVED, _first_order_lanes, derive
from sam.hydraulics import DP_CONDUCTANCE_MIN

N_STEPS = 4000
DT = 1e-3
RECORD_EVERY = 10
U = 2.5
CHANNELS = ("p_A", "p_B", "v")


# ---------------------------------------------------------------- (a) the numpy baseline
def numpy_constants(params: np.ndarray) -> np.ndarray:
    """The per-run constants (len(D), n), once per run as a user would (sam's derive)."""
    d = np.empty((params.shape[0], N_DERIVED))
    for i, p in enumerate(params):
        derive(p, d[i])
    return np.ascontiguousarray(d.T)


def numpy_simulate(params: np.ndarray, x0: np.ndarray, chunk: int) -> dict[str, np.ndarray]:
    """Eq. (22) over the batch with numpy, ``chunk`` runs at a time (arrays that stay in cache)."""
    n = params.shape[0]
    out = {c: np.empty((n, N_STEPS // RECORD_EVERY + 1)) for c in CHANNELS}
    for lo in range(0, n, chunk):
        with np.errstate(divide="ignore"):  # 1 / (h G) of a path without conductance, then not taken
            part = numpy_chunk(params[lo:lo + chunk], x0[lo:lo + chunk])
        for c in CHANNELS:
            out[c][lo:lo + chunk] = part[c]
    return out


def _ssqrt_G(k, dp):
    """Turbulent path of coefficient k: flow k sgn(dp) sqrt|dp| and chord conductance."""
    root = np.sqrt(np.abs(dp))
    return k * np.copysign(root, dp), k / np.maximum(root, np.sqrt(DP_CONDUCTANCE_MIN))


def numpy_chunk(params: np.ndarray, x0: np.ndarray) -> dict[str, np.ndarray]:
    p = {name: params[:, P[name]].copy() for name in P.__members__}
    d = numpy_constants(params)
    K_PA, K_AT, K_PB, K_BT, A_A, A_B = d[D.K_PA], d[D.K_AT], d[D.K_PB], d[D.K_BT], d[D.A_A], d[D.A_B]
    x_end, inv_J, sigma_1_r = d[D.x_end], d[D.inv_J_tot], d[D.sigma_1_r]
    w2, two_wz = p["omega_n"] ** 2, 2.0 * p["omega_n"] * p["zeta"]
    mg_L = (p["m_L"] - p["m_R"]) * G * p["L"]
    mg_B = p["m_B"] * G * p["r_B"]
    L1L2 = p["L_1"] * p["L_2"]
    p_A, p_B, x_s, dx_s, x, v, z = (x0[:, j].copy() for j in range(7))
    rec = {c: [] for c in CHANNELS}
    state = {"p_A": p_A, "p_B": p_B, "v": v}
    for k in range(N_STEPS + 1):
        if k % RECORD_EVERY == 0:
            for c in CHANNELS:
                rec[c].append(state[c].copy())
        if k == N_STEPS:
            break
        # valve, Eqs. (10)-(14)
        x_o = x_s + p["offset"]
        a1, a2 = np.maximum(x_o, 0.0), np.maximum(-x_o, 0.0)
        q_PA, g_PA = _ssqrt_G(K_PA * a1, p["p_S"] - p_A)
        q_AT, g_AT = _ssqrt_G(K_AT * a2, p_A - p["p_T"])
        q_PB, g_PB = _ssqrt_G(K_PB * a2, p["p_S"] - p_B)
        q_BT, g_BT = _ssqrt_G(K_BT * a1, p_B - p["p_T"])
        band = np.abs(x_o) < p["leak_band"]
        Q_A = q_PA - q_AT + band * (p["K_leak_PA"] * (p["p_S"] - p_A) - p["K_leak_AT"] * (p_A - p["p_T"]))
        Q_B = q_PB - q_BT + band * (p["K_leak_PB"] * (p["p_S"] - p_B) - p["K_leak_BT"] * (p_B - p["p_T"]))
        G_A = g_PA + g_AT + band * (p["K_leak_PA"] + p["K_leak_AT"])
        G_B = g_PB + g_BT + band * (p["K_leak_PB"] + p["K_leak_BT"])
        # leak faults, Eqs. (41)-(43)
        Q_int, G_AB = _ssqrt_G(p["K_int"], p_A - p_B)
        Q_extA, g_extA = _ssqrt_G(p["K_extA"], p_A - p["p_T"])
        Q_extB, g_extB = _ssqrt_G(p["K_extB"], p_B - p["p_T"])
        G_A, G_B = G_A + g_extA, G_B + g_extB
        # chambers, Eqs. (8)-(9)
        c_A = p["B_eff"] / (p["V_0A"] + A_A * x)
        c_B = p["B_eff"] / (p["V_0B"] + A_B * (p["x_max"] - x))
        r_A = (Q_A - Q_int - Q_extA - A_A * v) * c_A
        r_B = (Q_B + Q_int - Q_extB + A_B * v) * c_B
        # boom, Eqs. (5), (16), (20), (21)
        cos_t = (p["L_1"] ** 2 + p["L_2"] ** 2 - (x + p["L_3"]) ** 2) / (2.0 * L1L2)
        sin_t = np.sqrt(1.0 - cos_t * cos_t)
        r = L1L2 * sin_t / (x + p["L_3"])
        cos_phi = cos_t * d[D.cos_level] + sin_t * d[D.sin_level]
        sin_phi = sin_t * d[D.cos_level] - cos_t * d[D.sin_level]
        tau = mg_L * cos_phi + mg_B * (cos_phi * d[D.cos_cog] - sin_phi * d[D.sin_cog])
        # LuGre friction, Eq. (17)
        g = p["F_C"] + (p["F_S"] - p["F_C"]) * np.exp(-((v / p["v_s"]) ** 2))
        dz = v - p["sigma_0"] * np.abs(v) * z / g
        F_mu = p["sigma_0"] * z + sigma_1_r / r * dz + p["b"] * v
        dv = (p_A * A_A - p_B * A_B - F_mu - tau / r - p["F_d"]) * r * r * inv_J
        ddx_s = p["K_u"] * w2 * U - two_wz * dx_s - w2 * x_s
        # a step that reaches an end stop displaces oil only over the travel to it
        x_new = x + DT * v
        v_disp = np.where(x_new < 0.0, -np.maximum(x, 0.0) / DT, np.where(x_new > x_end, np.maximum(x_end - x, 0.0) / DT, v))
        r_A += c_A * A_A * (v - v_disp)
        r_B -= c_B * A_B * (v - v_disp)
        # the stiff chambers: the implicit share of each stiff path
        h_A, h_B = DT * c_A, DT * c_B
        a = np.where(h_A * G_A > 1.0, 1.0 - 1.0 / (h_A * G_A), 0.0) * G_A
        b = np.where(h_B * G_B > 1.0, 1.0 - 1.0 / (h_B * G_B), 0.0) * G_B
        hg = (h_A + h_B) * G_AB
        gg = np.where(hg > 1.0, 1.0 - 1.0 / hg, 0.0) * G_AB
        m_A, m_B = 1.0 + h_A * (a + gg), 1.0 + h_B * (b + gg)
        det = m_A * m_B - h_A * h_B * gg * gg
        r_A, r_B = (r_A * m_B + h_A * gg * r_B) / det, (r_B * m_A + h_B * gg * r_A) / det
        # Eq. (22), then the floors and the stops
        p_A += DT * r_A
        p_B += DT * r_B
        np.maximum(p_A, P_CAVITATION, out=p_A)
        np.maximum(p_B, P_CAVITATION, out=p_B)
        x_s, dx_s = x_s + DT * dx_s, dx_s + DT * ddx_s
        x += DT * v
        v += DT * dv
        z += DT * dz
        low, high = x <= 0.0, x >= x_end
        v[(low & (v < 0.0)) | (high & (v > 0.0))] = 0.0
        np.clip(x, 0.0, x_end, out=x)
    return {c: np.stack(rec[c], axis=1) for c in CHANNELS}


# ---------------------------------------------------------------- (b), (c) and the timing
def run_before(params, x0):
    return kernel_before.simulate_batch(params, np.full(N_STEPS, U), DT, x0=x0, record_every=RECORD_EVERY,
                                        channels=CHANNELS)[0]


def run_lanes(params, x0, precision="float64"):
    return sam.simulate_batch(params, np.full(N_STEPS, U), DT, x0=x0, record_every=RECORD_EVERY, channels=CHANNELS,
                              precision=precision)


def timed(fn, *args) -> tuple[float, dict]:
    t0 = time.perf_counter()
    out = fn(*args)
    return time.perf_counter() - t0, out


def in_cache_rate(precision: str, rounds: int = 500, repeats: int = 40) -> float:
    """ns per run-step of the paper's lane loop alone (Euler, no leak, no effect): one block of
    LANES runs stepped ``rounds`` times from compiled code, one thread, its arrays in the
    first-level cache (no memory traffic, no recording). The least of ``repeats`` timings of
    well under a scheduler's time slice: on a shared machine most are interrupted."""
    from sam.dynamics import LANES, derive_geometry, derive_machine

    f = np.float64 if precision == "float64" else np.float32
    params = table1_params(LANES)
    s = np.ascontiguousarray(sam.initial_state(params, 0.1).T, dtype=f)
    p = np.ascontiguousarray(params.T, dtype=f)
    d = np.empty((N_DERIVED, LANES), dtype=f)
    for j in range(LANES):
        derive_geometry(p, d, j)
        derive_machine(p, d, j)
    u, flags = np.full(LANES, U, dtype=f), np.zeros(LANES, dtype=np.int64)
    _paper_steps(s, u, p, d, f(DT), flags, 1)  # compile
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        _paper_steps(s, u, p, d, f(DT), flags, rounds)
        best = min(best, time.perf_counter() - t0)
    return best / (rounds * LANES) * 1e9


@numba.njit(error_model="numpy", _nrt=False)
def _paper_steps(s, u, p, d, h, flags, rounds):
    for _ in range(rounds):
        _first_order_lanes(s, u, p, d, h, flags, s.shape[1], False, False, False)


def loop_instructions() -> dict[str, int]:
    """Instruction counts of the vectorised body of the paper's lane loop (Euler, no leak, no
    effect, float64), compiled afresh (a cached function cannot be inspected): its 512-bit vector
    instructions (8 lanes each), and among them the divisions and the square roots."""
    from sam.dynamics import LANES, N_PARAMS, N_STATES, _first_order_lane, _fixed, _lanes
    from sam.simd import float_type

    @numba.njit(error_model="numpy", _nrt=False)
    def paper_loop(s, u, p, d, h, flags, n):
        f = float_type(s)
        s, p, d = _fixed(s, p, d)
        for j in _lanes(n):
            _first_order_lane(s, u, p, d, j, h, flags, False, False, False, f)

    z = np.zeros
    paper_loop(z((N_STATES, LANES)), z(LANES), z((N_PARAMS, LANES)), z((N_DERIVED, LANES)), DT,
               z(LANES, dtype=np.int64), LANES)
    asm = paper_loop.inspect_asm(paper_loop.signatures[0])
    return {"zmm": len(re.findall(r"^\s+v\w+\s[^\n]*zmm", asm, re.M)),
            "div": len(re.findall(r"vdivpd\s[^\n]*zmm", asm)), "sqrt": len(re.findall(r"vsqrtpd\s[^\n]*zmm", asm))}


#: Assumed 512-bit throughputs of this machine's cores (AMD Zen 4, which splits a 512-bit
#: instruction in two 256-bit halves): instructions per cycle, and cycles per division and per
#: square root (the dividers are not pipelined). Rough, from the vendor's optimisation guide's
#: orders of magnitude; the estimate says so.
ZMM_PER_CYCLE, DIV_CYCLES, SQRT_CYCLES = 2.0, 10.0, 17.0


def limit_ns(ins: dict[str, int], ghz: float, cores: int) -> float:
    """ns per run-step of the compiled loop if it ran at the cores' vector throughput (issue
    or divider bound, whichever is slower), 8 float64 lanes per instruction, on every core."""
    cycles = max(ins["zmm"] / ZMM_PER_CYCLE, ins["div"] * DIV_CYCLES + ins["sqrt"] * SQRT_CYCLES)
    return cycles / 8 / ghz / cores


def cpu_ghz() -> float:
    with open("/proc/cpuinfo") as fh:
        return float(re.search(r"cpu MHz\s*:\s*([\d.]+)", fh.read()).group(1)) / 1000


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=90_000, help="runs of the batch for (b) and (c)")
    ap.add_argument("--numpy-runs", type=int, default=20_000, help="runs timed for (a) (one numpy batch)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    params = table1_params(args.runs)
    x0 = sam.initial_state(params)
    small = slice(0, 64)
    run_before(params[small], x0[small]), run_lanes(params[small], x0[small])  # compile
    run_lanes(params[small], x0[small], "float32")
    na = min(args.numpy_runs, args.runs)
    a_out = numpy_simulate(params[:na], x0[:na], na)
    c_out = run_lanes(params[:na], x0[:na])
    agree = max(np.max(np.abs(a_out[c] - c_out[c])) / np.max(np.abs(c_out[c])) for c in CHANNELS)
    t = {"a": [], "b": [], "c": [], "c32": []}
    for _ in range(args.repeats):
        t["a"].append(timed(numpy_simulate, params[:na], x0[:na], na)[0] / (na * N_STEPS))
        t["b"].append(timed(run_before, params, x0)[0] / (args.runs * N_STEPS))
        t["c"].append(timed(run_lanes, params, x0)[0] / (args.runs * N_STEPS))
        t["c32"].append(timed(run_lanes, params, x0, "float32")[0] / (args.runs * N_STEPS))
    ns = {k: 1e9 * np.median(v) for k, v in t.items()}
    pair = {k: np.median(np.array(t[k]) / np.array(t["c"])) for k in ("a", "b")}
    b_out, c_full = run_before(params, x0), run_lanes(params, x0)
    exact = all(np.array_equal(b_out[c], c_full[c]) for c in CHANNELS)
    load = os.getloadavg()
    print(f"machine: {os.cpu_count()} cores, load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}; "
          f"medians of {args.repeats} interleaved rounds")
    print(f"(a) numpy, Eq. (22), {na} runs in one batch, 1 thread : {ns['a']:6.1f} ns per run-step "
          f"(agrees with sam to {agree:.1e} of each channel's range)")
    print(f"(b) before: one run per iteration, {args.runs} runs, 2 threads : {ns['b']:6.1f} ns per run-step")
    print(f"(c) lanes, float64, {args.runs} runs, 2 threads : {ns['c']:6.1f} ns per run-step "
          f"({'bit for bit' if exact else 'NOT bit for bit'} (b)'s)")
    print(f"(c) lanes, float32, {args.runs} runs, 2 threads : {ns['c32']:6.1f} ns per run-step")
    print(f"ratios (median of the rounds' pairs): (a)/(c) {pair['a']:.1f}x, (b)/(c) {pair['b']:.1f}x, "
          f"(c)/(c32) {np.median(np.array(t['c']) / np.array(t['c32'])):.2f}x")
    cache64, cache32 = in_cache_rate("float64"), in_cache_rate("float32")
    print(f"one block in L1, 1 thread, uninterrupted: float64 {cache64:.1f}, float32 {cache32:.1f} ns per "
          f"run-step (/{os.cpu_count()} cores: {cache64 / os.cpu_count():.1f}, {cache32 / os.cpu_count():.1f})")
    ins, ghz = loop_instructions(), cpu_ghz()
    print(f"estimated limit: {limit_ns(ins, ghz, os.cpu_count()):.1f} ns per run-step: the vectorised body of "
          f"the paper's lane loop (Euler, float64) has {ins['zmm']} 512-bit instructions ({ins['div']} divisions, {ins['sqrt']} square "
          f"roots) for 8 lanes; at {ZMM_PER_CYCLE:g} per cycle ({DIV_CYCLES:g} and {SQRT_CYCLES:g} cycles per "
          f"division and root), {ghz:.2f} GHz, {os.cpu_count()} cores; memory traffic not counted")
    print(f"targets: <= 4 ns per run-step ({'met' if ns['c'] <= 4 else 'NOT met'}), >= 10x (a) "
          f"({'met' if pair['a'] >= 10 else 'NOT met'})")


if __name__ == "__main__":
    main()
