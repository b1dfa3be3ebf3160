"""Model runs that returned NaN or inf: find them and say which they are.

Policy (shared by the runner and the analysis): such runs are never dropped
silently and never allowed into an estimator, where one NaN would poison every
index of its output. By default they raise a :class:`~gsa.errors.GSAError`
listing the count and the first parameter rows; dropping the affected base
samples is an explicit opt-in of :func:`gsa.analyze.analyze`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsa.design import Design

_ROWS_PER_PASS = 4096  # bounds the temporary boolean array of the scan


def nonfinite_mask(Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(bad_runs (n_runs,), bad_outputs (M,)) booleans: any NaN/inf in that row / column."""
    bad_runs = np.zeros(Y.shape[0], dtype=bool)
    bad_outputs = np.zeros(Y.shape[1], dtype=bool)
    for r0 in range(0, Y.shape[0], _ROWS_PER_PASS):
        bad = ~np.isfinite(Y[r0 : r0 + _ROWS_PER_PASS])
        bad_runs[r0 : r0 + _ROWS_PER_PASS] = bad.any(axis=1)
        bad_outputs |= bad.any(axis=0)
    return bad_runs, bad_outputs


@dataclass(frozen=True, eq=False)
class NonFiniteReport:
    """Which runs returned NaN/inf, with their parameter rows.

    Attributes
    ----------
    runs : (n_bad,) int -- run indices (rows of the design's X and of Y)
    X : (n_bad, k) float -- their parameter values
    blocks : tuple[str] -- design block of each run ("A", "B", "AB_2", ...)
    samples : (n_bad,) int -- base-sample index m of each run
    outputs : (n_out,) int -- outputs with at least one non-finite value
    """

    runs: np.ndarray
    X: np.ndarray
    blocks: tuple[str, ...]
    samples: np.ndarray
    outputs: np.ndarray
    n_runs: int
    parameter_names: tuple[str, ...]
    output_names: tuple[str, ...]

    @classmethod
    def from_outputs(cls, design: Design, Y: np.ndarray, output_names=None) -> NonFiniteReport:
        bad_runs, bad_outputs = nonfinite_mask(Y)
        runs = np.flatnonzero(bad_runs)
        located = [design.locate(int(r)) for r in runs]
        names = tuple(output_names) if output_names is not None else tuple(
            f"y{j}" for j in range(Y.shape[1])
        )
        return cls(
            runs=runs,
            X=np.array(design.X[runs]),
            blocks=tuple(b for b, _ in located),
            samples=np.array([m for _, m in located], dtype=np.intp),
            outputs=np.flatnonzero(bad_outputs),
            n_runs=design.n_runs,
            parameter_names=design.problem.names,
            output_names=names,
        )

    @property
    def count(self) -> int:
        return len(self.runs)

    def __bool__(self) -> bool:
        return self.count > 0

    def summary(self, max_rows: int = 5) -> str:
        """One paragraph for an error message: count, outputs, first parameter rows."""
        if not self:
            return "all model runs returned finite values"
        outs = ", ".join(repr(self.output_names[j]) for j in self.outputs[:5])
        more = f" and {len(self.outputs) - 5} more" if len(self.outputs) > 5 else ""
        lines = [
            f"the model returned NaN/inf in {self.count} of {self.n_runs} runs "
            f"(outputs affected: {len(self.outputs)}: {outs}{more}); first rows:"
        ]
        for r, block, m, x in list(zip(self.runs, self.blocks, self.samples, self.X))[:max_rows]:
            values = ", ".join(f"{n}={v:.6g}" for n, v in zip(self.parameter_names, x))
            lines.append(f"  run {r} ({block}, sample {m}): {values}")
        if self.count > max_rows:
            lines.append(f"  ... {self.count - max_rows} more")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-able form (written as nonfinite.json by the runner)."""
        return {
            "count": self.count,
            "n_runs": self.n_runs,
            "outputs": [self.output_names[j] for j in self.outputs],
            "runs": [
                {
                    "run": int(r),
                    "block": block,
                    "sample": int(m),
                    "parameters": dict(zip(self.parameter_names, map(float, x))),
                }
                for r, block, m, x in zip(self.runs, self.blocks, self.samples, self.X)
            ],
        }
