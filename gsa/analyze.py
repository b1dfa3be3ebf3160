"""Sobol' indices with confidence intervals for every output of a study.

    design = saltelli_design(problem, N=2**13, seed=1)
    Y = model(design.X)                        # or gsa.runner.run(...).Y
    result = analyze(problem, design, Y, output_names=names)
    result.write_csv("indices.csv")

This is the validating boundary: shapes, names, estimator and NaN policy are
checked here once; the numerics below trust their inputs.
"""

from __future__ import annotations

import csv
import math
import numbers
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gsa.bootstrap import DEFAULT_MEMORY_BUDGET, bootstrap_sobol
from gsa.design import Design, Samples
from gsa.errors import GSAError, NonFiniteWarning, ZeroVarianceWarning
from gsa.estimators import (
    DEFAULT_ESTIMATOR,
    SobolStatistic,
    get_estimator,
    interaction,
    ranking,
    second_order_matrix,
    separated_groups,
)
from gsa.nonfinite import NonFiniteReport
from gsa.problem import Problem

CSV_COLUMNS = ("output", "time_s", "parameter", "S1", "S1_lo", "S1_hi", "ST", "ST_lo", "ST_hi")


@dataclass(frozen=True, eq=False)
class SobolResult:
    """Indices of G factors for M outputs. All index arrays are dimensionless.

    ``S1``, ``S1_lo``, ``S1_hi``, ``ST``, ``ST_lo``, ``ST_hi``: (G, M), the point
    estimate and the bounds of its confidence interval (NaN when n_boot = 0).
    ``S2``, ``S2_lo``, ``S2_hi``: (G, G, M), upper triangle (i < j) only, NaN
    elsewhere; None unless second order was asked for. Outputs flagged in
    ``constant`` (M,) did not vary and have NaN everywhere.
    """

    factor_names: tuple[str, ...]
    output_names: tuple[str, ...]
    output_times: np.ndarray | None  # (M,) s, or None
    estimator: str
    N: int  # base samples used (after any dropped ones)
    n_boot: int
    ci: str
    confidence: float
    S1: np.ndarray
    S1_lo: np.ndarray
    S1_hi: np.ndarray
    ST: np.ndarray
    ST_lo: np.ndarray
    ST_hi: np.ndarray
    S2: np.ndarray | None
    S2_lo: np.ndarray | None
    S2_hi: np.ndarray | None
    constant: np.ndarray
    dropped_samples: int = 0

    @property
    def interactions(self) -> np.ndarray:
        """1 - sum_i S1_i per output, (M,): variance share of interactions."""
        return interaction(self.S1)

    def ranking(self, by: str = "ST") -> np.ndarray:
        """(G, M) factor indices, most influential first, by ``"ST"`` or ``"S1"``."""
        if by not in ("S1", "ST"):
            raise GSAError(f"ranking is by 'S1' or 'ST', got {by!r}")
        return ranking(getattr(self, by))

    def ranked_factors(self, output: int | str, by: str = "ST") -> list[str]:
        """Factor names of one output (index or name), most influential first."""
        j = self._output_index(output)
        return [self.factor_names[i] for i in self.ranking(by)[:, j]]

    def ranked_groups(self, output: int | str, by: str = "ST") -> list[list[int]]:
        """Factor indices of one output, most influential first, grouped where the confidence
        intervals do not separate them (:func:`gsa.estimators.separated_groups`)."""
        if by not in ("S1", "ST"):
            raise GSAError(f"ranking is by 'S1' or 'ST', got {by!r}")
        j = self._output_index(output)
        return separated_groups(*(getattr(self, by + part)[:, j] for part in ("", "_lo", "_hi")))

    def to_rows(self) -> list[dict]:
        """One dict per (output, factor), keys :data:`CSV_COLUMNS`; time_s None if unknown or NaN."""
        rows = []
        for j, name in enumerate(self.output_names):
            t = None if self.output_times is None else float(self.output_times[j])
            t = None if t is not None and math.isnan(t) else t  # NaN time: a scalar output (steady state)
            for i, factor in enumerate(self.factor_names):
                rows.append(
                    {
                        "output": name,
                        "time_s": t,
                        "parameter": factor,
                        **{c: float(getattr(self, c)[i, j]) for c in CSV_COLUMNS[3:]},
                    }
                )
        return rows

    def write_csv(self, path: str | os.PathLike) -> Path:
        """Write :meth:`to_rows` as CSV (atomically: temp file + rename). Returns the path."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(CSV_COLUMNS)
            for r in self.to_rows():
                w.writerow(["" if r[c] is None else _fmt(r[c]) for c in CSV_COLUMNS])
        os.replace(tmp, path)
        return path

    def _output_index(self, output: int | str) -> int:
        if isinstance(output, str):
            try:
                return self.output_names.index(output)
            except ValueError:
                raise GSAError(f"no output named {output!r}") from None
        return int(output)


def _label(name: str, times: np.ndarray | None, j: int) -> str:
    """An output's name for messages, with its time when it has one: 'v' at 0.01 s."""
    if times is None or not math.isfinite(times[j]):
        return repr(name)
    return f"{name!r} at {times[j]:g} s"


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    return str(v)


