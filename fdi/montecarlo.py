"""Monte Carlo runs for threshold tuning: healthy and faulty runs under unknown loads
and model uncertainty, filtered many at a time by the batched UKF."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sam import P, Plant, profiles
from sam.constants import LPM
from sam.hydraulics import fault_leakages_batch

from .faults import FAULTS
from .synth import INPUT_KINDS, POSITION_SENSORS, lpm, profile, random_input, simulate_runs

#: The nuisance box of the threshold study and the Monte Carlo: Table 1's parameters that a
#: calibration leaves uncertain, their relative half-widths (each valve notch's flow and
#: pressure drop +-2 %, B_eff +-10 %, viscous friction +-20 %).
NUISANCE = {
    "Q_N_PA": 0.02, "Q_N_AT": 0.02, "Q_N_PB": 0.02, "Q_N_BT": 0.02,
    "dp_N_PA": 0.02, "dp_N_AT": 0.02, "dp_N_PB": 0.02, "dp_N_BT": 0.02,
    "B_eff": 0.10, "b": 0.20,
}
LOAD_RANGE = (0.0, 800.0)  #: kg: the load, unknown to the filter
#: The issue's 20-60 s extend/retract cycles as a healthy population of their own (the tune's
#: "healthy_long" runs; not in the threshold studies: fdi.synth.CYCLE_PERIOD_S says why). Each
#: run: a random period, amplitude and phase, no dwell or a dwell of half of each stroke, and a
#: random start position, so that some long strokes end on an end stop and some reverse in mid
#: stroke (a reversal after a long steady stroke: docs/fdi.md, "Known limitations").
LONG_CYCLES = {"period_s": (20.0, 60.0), "amplitude_V": (1.0, 4.0), "dwell_fraction": (0.0, 0.5),
               "x0_m": (0.02, 0.40)}
#: the input families of make_batch: the studies' mix, and the long cycles
INPUT_FAMILIES = ("standard", "long_cycles")


@dataclass(frozen=True)
class TuneDesign:
    """The Monte Carlo evaluation of the detector (``samfdi fdi tune``): its fault cases, runs
    and what it scores. Healthy runs last the thresholds' run_length_s (their false-alarm level's)."""

    #: fault -> its sizes: leaks in L/min at 10 MPa, the offset in fractions of spool travel
    fault_sizes: dict = field(default_factory=lambda: {
        "K_int": (0.1, 0.25, 0.5, 1.0), "K_extA": (0.1, 0.25, 0.5, 1.0), "K_extB": (0.1, 0.25, 0.5, 1.0),
        "offset": (0.01, -0.01, 0.02, -0.02, 0.05)})
    fault_run_s: float = 4.0  #: s: the length of a fault run
    dt: float = 1e-3  #: s: the simulation's and the filter's sampling step
    #: s: each fault run steps in at its own onset, uniform in this range (+ the scored second < fault_run_s)
    onset_range_s: tuple = (1.5, 2.5)
    within_s: float = 1.0  #: s: scored: detected and isolated within this long of the onset
    reference_s: float = 4.0  #: s: the healthy reference recording of ``--reference``
    chunk_runs: int = 25  #: runs per chunk (a chunk is saved as it finishes)
    #: each fault case detected and isolated within ``within_s`` in at least this fraction of runs
    target_rate: float = 0.95
    #: sizes unbiased: the median relative size error of the isolated runs within +-this
    size_bias: float = 0.10
    #: and the truth inside the reported +-2 sigma in at least this fraction of them
    size_coverage: float = 0.90
    load_bins_kg: tuple = ((0.0, 267.0), (267.0, 534.0), (534.0, 800.1))  #: load thirds the rates are split by
    #: L/min: edges of the flow a leak passed in its scored second, for isolation by flow
    flow_bins_lpm: tuple = (0.05, 0.1, 0.15, 0.25, 0.5, 1.0)

    def __post_init__(self):
        for name in ("fault_run_s", "dt", "within_s", "reference_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < math.inf):
                raise ValueError(f"TuneDesign.{name} = {v!r}: must be a duration > 0 s")
        lo, hi = self.onset_range_s
        if not 0 < lo <= hi or hi + self.within_s > self.fault_run_s:
            raise ValueError(f"TuneDesign.onset_range_s = {self.onset_range_s!r}: must lie in (0, fault_run_s - "
                             f"within_s] = (0, {self.fault_run_s - self.within_s:g}] s, the scored second in the run")
        if isinstance(self.chunk_runs, bool) or not isinstance(self.chunk_runs, int) or self.chunk_runs < 1:
            raise ValueError(f"TuneDesign.chunk_runs = {self.chunk_runs!r}: must be a whole number >= 1")
        for name in ("target_rate", "size_coverage"):
            if not 0 < getattr(self, name) < 1:
                raise ValueError(f"TuneDesign.{name} = {getattr(self, name)!r}: must be a fraction of runs in (0, 1)")
        if not 0 < self.size_bias < math.inf:
            raise ValueError(f"TuneDesign.size_bias = {self.size_bias!r}: must be a relative size error > 0")
        for fault, sizes in self.fault_sizes.items():
            if fault not in FAULTS or not sizes or any(s == 0 for s in sizes):
                raise ValueError(f"TuneDesign.fault_sizes[{fault!r}] = {sizes!r}: must be non-zero sizes of one of "
                                 f"{', '.join(FAULTS)}")


TUNE = TuneDesign()


#: the leak faults, in the order of fault_leakages' flows
LEAKS = ("K_int", "K_extA", "K_extB")


def leak_flow_lpm(runs, fault: str, k_from: np.ndarray, window_s: float) -> np.ndarray:
    """(B,) mean flow [L/min] through the leak ``fault`` (a LEAKS name) of each run of
    :func:`make_batch`'s ``runs`` over its samples [k_from[b], k_from[b] + window_s): Eqs.
    (41)-(43) at the run's true pressures, tank pressure and leak coefficient. A leak is rated
    by its flow at 10 MPa, but passes K sqrt(dp) at the machine's own pressure difference: a
    "0.25 L/min" K_int passes less where p_A and p_B balance (light loads), K_extB less where p_B
    is low (heavy loads). The magnitude: an internal leak may flow either way."""
    tr = runs.truth
    zero = np.zeros_like(tr["p_A"])
    K = [np.broadcast_to(tr.get(f, zero), zero.shape).astype(float) for f in LEAKS]
    Q = fault_leakages_batch(tr["p_A"], tr["p_B"], np.ascontiguousarray(tr["params"][:, P.p_T]), *K)
    Q = np.abs(Q[LEAKS.index(fault)])
    w = max(1, int(round(window_s / runs.inp.dt)))
    return np.array([Q[b, k:k + w].mean() for b, k in enumerate(np.asarray(k_from))]) / LPM


def draw_truth(plant: Plant, n: int, rng: np.random.Generator, nuisance: bool = True) -> np.ndarray:
    base = plant.vector()
    p = np.tile(base, (n, 1))
    if nuisance:
        for name, rel in NUISANCE.items():
            p[:, P[name]] *= 1.0 + rel * rng.uniform(-1, 1, n)
    p[:, P.m_L] = rng.uniform(*LOAD_RANGE, n)
    return p


def draw_inputs(n: int, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    kinds = rng.choice(INPUT_KINDS, n)
    return np.stack([random_input(str(kind), t, rng) for kind in kinds]) if n else np.empty((0, len(t)))


def draw_long_cycles(n: int, t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(u (n, T) [V], x0 (n,) [m]): n runs of LONG_CYCLES, each drawn in this order: period,
    amplitude, dwell fraction (one of the two), phase (uniform over the period), start position."""
    c = LONG_CYCLES
    u, x0 = np.empty((n, len(t))), np.empty(n)
    for i in range(n):
        period = rng.uniform(*c["period_s"])
        amplitude = rng.uniform(*c["amplitude_V"])
        dwell = float(rng.choice(c["dwell_fraction"]))
        phase = rng.uniform(0.0, period)
        u[i] = profiles.cycle_input(t + phase, amplitude, period, dwell_fraction=dwell)
        x0[i] = rng.uniform(*c["x0_m"])
    return u, x0


