"""The uncertain inputs of a sensitivity study: names, distributions, groups.

A :class:`Problem` is immutable and validated once, when it is built; everything
downstream (design, runner, estimators) trusts it.

Distributions, one per parameter, with what ``bounds[i]`` holds for each. The
layouts are SALib's, so a SALib problem means the same here; SALib's names
(in brackets) are accepted and stored under ours:

=========================  =========================  ==========================================
``dists[i]``               ``bounds[i]``              meaning
=========================  =========================  ==========================================
uniform (unif)             ``(lo, hi)``               U(lo, hi), lo < hi
loguniform (logunif)       ``(lo, hi)``               log X ~ U(log lo, log hi), 0 < lo < hi
normal (norm)              ``(mean, sd)``             N(mean, sd^2), sd > 0
truncnormal (truncnorm)    ``(lo, hi, mean, sd)``     N(mean, sd^2) truncated to [lo, hi], lo < hi
lognormal (lognorm)        ``(mu, sigma)``            ln X ~ N(mu, sigma^2), sigma > 0 (natural log)
triangular (triang)        ``(lo, hi, c)``            triangular on [lo, hi], peak at lo + c (hi - lo), 0 <= c <= 1
=========================  =========================  ==========================================

(A 4-value ``normal`` is refused: it was once (mean, sd, lo, hi) here while SALib's
truncated normal is (lo, hi, mean, sd), and one layout read as the other is a
valid but different distribution.)

Values are in the parameter's own unit; the engine never looks at units.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import stats

from gsa.errors import GSAError

DISTRIBUTIONS = ("uniform", "loguniform", "normal", "truncnormal", "lognormal", "triangular")
#: SALib's distribution names -> ours (same layout of ``bounds``)
SALIB_NAMES = {"unif": "uniform", "logunif": "loguniform", "norm": "normal", "truncnorm": "truncnormal",
               "lognorm": "lognormal", "triang": "triangular"}
_N_VALUES = {"uniform": 2, "loguniform": 2, "normal": 2, "truncnormal": 4, "lognormal": 2, "triangular": 3}
_LAYOUT = {"uniform": "(lo, hi)", "loguniform": "(lo, hi)", "normal": "(mean, sd)",
           "truncnormal": "(lo, hi, mean, sd)", "lognormal": "(mu, sigma) of ln X", "triangular": "(lo, hi, c)"}

# U = 0 or 1 maps to -inf/+inf through an unbounded ppf; a scrambled Sobol' point can
# hit 0 exactly (its values are multiples of 2^-bits), so such U are nudged inwards.
_U_MIN = 2.0**-53
_U_MAX = 1.0 - 2.0**-53


@dataclass(frozen=True)
class Problem:
    """k uncertain parameters and, optionally, how they are grouped.

    Attributes
    ----------
    names : tuple[str, ...]
        Parameter names, unique and non-empty, length k.
    bounds : tuple[tuple[float, ...], ...]
        Distribution parameters per parameter (see the module docstring).
    dists : tuple[str, ...]
        Distribution name per parameter; ``None`` when building means all uniform.
    groups : tuple[str, ...] | None
        Group name per parameter. With groups, indices are computed per group
        (parameters of a group are resampled together) and "factor" below means
        group; without, a factor is a parameter.
    """

    names: tuple[str, ...]
    bounds: tuple[tuple[float, ...], ...]
    dists: tuple[str, ...] | None = None
    groups: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        names = _as_names(self.names)
        k = len(names)
        dists = ("uniform",) * k if self.dists is None else _as_dists(self.dists, names)
        bounds = _as_bounds(self.bounds, names, dists)
        groups = None if self.groups is None else _as_groups(self.groups, names)
        # Frozen dataclass: normalise the fields in place once (lists -> tuples).
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "dists", dists)
        object.__setattr__(self, "bounds", bounds)
        object.__setattr__(self, "groups", groups)

    # -- construction -------------------------------------------------------------
    @classmethod
    def from_dict(cls, spec: Mapping) -> Problem:
        """Build from a SALib problem dict ``{"num_vars"?, "names", "bounds", "dists"?, "groups"?,
        "outputs"?}`` (SALib's distribution names and layouts; ``outputs`` names the model's
        outputs and is not part of a Problem)."""
        if not isinstance(spec, Mapping):
            raise GSAError(f"a problem must be a mapping, got {type(spec).__name__}")
        unknown = sorted(set(spec) - {"names", "bounds", "dists", "groups", "num_vars", "outputs"})
        if unknown:
            raise GSAError(
                f"problem: unknown key(s) {unknown}; expected names, bounds, dists, groups (num_vars, outputs)"
            )
        for key in ("names", "bounds"):
            if key not in spec:
                raise GSAError(f"problem: missing key '{key}'")
        names = spec["names"]
        if "num_vars" in spec and (not isinstance(names, Sequence) or spec["num_vars"] != len(names)):
            raise GSAError(f"problem: num_vars is {spec['num_vars']!r} but names lists "
                           f"{len(names) if isinstance(names, Sequence) else 'no'} parameters")
        return cls(
            names=names,
            bounds=spec["bounds"],
            dists=spec.get("dists"),
            groups=spec.get("groups"),
        )

    def to_dict(self) -> dict:
        """Plain JSON-able form (used in run fingerprints); inverse of :meth:`from_dict`."""
        return {
            "names": list(self.names),
            "bounds": [list(b) for b in self.bounds],
            "dists": list(self.dists),
            "groups": None if self.groups is None else list(self.groups),
        }

    def to_salib(self) -> dict:
        """The same problem as SALib's problem dict (its distribution names)."""
        salib = {ours: theirs for theirs, ours in SALIB_NAMES.items()}
        return {
            "num_vars": self.k,
            "names": list(self.names),
            "bounds": [list(b) for b in self.bounds],
            "dists": [salib[d] for d in self.dists],
            "groups": None if self.groups is None else list(self.groups),
        }

    # -- shape ------------------------------------------------------------------
    @property
    def k(self) -> int:
        """Number of parameters (columns of X)."""
        return len(self.names)

    @cached_property
    def factor_names(self) -> tuple[str, ...]:
        """Names of the factors indices are reported for: groups (first-seen order) or parameters."""
        if self.groups is None:
            return self.names
        return tuple(dict.fromkeys(self.groups))

    @property
    def n_factors(self) -> int:
        """Number of factors G (= k without groups)."""
        return len(self.factor_names)

    @cached_property
    def factor_columns(self) -> tuple[tuple[int, ...], ...]:
        """Column indices of X belonging to each factor, length G."""
        if self.groups is None:
            return tuple((i,) for i in range(self.k))
        return tuple(
            tuple(i for i, g in enumerate(self.groups) if g == name) for name in self.factor_names
        )

    # -- sampling ---------------------------------------------------------------
    def transform(self, U: np.ndarray) -> np.ndarray:
        """Map unit-cube samples to parameter space by each marginal's inverse CDF.

        Parameters
        ----------
        U : (n, k) array in [0, 1)

        Returns
        -------
        X : (n, k) float64 array, in the parameters' units.

        The map is elementwise, so a row's value never depends on the other rows.
        """
        U = np.asarray(U, dtype=np.float64)
        if U.ndim != 2 or U.shape[1] != self.k:
            raise GSAError(f"transform expects U of shape (n, {self.k}), got {U.shape}")
        X = np.empty_like(U)
        for i, (dist, b) in enumerate(zip(self.dists, self.bounds)):
            X[:, i] = _marginal(dist, b).ppf(_clip_unbounded(dist, b, U[:, i]))
        return X


