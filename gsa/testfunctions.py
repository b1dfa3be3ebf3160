"""Benchmark functions with analytic Sobol' indices (for tests and demos).

The models follow the runner's contract: ``model(X (n, k)) -> Y (n, M)`` float64,
row-independent, module-level (so they pickle for process and dask executors;
bind parameters with :func:`functools.partial`).
"""

from __future__ import annotations

import numpy as np

from gsa.problem import Problem


# -- Ishigami & Homma (1990) ---------------------------------------------------------


def ishigami_problem() -> Problem:
    """x1, x2, x3 ~ U(-pi, pi)."""
    return Problem(names=("x1", "x2", "x3"), bounds=((-np.pi, np.pi),) * 3)


def ishigami(X: np.ndarray, a: float = 7.0, b: float = 0.1) -> np.ndarray:
    """f = sin x1 + a sin^2 x2 + b x3^4 sin x1; X (n, 3) -> Y (n, 1)."""
    X = np.asarray(X, dtype=np.float64)
    x1, x2, x3 = X[:, 0], X[:, 1], X[:, 2]
    y = np.sin(x1) + a * np.sin(x2) ** 2 + b * x3**4 * np.sin(x1)
    return y[:, None]


def ishigami_indices(a: float = 7.0, b: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Analytic (S1, ST), each (3,). For a=7, b=0.1: S1 = (0.3139, 0.4424, 0),
    ST = (0.5576, 0.4424, 0.2437)."""
    pi4, pi8 = np.pi**4, np.pi**8
    V1 = 0.5 * (1 + b * pi4 / 5) ** 2
    V2 = a**2 / 8
    V13 = b**2 * pi8 * (1 / 18 - 1 / 50)  # = 8 b^2 pi^8 / 225
    V = V1 + V2 + V13
    S1 = np.array([V1, V2, 0.0]) / V
    ST = np.array([V1 + V13, V2, V13]) / V
    return S1, ST


# -- Sobol' G function --------------------------------------------------------------------


def sobol_g_problem(k: int) -> Problem:
    """x_i ~ U(0, 1), i = 1..k."""
    return Problem(names=tuple(f"x{i + 1}" for i in range(k)), bounds=((0.0, 1.0),) * k)


def sobol_g(X: np.ndarray, a) -> np.ndarray:
    """f = prod_i (|4 x_i - 2| + a_i) / (1 + a_i); X (n, k) -> Y (n, 1)."""
    X = np.asarray(X, dtype=np.float64)
    a = np.asarray(a, dtype=np.float64)
    return np.prod((np.abs(4 * X - 2) + a) / (1 + a), axis=1)[:, None]


def sobol_g_indices(a) -> tuple[np.ndarray, np.ndarray]:
    """Analytic (S1, ST), each (k,): V_i = 1 / (3 (1 + a_i)^2), V = prod(1 + V_i) - 1."""
    a = np.asarray(a, dtype=np.float64)
    Vi = 1.0 / (3.0 * (1.0 + a) ** 2)
    V = np.prod(1.0 + Vi) - 1.0
    S1 = Vi / V
    ST = Vi * np.prod(1.0 + Vi) / (1.0 + Vi) / V
    return S1, ST


# -- linear additive model ---------------------------------------------------------------


def linear(X: np.ndarray, c) -> np.ndarray:
    """f = sum_i c_i x_i; X (n, k) -> Y (n, 1). Additive: S1 = ST = c_i^2 V(x_i) / V(f)."""
    return (np.asarray(X, dtype=np.float64) @ np.asarray(c, dtype=np.float64))[:, None]


def linear_indices(c, variances) -> np.ndarray:
    """Analytic S1 (= ST) of :func:`linear` for independent inputs with the given variances."""
    w = np.asarray(c, dtype=np.float64) ** 2 * np.asarray(variances, dtype=np.float64)
    return w / w.sum()
