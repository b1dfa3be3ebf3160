"""Saltelli's radial ("pick-freeze") sample design on a scrambled Sobol' sequence.

One scrambled Sobol' point set of dimension 2k and size N is split into two
independent unit-cube matrices, A (first k columns) and B (last k columns). For
every factor i (a parameter, or a group of parameters) two cross matrices are
defined (Saltelli et al. 2010 notation):

* ``AB_i`` -- A with the column(s) of factor i taken from B
* ``BA_i`` -- B with the column(s) of factor i taken from A (only when asked for)

The run matrix X stacks the blocks in this fixed order, N rows each::

    [A; B; AB_1; ...; AB_G]                    N (G + 2) runs
    [A; B; AB_1; ...; AB_G; BA_1; ...; BA_G]   N (2G + 2) runs  (second order / Azzini)

so run r belongs to block r // N and base sample m = r % N. The order is part
of the on-disk format of the runner and must not change.

Mapping to Nurmi & Mattila (2011), Sect. 3.2, where ``X3i`` is "X2 with the
i-th column taken from X1": any labelling of the two independent halves is
equally valid, and the one that needs no extra runs is

    paper X1 = B,    paper X2 = A,    paper X3i = AB_i

(X3i = AB_i = A with column i from B = X2 with column i from X1). With the
literal labelling X1 = A, X2 = B one would need the BA_i block instead; the
two are the same estimator applied to exchangeable samples. The estimator
``"saltelli2002"`` in :mod:`gsa.estimators` uses the mapping above.
"""

from __future__ import annotations

import hashlib
import numbers
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple

import numpy as np
from scipy.stats import qmc

from gsa.errors import GSAError, SamplingWarning
from gsa.problem import Problem


class Samples(NamedTuple):
    """Model outputs split by design block (views into Y, no copies).

    Shapes: ``f_A``, ``f_B``: (N, M); ``f_AB``, ``f_BA``: (G, N, M); ``f_BA`` is
    None when the design has no BA block. M is the number of outputs.
    """

    f_A: np.ndarray
    f_B: np.ndarray
    f_AB: np.ndarray
    f_BA: np.ndarray | None