def make_batch(plant: Plant, n: int, seed: int, *, fault: str | None = None, size: float = 0.0,
               duration: float = 4.0, dt: float = 1e-3, onset: float | np.ndarray = 1.5, nuisance: bool = True,
               position_sensor: str = "encoder", inputs: str = "standard"):
    """n runs; fault in K_int/K_extA/K_extB (size in L/min) or offset (size in fraction)
    stepping in at ``onset`` [s]: one time for every run, or an array (n,) of per-run times
    (run i is healthy for t < onset[i], faulty from the first sample with t >= onset[i]).
    The filter is given the nominal plant with healthy faults. The onset does not touch the
    seeded draws (loads, nuisance, inputs, noise), so runs with the same seed are paired
    whatever their onsets. ``runs.truth`` gets ``"onset_s"`` (n,) and ``"k_onset"`` (n,), the
    index of run i's first faulty sample (also for healthy runs: where a fault would start).
    ``position_sensor``: the position channel recorded (fdi.synth.POSITION_SENSORS).
    ``inputs``: "standard" (the studies' sine / cycle / PRBS mix from x = 0.05 m) or
    "long_cycles" (LONG_CYCLES, each from its own start position)."""
    if inputs not in INPUT_FAMILIES:
        raise ValueError(f"inputs: one of {', '.join(INPUT_FAMILIES)}, got {inputs!r}")
    rng = np.random.default_rng(seed)
    T = int(round(duration / dt)) + 1
    t = np.arange(T) * dt
    onset_s = np.asarray(onset, dtype=float)
    if onset_s.ndim == 0:
        onset_s = np.full(n, float(onset_s))
    if onset_s.shape != (n,):
        raise ValueError(f"onset: a float or an array of shape ({n},), got shape {onset_s.shape}")
    k_onset = np.searchsorted(t, onset_s, side="left").astype(np.int64)  # first k with t[k] >= onset
    truth = draw_truth(plant, n, rng, nuisance)
    if inputs == "long_cycles":
        u, x0 = draw_long_cycles(n, t, rng)
    else:
        u, x0 = draw_inputs(n, t, rng), 0.05
    faults = None
    if fault is not None:
        value = size if fault == "offset" else lpm(size)
        faults = {fault: np.stack([profile("step", value, t, t0=float(o)) for o in onset_s])}
    nominal = np.tile(plant.vector(), (n, 1))
    runs = simulate_runs(truth, u, dt, faults=faults, nominal=nominal, seed=seed + 1, x0=x0,
                         **POSITION_SENSORS[position_sensor])
    runs.truth["params"] = truth  #: (B, len(P)) each run's true plant (its machine)
    runs.truth["m_L_kg"] = truth[:, P.m_L]  #: (B,) the unknown load of each run
    runs.truth["onset_s"] = onset_s  #: (B,) the fault onset of each run [s]
    runs.truth["k_onset"] = k_onset  #: (B,) its sample index
    return runs


def make_reference_batch(plant: Plant, machines: np.ndarray, seed: int, *, duration: float = 4.0,
                         dt: float = 1e-3, position_sensor: str = "encoder"):
    """A healthy reference recording of each machine (rows of ``machines``, (B, len(P)): the
    truth of a :func:`make_batch`), as a lab would record one before monitoring: the same
    valve, cylinder and fluid, another load (uniform over LOAD_RANGE) and another input, from
    their own generator (seed, 99), so that the batch's own draws are unchanged."""
    rng = np.random.default_rng((seed, 99))
    n = len(machines)
    truth = np.array(machines, dtype=float, copy=True)
    truth[:, P.m_L] = rng.uniform(*LOAD_RANGE, n)
    t = np.arange(int(round(duration / dt)) + 1) * dt
    u = draw_inputs(n, t, rng)
    return simulate_runs(truth, u, dt, nominal=np.tile(plant.vector(), (n, 1)), seed=int(rng.integers(1 << 31)),
                         **POSITION_SENSORS[position_sensor])
