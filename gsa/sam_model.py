"""The SAM model as a GSA model: parameter rows in, time-resolved outputs out.

This is where the generic engine meets the hydraulics: a picklable callable
``SamModel(X) -> Y`` that writes each sampled parameter into its column of the
plant's parameter vector, runs the whole chunk through :func:`sam.simulate_batch`
and returns the outputs at the requested instants, plus a steady-state value.
"""

from __future__ import annotations

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
        """X (n, k) in the study's units -> Y (n, n_outputs)."""
        if self.threads is not None:
            numba.set_num_threads(min(self.threads, numba.config.NUMBA_NUM_THREADS))
        params = np.tile(self.base, (X.shape[0], 1))
        params[:, list(self.columns)] = X * self.scales
        res = sam.simulate_batch(params, self.u, self.dt, time_varying=self.time_varying,
                                 record_at=self.record_at, channels=self.signals, precision=self.precision)
        steady = self.record_at >= self.steady_from
        blocks = []
        for s in self.signals:
            blocks += [res[s], res[s][:, steady].mean(axis=1, keepdims=True)]
        return np.hstack(blocks)