# ----------------------------------------------------------------------------------
# Validation helpers: each raises GSAError naming the parameter and the value.


def _as_names(names) -> tuple[str, ...]:
    if isinstance(names, str) or not isinstance(names, Sequence):
        raise GSAError(f"problem: names must be a list of strings, got {names!r}")
    if len(names) == 0:
        raise GSAError("problem: needs at least one parameter, names is empty")
    seen: dict[str, int] = {}
    for pos, name in enumerate(names):
        if not isinstance(name, str) or not name.strip():
            raise GSAError(f"problem: parameter #{pos + 1} needs a non-empty name, got {name!r}")
        if name in seen:
            raise GSAError(
                f"problem: duplicate parameter name '{name}' (positions {seen[name] + 1} and {pos + 1})"
            )
        seen[name] = pos
    return tuple(names)


def _as_dists(dists, names) -> tuple[str, ...]:
    if isinstance(dists, str) or not isinstance(dists, Sequence) or len(dists) != len(names):
        raise GSAError(
            f"problem: dists must list one distribution per parameter ({len(names)}), got {dists!r}"
        )
    out = []
    for name, dist in zip(names, dists):
        dist = SALIB_NAMES.get(dist, dist) if isinstance(dist, str) else dist
        if dist not in DISTRIBUTIONS:
            raise GSAError(
                f"parameter '{name}': unknown distribution {dist!r} (known: {', '.join(DISTRIBUTIONS)}, "
                f"or SALib's {', '.join(SALIB_NAMES)})"
            )
        out.append(dist)
    return tuple(out)