@dataclass(frozen=True, eq=False)
class Design:
    """A sample design: unit-cube matrices A, B (N, k) and the block layout.

    Build it with :func:`saltelli_design`; it is fully determined by
    ``(problem, N, seed, with_BA)``.
    """

    problem: Problem
    N: int
    seed: int
    second_order: bool
    with_BA: bool
    A: np.ndarray = field(repr=False)  #: (N, k) unit-cube samples, first half of the Sobol' points
    B: np.ndarray = field(repr=False)  #: (N, k) unit-cube samples, second half

    # -- layout -------------------------------------------------------------------
    @property
    def G(self) -> int:
        """Number of factors (parameters, or groups)."""
        return self.problem.n_factors

    @cached_property
    def block_names(self) -> tuple[str, ...]:
        """Block names in run order: A, B, AB_1..AB_G[, BA_1..BA_G] (1-based factor numbers)."""
        names = ["A", "B"] + [f"AB_{i + 1}" for i in range(self.G)]
        if self.with_BA:
            names += [f"BA_{i + 1}" for i in range(self.G)]
        return tuple(names)

    @property
    def n_blocks(self) -> int:
        return len(self.block_names)

    @property
    def n_runs(self) -> int:
        """Total model runs: N (G + 2), or N (2G + 2) with the BA block."""
        return self.N * self.n_blocks

    def locate(self, run: int) -> tuple[str, int]:
        """Block name and base-sample index m of run index ``run``."""
        return self.block_names[run // self.N], run % self.N

    # -- matrices -----------------------------------------------------------------
    def unit_block(self, j: int) -> np.ndarray:
        """Unit-cube matrix (N, k) of block number j (0 = A, 1 = B, 2.. = AB_i, then BA_i)."""
        if j == 0:
            return self.A
        if j == 1:
            return self.B
        i, from_B = (j - 2, True) if j < 2 + self.G else (j - 2 - self.G, False)
        cols = list(self.problem.factor_columns[i])
        base, donor = (self.A, self.B) if from_B else (self.B, self.A)
        U = base.copy()
        U[:, cols] = donor[:, cols]
        return U

    @cached_property
    def U(self) -> np.ndarray:
        """Full unit-cube run matrix (n_runs, k) in block order."""
        return np.concatenate([self.unit_block(j) for j in range(self.n_blocks)])

    @cached_property
    def X(self) -> np.ndarray:
        """Full run matrix (n_runs, k) in parameter units, in block order.

        Computed once for the whole design, so chunking can never change a value.
        """
        X = self.problem.transform(self.U)
        X.setflags(write=False)
        return X

    def rows(self, start: int, stop: int) -> np.ndarray:
        """Runs ``start:stop`` of :attr:`X` (a read-only view)."""
        return self.X[start:stop]

    def split(self, Y: np.ndarray) -> Samples:
        """Split outputs Y (n_runs, M) into the blocks, as views.

        Y must be validated (shape, dtype) by the caller.
        """
        N, G, M = self.N, self.G, Y.shape[1]
        f_AB = Y[2 * N : (2 + G) * N].reshape(G, N, M)
        f_BA = Y[(2 + G) * N : (2 + 2 * G) * N].reshape(G, N, M) if self.with_BA else None
        return Samples(Y[:N], Y[N : 2 * N], f_AB, f_BA)

    # -- identity -----------------------------------------------------------------
    @cached_property
    def sha256(self) -> str:
        """Hash of the unit-cube samples: changes if the sampler ever produces other points."""
        h = hashlib.sha256()
        for M in (self.A, self.B):
            h.update(np.ascontiguousarray(M, dtype="<f8").tobytes())
        return h.hexdigest()

    def fingerprint(self) -> dict:
        """JSON-able identity of the design (what a resumed run must share)."""
        return {
            "problem": self.problem.to_dict(),
            "N": self.N,
            "seed": self.seed,
            "second_order": self.second_order,
            "with_BA": self.with_BA,
            "n_runs": self.n_runs,
            "design_sha256": self.sha256,
        }


def is_power_of_two(n: int) -> bool:
    return n > 0 and n & (n - 1) == 0


def saltelli_design(
    problem: Problem,
    N: int,
    seed: int,
    second_order: bool = False,
    *,
    with_BA: bool | None = None,
) -> Design:
    """Sample design for Sobol' indices from one scrambled Sobol' point set.

    Parameters
    ----------
    problem : Problem
    N : int >= 2
        Base sample size (rows of A and B). Powers of two keep the Sobol'
        sequence's balance; other N work but emit one :class:`SamplingWarning`.
    seed : int >= 0
        Seed of the scrambling (``scipy.stats.qmc.Sobol(..., rng=seed)``).
    second_order : bool
        Also prepare second-order indices (adds the BA block).
    with_BA : bool, optional
        Add the BA block without second-order indices (needed by ``"azzini"``).
        Defaults to ``second_order``; cannot be False when ``second_order`` is True.

    Returns
    -------
    Design with N (G + 2) runs, or N (2G + 2) with the BA block.
    """
    if isinstance(N, bool) or not isinstance(N, numbers.Integral) or N < 2:
        raise GSAError(f"design: N (base sample size) must be an integer >= 2, got {N!r}")
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise GSAError(f"design: seed must be a non-negative integer, got {seed!r}")
    if with_BA is None:
        with_BA = bool(second_order)
    if second_order and not with_BA:
        raise GSAError("design: second-order indices need the BA block; do not pass with_BA=False")
    N, seed, k = int(N), int(seed), problem.k

    if not is_power_of_two(N):
        lower, upper = 1 << (N.bit_length() - 1), 1 << N.bit_length()
        warnings.warn(
            f"N={N} is not a power of two: the Sobol' sequence's balance (stratification) "
            f"properties, and with them its faster-than-Monte-Carlo convergence, hold only "
            f"for N = 2^m. Consider N={lower} or N={upper}.",
            SamplingWarning,
            stacklevel=2,
        )
    try:
        sobol = qmc.Sobol(d=2 * k, scramble=True, rng=seed)
    except TypeError:  # scipy < 1.15 calls it seed; both mean default_rng(seed)
        sobol = qmc.Sobol(d=2 * k, scramble=True, seed=seed)
    with warnings.catch_warnings():
        # scipy raises its own balance warning for the same reason; ours (above) says it once.
        warnings.filterwarnings("ignore", message=".*balance properties.*", category=UserWarning)
        base = sobol.random(N)
    A = np.ascontiguousarray(base[:, :k])
    B = np.ascontiguousarray(base[:, k:])
    A.setflags(write=False)
    B.setflags(write=False)
    return Design(problem, N, seed, bool(second_order), bool(with_BA), A, B)
