"""Monte Carlo estimators of Sobol' indices, vectorised over thousands of outputs.

Every estimator here is a smooth function of *sample means of per-row
quantities*: for base sample m (one row of A, B, AB_i, BA_i) it forms a few
numbers q_j[m] per output, and the indices are a function g of the means
mean_m q_j[m]. Splitting each estimator into

* ``fill``    -- rows -> quantities, shape (N, n_q, M), and
* ``combine`` -- means (..., n_q, M) -> indices (..., G, M),

lets one code path produce the point estimate (plain means), every bootstrap
replicate (means under resample weights: one matrix product, see
:mod:`gsa.bootstrap`) and the jackknife for BCa (leave-one-out means), for all
outputs at once and with no Python loop over outputs.

Notation (Saltelli et al. 2010): f_A, f_B are (N, M) outputs of A and B; f_AB[i],
f_BA[i] are (N, M) outputs of AB_i (A with factor i from B) and BA_i (B with
factor i from A); <q> is the mean over the N base samples; G is the number of
factors. "Centred" estimators first subtract from every output its mean over
all runs of the design, exactly as SALib normalises Y; the indices of those
estimators are ratios of quantities that would otherwise lose digits to
cancellation when an output's mean is large against its spread (pressures in Pa).

Estimators (registry :data:`ESTIMATORS`):

``"saltelli2010-jansen"`` (default)
    S_i  = <f_B (f_AB_i - f_A)> / V                    (Saltelli et al. 2010, Eq. b)
    ST_i = 1/2 <(f_A - f_AB_i)^2> / V                  (Jansen 1999)
    V    = variance of the 2N values [f_A; f_B] (ddof 0)
    Identical to SALib 1.6 ``sobol.analyze`` (same centring, same formulas).

``"janon"`` (Janon et al. 2014), for a pair (y, z) sharing the relevant inputs,
    S(y, z) = (<y z> - <(y+z)/2>^2) / (<(y^2+z^2)/2> - <(y+z)/2>^2);
    S_i = S(f_B, f_AB_i)  (share factor i),  ST_i = 1 - S(f_A, f_AB_i)  (share all but i).
    Asymptotically efficient; good when S_i is large.

``"azzini"`` (Azzini, Mara & Rosati 2020; Azzini & Rosati 2021), needs BA_i:
    D_i  = <(f_A - f_B)^2> + <(f_BA_i - f_AB_i)^2>
    S_i  = 2 <(f_BA_i - f_B)(f_A - f_AB_i)> / D_i
    ST_i = (<(f_B - f_BA_i)^2> + <(f_A - f_AB_i)^2>) / D_i
    Recommended by Puy et al. (2022) among the most accurate; costs N (2G + 2) runs.

``"saltelli2002"`` -- Nurmi & Mattila (2011) Eqs. (33)-(38) as printed, with the
    paper's matrices X1 = B, X2 = A, X3i = AB_i (see :mod:`gsa.design`), raw
    (uncentred) outputs:
    f1^2 = <f(X1) f(X2)>  (35),   V1 = <f(X1)^2> - f1^2  (33),
    f2^2 = <f(X2)>^2      (36),   V2 = <f(X2)^2> - f2^2  (34),
    S_i  = (<f(X1) f(X3i)> - f1^2) / V1                   (37)
    ST_i = 1 - (<f(X2) f(X3i)> - f2^2) / V2               (38)
    Kept for reproducing the paper. Known weaknesses (Saltelli 2002; Sobol' et
    al. 2007; Saltelli et al. 2010): the squared mean estimated from a product of
    two independent samples makes S_i noisy and biased when |E Y| is large
    compared with its standard deviation (errors grow like (E Y)^2 / V), the
    variances differ between (37) and (38), and (38) converges more slowly than
    Jansen's. Use it to compare with the paper, not to decide.

Second order (optional, needs BA_i), Saltelli (2002) as in SALib:
    S_ij = (<f_BA_i f_AB_j> - <f_A f_B>) / V - S_i - S_j   (S_i Saltelli 2010, centred)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from gsa.design import Samples
from gsa.errors import GSAError

#: An output whose values over all runs span at most this many units in the last place
#: (ulps, np.spacing) of its largest magnitude is constant up to rounding: its indices are
#: 0/0 and are reported as NaN. How it was chosen: storing a value rounds it by up to half
#: an ulp, a variance of ulp^2 / 12 against ~range^2 / 12 for values spread over a range, so
#: rounding carries (ulp / range)^2 of the output's variance: 1 % at 10 ulps, and less the
#: wider the spread. An output with a relative spread of 1e-12 (4500 ulps) is computed (as
#: SALib and scipy compute it) and agrees with SALib; below 10 ulps the indices would
#: apportion rounding, not the model.
CONSTANT_ULPS = 10


@dataclass(frozen=True)
class Estimator:
    """One estimator as (rows -> quantities, means -> indices).

    ``fill(s, c, out)`` writes the per-row quantities of samples ``s`` (a
    :class:`~gsa.design.Samples` over a block of Mb outputs, raw values) into ``out``
    of shape (N, n_q(G), Mb); ``c`` (Mb,) is the centring constant (each output's
    mean over all runs), used by centred estimators and None for the others.
    ``combine(m, G)`` maps means of shape (..., n_q, Mb) to a dict of index arrays,
    each (..., G, Mb) (or (..., P, Mb) for the P = G(G-1)/2 pairs).
    """

    name: str
    summary: str
    needs_BA: bool
    centred: bool
    n_q: Callable[[int], int]
    fill: Callable[[Samples, np.ndarray | None, np.ndarray], None]
    combine: Callable[[np.ndarray, int], dict[str, np.ndarray]]


# Centring is folded into each fill (no centred copy of the outputs): differences such
# as f_AB_i - f_A need none, only the factors that multiply are centred.

# -- saltelli2010-jansen --------------------------------------------------------------


def _jansen_fill(s: Samples, c: np.ndarray, out: np.ndarray) -> None:
    a, b = s.f_A - c, s.f_B - c
    G = s.f_AB.shape[0]
    np.add(a, b, out=out[:, 0])
    np.multiply(a, a, out=out[:, 1])
    out[:, 1] += b * b
    for i in range(G):
        d = out[:, 2 + G + i]  # f_AB_i - f_A is built in its final slot, then squared
        np.subtract(s.f_AB[i], s.f_A, out=d)
        np.multiply(b, d, out=out[:, 2 + i])
        np.square(d, out=d)


def _jansen_combine(m: np.ndarray, G: int) -> dict[str, np.ndarray]:
    # var of the 2N values [a; b]: mean of squares minus squared mean (both over 2N).
    V = (0.5 * m[..., 1, :] - (0.5 * m[..., 0, :]) ** 2)[..., None, :]
    return {"S1": m[..., 2 : 2 + G, :] / V, "ST": 0.5 * m[..., 2 + G : 2 + 2 * G, :] / V}


# -- saltelli2002 (the paper) -------------------------------------------------------------


def _paper_fill(s: Samples, c: None, out: np.ndarray) -> None:
    x1, x2, x3 = s.f_B, s.f_A, s.f_AB  # paper roles: X1 = B, X2 = A, X3i = AB_i
    G = x3.shape[0]
    np.multiply(x1, x2, out=out[:, 0])
    np.multiply(x1, x1, out=out[:, 1])
    out[:, 2] = x2
    np.multiply(x2, x2, out=out[:, 3])
    for i in range(G):
        np.multiply(x1, x3[i], out=out[:, 4 + i])
        np.multiply(x2, x3[i], out=out[:, 4 + G + i])


def _paper_combine(m: np.ndarray, G: int) -> dict[str, np.ndarray]:
    f1_sq = m[..., 0, :][..., None, :]  # Eq. (35)
    V1 = m[..., 1, :][..., None, :] - f1_sq  # Eq. (33)
    f2_sq = (m[..., 2, :] ** 2)[..., None, :]  # Eq. (36)
    V2 = m[..., 3, :][..., None, :] - f2_sq  # Eq. (34)
    S1 = (m[..., 4 : 4 + G, :] - f1_sq) / V1  # Eq. (37)
    ST = 1.0 - (m[..., 4 + G : 4 + 2 * G, :] - f2_sq) / V2  # Eq. (38)
    return {"S1": S1, "ST": ST}


# -- janon --------------------------------------------------------------------------------


def _janon_fill(s: Samples, c: np.ndarray, out: np.ndarray) -> None:
    a, b = s.f_A - c, s.f_B - c
    G = s.f_AB.shape[0]
    out[:, 0] = a
    out[:, 1] = b
    np.multiply(a, a, out=out[:, 2])
    np.multiply(b, b, out=out[:, 3])
    for i in range(G):
        z = s.f_AB[i] - c
        out[:, 4 + i] = z
        np.multiply(z, z, out=out[:, 4 + G + i])
        np.multiply(b, z, out=out[:, 4 + 2 * G + i])
        np.multiply(a, z, out=out[:, 4 + 3 * G + i])


def _janon_combine(m: np.ndarray, G: int) -> dict[str, np.ndarray]:
    def pair(y_mean, y_sq, z_mean, z_sq, yz):
        mu_sq = (0.5 * (y_mean + z_mean)) ** 2
        return (yz - mu_sq) / (0.5 * (y_sq + z_sq) - mu_sq)

    a_mean, b_mean = m[..., 0:1, :], m[..., 1:2, :]
    a_sq, b_sq = m[..., 2:3, :], m[..., 3:4, :]
    ab_mean = m[..., 4 : 4 + G, :]
    ab_sq = m[..., 4 + G : 4 + 2 * G, :]
    b_ab = m[..., 4 + 2 * G : 4 + 3 * G, :]
    a_ab = m[..., 4 + 3 * G : 4 + 4 * G, :]
    S1 = pair(b_mean, b_sq, ab_mean, ab_sq, b_ab)  # f_B and f_AB_i share factor i
    ST = 1.0 - pair(a_mean, a_sq, ab_mean, ab_sq, a_ab)  # f_A and f_AB_i share all but i
    return {"S1": S1, "ST": ST}


# -- azzini -------------------------------------------------------------------------------


def _azzini_fill(s: Samples, c: None, out: np.ndarray) -> None:
    a, b, ab, ba = s.f_A, s.f_B, s.f_AB, s.f_BA
    G = ab.shape[0]
    d = a - b
    np.multiply(d, d, out=out[:, 0])
    for i in range(G):
        d = ba[i] - ab[i]
        np.multiply(d, d, out=out[:, 1 + i])
        d_b = ba[i] - b  # varies factor i only, around B
        d_a = a - ab[i]  # varies factor i only, around A
        np.multiply(d_b, d_a, out=out[:, 1 + G + i])
        np.multiply(d_b, d_b, out=out[:, 1 + 2 * G + i])
        out[:, 1 + 2 * G + i] += d_a * d_a


def _azzini_combine(m: np.ndarray, G: int) -> dict[str, np.ndarray]:
    D = m[..., 0:1, :] + m[..., 1 : 1 + G, :]
    return {"S1": 2.0 * m[..., 1 + G : 1 + 2 * G, :] / D, "ST": m[..., 1 + 2 * G :, :] / D}


# -- second order (Saltelli 2002, as SALib) ----------------------------------------------


def pairs(G: int) -> list[tuple[int, int]]:
    """Factor pairs (i, j), i < j, in the order of the ``"S2"`` axis."""
    return list(combinations(range(G), 2))


def _second_fill(s: Samples, c: np.ndarray, out: np.ndarray) -> None:
    a, b = s.f_A - c, s.f_B - c
    G = s.f_AB.shape[0]
    np.add(a, b, out=out[:, 0])
    np.multiply(a, a, out=out[:, 1])
    out[:, 1] += b * b
    np.multiply(a, b, out=out[:, 2])
    for i in range(G):
        np.multiply(b, s.f_AB[i] - s.f_A, out=out[:, 3 + i])
    ab = [s.f_AB[i] - c for i in range(G)]  # each product needs both factors centred
    ba = [s.f_BA[i] - c for i in range(G)]
    for p, (i, j) in enumerate(pairs(G)):
        np.multiply(ba[i], ab[j], out=out[:, 3 + G + p])


def _second_combine(m: np.ndarray, G: int) -> dict[str, np.ndarray]:
    V = (0.5 * m[..., 1, :] - (0.5 * m[..., 0, :]) ** 2)[..., None, :]
    S1 = m[..., 3 : 3 + G, :] / V
    P = pairs(G)
    i = [p[0] for p in P]
    j = [p[1] for p in P]
    V_ij = (m[..., 3 + G : 3 + G + len(P), :] - m[..., 2:3, :]) / V
    return {"S2": V_ij - S1[..., i, :] - S1[..., j, :]}


ESTIMATORS: dict[str, Estimator] = {
    e.name: e
    for e in (
        Estimator(
            "saltelli2010-jansen",
            "S1 Saltelli et al. (2010), ST Jansen (1999); SALib's sobol.analyze",
            needs_BA=False,
            centred=True,
            n_q=lambda G: 2 + 2 * G,
            fill=_jansen_fill,
            combine=_jansen_combine,
        ),
        Estimator(
            "janon",
            "Janon et al. (2014), asymptotically efficient",
            needs_BA=False,
            centred=True,
            n_q=lambda G: 4 + 4 * G,
            fill=_janon_fill,
            combine=_janon_combine,
        ),
        Estimator(
            "azzini",
            "Azzini, Mara & Rosati (2020) / Azzini & Rosati (2021); needs the BA block",
            needs_BA=True,
            centred=False,
            n_q=lambda G: 1 + 3 * G,
            fill=_azzini_fill,
            combine=_azzini_combine,
        ),
        Estimator(
            "saltelli2002",
            "Nurmi & Mattila (2011) Eqs. (33)-(38), Saltelli (2002); for reproduction only",
            needs_BA=False,
            centred=False,
            n_q=lambda G: 4 + 2 * G,
            fill=_paper_fill,
            combine=_paper_combine,
        ),
    )
}
DEFAULT_ESTIMATOR = "saltelli2010-jansen"

SECOND_ORDER = Estimator(
    "saltelli2002-second-order",
    "second-order indices, Saltelli (2002) as in SALib",
    needs_BA=True,
    centred=True,
    n_q=lambda G: 3 + G + G * (G - 1) // 2,
    fill=_second_fill,
    combine=_second_combine,
)


class SobolStatistic:
    """The indices one analysis asks for: an estimator, plus second order if wanted.

    It concatenates the components' quantities so that a single pass (and a single
    matrix product per bootstrap block) serves all of them.
    """

    def __init__(self, estimator: str, G: int, second_order: bool = False):
        self.estimator = get_estimator(estimator)
        self.G = G
        parts = [self.estimator] + ([SECOND_ORDER] if second_order else [])
        self.parts: list[tuple[Estimator, slice]] = []
        start = 0
        for part in parts:
            n = part.n_q(G)
            self.parts.append((part, slice(start, start + n)))
            start += n
        self.n_q = start
        self.needs_BA = any(p.needs_BA for p, _ in self.parts)
        self.needs_centre = any(p.centred for p, _ in self.parts)
        self.second_order = second_order
        self.names = ("S1", "ST") + (("S2",) if second_order else ())

    def n_indices(self, name: str) -> int:
        """Length of the index axis of ``name``: G, or G(G-1)/2 for S2."""
        return self.G * (self.G - 1) // 2 if name == "S2" else self.G

    def fill(self, s: Samples, c: np.ndarray | None, out: np.ndarray) -> None:
        """Quantities (N, n_q, Mb) of one block of outputs; c (Mb,) centres (see Estimator)."""
        for part, sl in self.parts:
            part.fill(s, c if part.centred else None, out[:, sl])

    def indices(self, means: np.ndarray) -> dict[str, np.ndarray]:
        """Indices from means of shape (..., n_q, Mb); each value (..., G or P, Mb)."""
        out: dict[str, np.ndarray] = {}
        with np.errstate(divide="ignore", invalid="ignore"):
            for part, sl in self.parts:
                out.update(part.combine(means[..., sl, :], self.G))
        return out


def get_estimator(name: str) -> Estimator:
    """The registered estimator ``name``; GSAError listing the known ones otherwise."""
    try:
        return ESTIMATORS[name]
    except (KeyError, TypeError):
        raise GSAError(
            f"unknown estimator {name!r} (known: {', '.join(ESTIMATORS)})"
        ) from None


def output_means(s: Samples) -> np.ndarray:
    """Mean of each output over all runs of the design, shape (M,)."""
    total = s.f_A.sum(axis=0) + s.f_B.sum(axis=0) + s.f_AB.sum(axis=(0, 1))
    n = 2 * s.f_A.shape[0] + s.f_AB.shape[0] * s.f_AB.shape[1]
    if s.f_BA is not None:
        total += s.f_BA.sum(axis=(0, 1))
        n += s.f_BA.shape[0] * s.f_BA.shape[1]
    return total / n


def constant_outputs(s: Samples) -> np.ndarray:
    """Boolean (M,): outputs that do not vary over the design (up to rounding)."""
    blocks = [s.f_A, s.f_B, *s.f_AB] + ([] if s.f_BA is None else list(s.f_BA))
    hi = np.max([f.max(axis=0) for f in blocks], axis=0)
    lo = np.min([f.min(axis=0) for f in blocks], axis=0)
    scale = np.maximum(np.abs(hi), np.abs(lo))
    return (hi - lo) <= CONSTANT_ULPS * np.spacing(scale)


def sobol_indices(
    samples: Samples, estimator: str = DEFAULT_ESTIMATOR, second_order: bool = False
) -> dict[str, np.ndarray]:
    """Point estimates for all outputs at once (no confidence intervals).

    Parameters
    ----------
    samples : Samples
        Model outputs by block, f_A (N, M), f_B (N, M), f_AB (G, N, M)[, f_BA (G, N, M)].
    estimator : str
        A key of :data:`ESTIMATORS`.
    second_order : bool
        Also return ``"S2"`` (P, M) for the pairs of :func:`pairs` (needs f_BA).

    Returns
    -------
    dict with ``"S1"``, ``"ST"`` (G, M) [and ``"S2"`` (P, M)], dimensionless.
    Constant outputs give NaN (see :func:`gsa.analyze.analyze` for the warning).
    Memory: O(N n_q M); use :func:`gsa.analyze.analyze` for large M.
    """
    G = samples.f_AB.shape[0]
    stat = SobolStatistic(estimator, G, second_order)
    if stat.needs_BA and samples.f_BA is None:
        raise GSAError(f"estimator {estimator!r} needs the BA block (a design with with_BA=True)")
    c = output_means(samples) if stat.needs_centre else None
    Q = np.empty((samples.f_A.shape[0], stat.n_q, samples.f_A.shape[1]))
    stat.fill(samples, c, Q)
    est = stat.indices(Q.mean(axis=0))
    flat = constant_outputs(samples)
    for v in est.values():
        v[..., flat] = np.nan
    return est


# -- derived measures -------------------------------------------------------------------


def interaction(S1: np.ndarray) -> np.ndarray:
    """1 - sum_i S_i per output, shape (M,) from S1 (G, M): the share of variance
    due to interactions (0 for an additive model), Nurmi & Mattila Sect. 3.3."""
    return 1.0 - S1.sum(axis=0)


def ranking(S: np.ndarray) -> np.ndarray:
    """Factor indices sorted by descending index, per output: (G, M) ints from S (G, M).

    Row 0 holds the most influential factor of each output; NaN sorts last, ties keep
    the factor order.
    """
    return np.argsort(-S, axis=0, kind="stable")


def separated_groups(S: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[list[int]]:
    """One output's factors, most influential first, in groups that the intervals separate.

    ``S``, ``lo``, ``hi`` (G,): the estimates and their interval bounds. Factors are
    sorted by S; the order is cut between two positions only where every factor above
    has its lower bound above the upper bound of every factor below, so each ">" a
    reader sees is backed by disjoint intervals and "tied" means "not separated at
    this confidence". Without intervals (NaN bounds) nothing is separated: one group.
    """
    order = [int(i) for i in np.argsort(-S, kind="stable")]
    low = np.where(np.isfinite(lo), lo, -np.inf)[order]
    high = np.where(np.isfinite(hi), hi, np.inf)[order]
    floor_above = np.minimum.accumulate(low)
    ceil_below = np.maximum.accumulate(high[::-1])[::-1]
    groups, start = [], 0
    for p in range(len(order) - 1):
        if floor_above[p] > ceil_below[p + 1]:
            groups.append(order[start : p + 1])
            start = p + 1
    groups.append(order[start:])
    return groups


def second_order_matrix(S2: np.ndarray, G: int) -> np.ndarray:
    """Expand pairs (P, ...) to a (G, G, ...) matrix with NaN off the upper triangle (as SALib)."""
    out = np.full((G, G) + S2.shape[1:], np.nan)
    for p, (i, j) in enumerate(pairs(G)):
        out[i, j] = S2[p]
    return out