def analyze(
    problem: Problem,
    design: Design,
    Y: np.ndarray,
    estimator: str = DEFAULT_ESTIMATOR,
    n_boot: int = 1000,
    ci: str = "percentile",
    seed=None,
    *,
    confidence: float = 0.95,
    output_names: Sequence[str] | None = None,
    output_times: Sequence[float] | None = None,
    second_order: bool | None = None,
    memory_budget: int = DEFAULT_MEMORY_BUDGET,
    precision: str = "float64",
    drop_nonfinite: bool = False,
) -> SobolResult:
    """Sobol' indices of every output, with bootstrap confidence intervals.

    Parameters
    ----------
    problem, design :
        The problem and the design Y was computed on (``design.problem == problem``).
    Y : (n_runs, M) or (n_runs,) array
        Model outputs in the design's run order (see :mod:`gsa.design`), any unit.
    estimator : str
        ``"saltelli2010-jansen"`` (default), ``"janon"``, ``"azzini"`` (needs a
        design with BA) or ``"saltelli2002"`` (the paper's Eqs. 33-38).
    n_boot : int
        Bootstrap replicates (0: no intervals).
    ci : ``"percentile"`` or ``"bca"``
    seed : int
        Bootstrap seed (default: the design's seed, so a study is reproducible by
        default); it seeds a stream separate from the design's scrambling.
    confidence : float
        Two-sided interval level.
    output_names, output_times :
        M names (default y0, y1, ...) and optional M times in s (CSV column time_s).
    second_order : bool
        Also compute S2 (needs the BA block); default: ``design.second_order``.
    memory_budget : int
        Bytes of extra memory the analysis may use (Y itself not counted).
    precision : "float64" | "float32"
        Arithmetic of the bootstrap's matrix product (see
        :func:`gsa.bootstrap.bootstrap_sobol`); point estimates are always float64.
    drop_nonfinite : bool
        If Y has NaN/inf: False (default) raises GSAError listing them; True drops
        every base sample m touched by one (its row in A, B and all AB_i/BA_i) and
        warns (:class:`~gsa.errors.NonFiniteWarning`) with the count.
    """
    if not isinstance(design, Design):
        raise GSAError(f"design must be a gsa Design, got {type(design).__name__}")
    if design.problem != problem:
        raise GSAError("the design was built for a different problem than the one given")
    Y = _as_outputs(Y, design)
    M = Y.shape[1]
    names = _as_output_names(output_names, M)
    times = _as_output_times(output_times, M)
    est = get_estimator(estimator)
    if est.needs_BA and not design.with_BA:
        raise GSAError(
            f"estimator {estimator!r} needs the BA_i runs: build the design with "
            f"saltelli_design(..., with_BA=True) (N(2G+2) runs instead of N(G+2))"
        )
    if second_order is None:
        second_order = design.second_order
    if second_order and not design.with_BA:
        raise GSAError(
            "second-order indices need the BA_i runs: build the design with second_order=True"
        )
    if seed is not None and (
        isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0
    ):
        raise GSAError(f"seed must be a non-negative integer, got {seed!r}")
    # A stream of its own: the same integer also seeds the Sobol' scrambling.
    seed = np.random.SeedSequence(design.seed if seed is None else seed, spawn_key=(0xB007,))

    samples, N, dropped = _finite_samples(design, Y, names, drop_nonfinite)
    stat = SobolStatistic(estimator, design.G, bool(second_order))
    res = bootstrap_sobol(
        samples,
        stat,
        n_boot=n_boot,
        ci=ci,
        confidence=confidence,
        seed=seed,
        memory_budget=memory_budget,
        precision=precision,
    )
    if res.constant.any():
        flat = np.flatnonzero(res.constant)
        listed = ", ".join(_label(names[j], times, j) for j in flat[:10])
        more = f" and {len(flat) - 10} more" if len(flat) > 10 else ""
        warnings.warn(
            f"{len(flat)} of {M} outputs do not vary over the design, so their Sobol' "
            f"indices are undefined and set to NaN: {listed}{more}",
            ZeroVarianceWarning,
            stacklevel=2,
        )

    S2 = S2_lo = S2_hi = None
    if second_order:
        S2, S2_lo, S2_hi = (
            second_order_matrix(d["S2"], design.G) for d in (res.estimates, res.lo, res.hi)
        )
    return SobolResult(
        factor_names=problem.factor_names,
        output_names=names,
        output_times=times,
        estimator=estimator,
        N=N,
        n_boot=n_boot,
        ci=ci,
        confidence=confidence,
        S1=res.estimates["S1"],
        S1_lo=res.lo["S1"],
        S1_hi=res.hi["S1"],
        ST=res.estimates["ST"],
        ST_lo=res.lo["ST"],
        ST_hi=res.hi["ST"],
        S2=S2,
        S2_lo=S2_lo,
        S2_hi=S2_hi,
        constant=res.constant,
        dropped_samples=dropped,
    )