def _as_bounds(bounds, names, dists) -> tuple[tuple[float, ...], ...]:
    if not isinstance(bounds, Sequence) or len(bounds) != len(names):
        n = len(bounds) if isinstance(bounds, Sequence) else "no"
        raise GSAError(f"problem: bounds has {n} entries but there are {len(names)} parameters")
    out = []
    for name, dist, b in zip(names, dists, bounds):
        try:
            values = tuple(float(v) for v in b)
        except (TypeError, ValueError):
            raise GSAError(f"parameter '{name}': bounds must be numbers, got {b!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise GSAError(f"parameter '{name}': bounds must be finite, got {b!r}")
        _check_marginal(name, dist, values)
        out.append(values)
    return tuple(out)


def _check_marginal(name: str, dist: str, b: tuple[float, ...]) -> None:
    if len(b) != _N_VALUES[dist]:
        hint = (" (a truncated normal is 'truncnormal' with (lo, hi, mean, sd), SALib's order)"
                if dist == "normal" and len(b) == 4 else "")
        raise GSAError(f"parameter '{name}': {dist} needs bounds {_LAYOUT[dist]}, got {b}{hint}")
    if dist in ("uniform", "loguniform", "truncnormal", "triangular"):
        lo, hi = b[0], b[1]
        if not lo < hi:
            raise GSAError(
                f"parameter '{name}': lower bound must be below upper bound, got lo={lo:g}, hi={hi:g}"
            )
        if dist == "loguniform" and lo <= 0:
            raise GSAError(f"parameter '{name}': loguniform needs lo > 0, got lo={lo:g}")
    if dist in ("normal", "lognormal") and not b[1] > 0:
        raise GSAError(f"parameter '{name}': {dist} needs {'sd' if dist == 'normal' else 'sigma'} > 0, "
                       f"got {'sd' if dist == 'normal' else 'sigma'}={b[1]:g}")
    if dist == "truncnormal" and not b[3] > 0:
        raise GSAError(f"parameter '{name}': truncnormal needs sd > 0, got sd={b[3]:g}")
    if dist == "triangular" and not 0 <= b[2] <= 1:
        raise GSAError(f"parameter '{name}': triangular needs the peak's position c in [0, 1] "
                       f"(a fraction of hi - lo), got c={b[2]:g}")


def _as_groups(groups, names) -> tuple[str, ...]:
    if isinstance(groups, str) or not isinstance(groups, Sequence) or len(groups) != len(names):
        raise GSAError(
            f"problem: groups must give one group name per parameter ({len(names)}), got {groups!r}"
        )
    for name, g in zip(names, groups):
        if not isinstance(g, str) or not g.strip():
            raise GSAError(f"parameter '{name}': group name must be a non-empty string, got {g!r}")
    return tuple(groups)


def _marginal(dist: str, b: tuple[float, ...]):
    """Frozen scipy.stats distribution of one parameter."""
    if dist == "uniform":
        return stats.uniform(loc=b[0], scale=b[1] - b[0])
    if dist == "loguniform":
        return stats.loguniform(b[0], b[1])
    if dist == "normal":
        return stats.norm(loc=b[0], scale=b[1])
    if dist == "truncnormal":
        lo, hi, mean, sd = b
        return stats.truncnorm((lo - mean) / sd, (hi - mean) / sd, loc=mean, scale=sd)
    if dist == "lognormal":
        return stats.lognorm(s=b[1], scale=math.exp(b[0]))
    return stats.triang(c=b[2], loc=b[0], scale=b[1] - b[0])


def _clip_unbounded(dist: str, b: tuple[float, ...], u: np.ndarray) -> np.ndarray:
    if dist in ("normal", "lognormal"):
        return np.clip(u, _U_MIN, _U_MAX)
    return u
