"""The SAM model as a GSA model: parameter rows in, time-resolved outputs out.

This is where the generic engine meets the hydraulics: a picklable callable
``SamModel(X) -> Y`` that writes each sampled parameter into its column of the
plant's parameter vector, runs the whole chunk through :func:`sam.simulate_batch`
and returns the outputs at the requested instants, plus a steady-state value.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numba
import numpy as np

import sam


#: the model's states as a hydraulics engineer names them (tables, legends, conclusions)
OUTPUT_WORDS = {
    "p_A": "piston-side chamber pressure p_A",
    "p_B": "rod-side chamber pressure p_B",
    "x_s": "spool position x_s",
    "dx_s": "spool velocity",
    "x": "piston position x",
    "v": "piston velocity v",
    "z": "friction bristle deflection z",
}


@dataclass(frozen=True, eq=False)
class SamModel:
    """Evaluate the SAM model for rows of sampled parameters.

    Attributes:
        base: (len(P),) the plant's parameter vector; sampled columns are overwritten.
        columns: indices into ``base`` (``sam.P``) of the k sampled parameters.
        scales: (k,) factor from the study's units to SI for each sampled parameter.
        u: (n_steps,) control signal [V].
        dt: Euler step [s].
        record_at: step indices of the time-resolved outputs.
        signals: state names to output, e.g. ("p_A", "p_B", "v").
        steady_from: step index from which the steady-state value is taken: the mean
            of the recorded instants from there to the end.
        time_varying: parameter name -> (n_steps,) profile shared by all runs (e.g. the load).
        threads: numba threads to use (1 inside process or dask workers: the
            executor already spreads the work over the cores).
        precision: the step's arithmetic, ``"float64"`` or ``"float32"`` (faster; how far the
            paper's indices move: docs/benchmarks.md).
    """

    base: np.ndarray
    columns: tuple[int, ...]
    scales: np.ndarray
    u: np.ndarray
    dt: float
    record_at: np.ndarray
    signals: tuple[str, ...]
    steady_from: int
    time_varying: dict | None = None
    threads: int | None = None
    precision: str = "float64"

    def fingerprint(self) -> str:
        """sha256 of what the outputs depend on (not ``threads``): the parameter row, the
        factors' columns and scales, the input, the step, the recorded instants, the signals, the
        steady window, the time-varying profiles and the precision."""
        h = hashlib.sha256()
        for a in (self.base, np.asarray(self.columns), self.scales, self.u, self.record_at):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
        h.update(repr((float(self.dt), tuple(self.signals), int(self.steady_from), self.precision)).encode())
        for name, profile in sorted((self.time_varying or {}).items()):
            h.update(name.encode())
            h.update(np.ascontiguousarray(profile, dtype=np.float64).tobytes())
        return h.hexdigest()

    @property
    def n_outputs(self) -> int:
        return len(self.signals) * (len(self.record_at) + 1)

    def output_names_and_times(self) -> tuple[tuple[str, ...], tuple[float, ...]]:
        """Output layout: per signal, its value at each recorded instant, then its steady-state
        mean (named ``<signal>_steady`` with time NaN)."""
        t = self.record_at * self.dt
        names, times = [], []
        for s in self.signals:
            names += [s] * len(t) + [f"{s}_steady"]
            times += list(t) + [float("nan")]
        return tuple(names), tuple(times)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """X (n, k) in the study's units -> Y (n, n_outputs): float64, or float32 when the step
        runs in single precision (every value a float32 the step computed, the steady-state
        means rounded to float32; the runner stores such chunks at half the size)."""
        if self.threads is not None:
            numba.set_num_threads(min(self.threads, numba.config.NUMBA_NUM_THREADS))
        params = np.tile(self.base, (X.shape[0], 1))
        params[:, list(self.columns)] = X * self.scales
        # Recorded straight into the output layout: per signal its instants, then a free column
        # for its steady state (no stacking copy of a chunk's outputs).
        n_rec = len(self.record_at)
        Y = np.empty((X.shape[0], len(self.signals), n_rec + 1), np.dtype(self.precision))
        sam.simulate_batch(params, self.u, self.dt, time_varying=self.time_varying, record_at=self.record_at,
                           channels=self.signals, precision=self.precision, out=Y)
        Y[:, :, n_rec] = self._steady_means(Y[:, :, :n_rec])
        return Y.reshape(X.shape[0], -1)

    def _steady_means(self, rec: np.ndarray) -> np.ndarray:
        """(n, n_signals) float64 mean of the recorded instants ``rec`` (n, n_signals, n_rec) from
        ``steady_from`` on (NaN if none), summed in time order."""
        first = int(np.searchsorted(self.record_at, self.steady_from))  # record_at is sorted
        if first == rec.shape[2]:
            return np.full(rec.shape[:2], np.nan)
        total = rec[:, :, first].astype(np.float64)
        for r in range(first + 1, rec.shape[2]):
            total += rec[:, :, r]
        return total / (rec.shape[2] - first)