def _as_outputs(Y, design: Design) -> np.ndarray:
    Y = np.asarray(Y)
    if Y.ndim == 1:
        Y = Y[:, None]
    if Y.ndim != 2:
        raise GSAError(f"Y must be (n_runs, n_outputs), got an array of shape {Y.shape}")
    if Y.shape[0] != design.n_runs:
        raise GSAError(
            f"Y has {Y.shape[0]} rows but the design has {design.n_runs} runs "
            f"(N={design.N} x {design.n_blocks} blocks)"
        )
    if Y.shape[1] == 0:
        raise GSAError("Y has no outputs (0 columns)")
    if not np.issubdtype(Y.dtype, np.number) or np.iscomplexobj(Y):
        raise GSAError(f"Y must hold real numbers, got dtype {Y.dtype}")
    # Row-major float64 so that each design block is a reshape-able view, not a copy.
    return np.ascontiguousarray(Y, dtype=np.float64)


def _as_output_names(output_names, M: int) -> tuple[str, ...]:
    if output_names is None:
        return tuple(f"y{j}" for j in range(M))
    names = tuple(str(n) for n in output_names)
    if len(names) != M:
        raise GSAError(f"got {len(names)} output names for {M} outputs (columns of Y)")
    return names


def _as_output_times(output_times, M: int) -> np.ndarray | None:
    if output_times is None:
        return None
    t = np.asarray(output_times, dtype=np.float64)
    if t.shape != (M,):
        raise GSAError(f"got {t.size} output times for {M} outputs (columns of Y)")
    return t


def _finite_samples(design: Design, Y: np.ndarray, names, drop: bool) -> tuple[Samples, int, int]:
    """Samples of Y, after applying the NaN/inf policy. Returns (samples, N used, N dropped)."""
    report = NonFiniteReport.from_outputs(design, Y, names)
    if not report:
        return design.split(Y), design.N, 0
    if not drop:
        raise GSAError(
            report.summary()
            + "\nFix the model for these inputs, or pass drop_nonfinite=True to drop "
            "the affected base samples from the analysis."
        )
    bad = np.zeros(design.N, dtype=bool)
    bad[report.samples] = True
    keep = np.flatnonzero(~bad)
    if len(keep) < 2:
        raise GSAError(
            f"after dropping the {int(bad.sum())} base samples with NaN/inf fewer than 2 remain"
        )
    warnings.warn(
        f"dropped {int(bad.sum())} of {design.N} base samples (their rows in every design "
        f"block) because {report.count} runs returned NaN/inf; indices use N={len(keep)}",
        NonFiniteWarning,
        stacklevel=3,
    )
    N, M = design.N, Y.shape[1]
    Y_kept = np.ascontiguousarray(Y.reshape(design.n_blocks, N, M)[:, keep]).reshape(-1, M)
    G, n = design.G, len(keep)
    f_AB = Y_kept[2 * n : (2 + G) * n].reshape(G, n, M)
    f_BA = Y_kept[(2 + G) * n :].reshape(G, n, M) if design.with_BA else None
    return Samples(Y_kept[:n], Y_kept[n : 2 * n], f_AB, f_BA), n, int(bad.sum())
