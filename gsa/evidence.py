"""Published sensitivity results as evidence, and the loss of a model's indices against each.

A paper's tables and statements are the only measurements of some machines we have. Each
:class:`Evidence` item turns one of them into a *loss*: a number, lower is better, computed
from a model's Sobol' indices (or, for a natural frequency, from the model itself), for every
bootstrap replicate at once. The kinds:

* :class:`Ranking` (the paper's Tables 2 and 6): the share of the published pairwise orders a
  model reverses, ``1 - concordance``. A pair of two negligible indices (both below
  ``negligible``) is not reversed: their order is noise, in the paper as in the model.
* :class:`Values` (Tables 4, 7 and 8): the root-mean-square distance to the published indices
  over all instants and factors; per instant in :meth:`Evidence.details`.
* :class:`Interaction` (Table 3): the root-mean-square distance of ``1 - sum S1`` per output.
* :class:`Statement` (the text): a claim written as conditions on indices (:class:`Condition`),
  each with a margin (positive where it holds); the loss is the shortfall ``max(0, -margin)``,
  0 where it holds.
* :class:`Frequency` (Fig. 4): ``|f - f_paper| / f_paper`` of a frequency the caller computes.

Indices come in an :class:`IndexTable`, arrays with a leading replicate axis R (R = 1 for the
point estimate). This module knows nothing about the model: outputs are (signal, instant)
pairs, the instant a time in s or ``"steady"``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np

STEADY = "steady"  #: the instant name of a steady-state output
INDEX_NAMES = ("S1", "ST", "ST-S1")
TRENDS = ("rises", "falls")


def instant_label(instant) -> str:
    """'0.05 s' for a time, 'steady' for the steady state."""
    return STEADY if instant == STEADY else f"{float(instant):g} s"


@dataclass(frozen=True, eq=False)
class StudyIndices:
    """Indices of one sensitivity study: S1 and ST, each (R, G, M), for factors (G,) and
    outputs (M,) named (signal, instant). Undefined indices (an output that did not vary) are
    0: no factor explains variance that is not there."""

    factors: tuple[str, ...]
    outputs: tuple[tuple[str, object], ...]
    S1: np.ndarray
    ST: np.ndarray

    def get(self, index: str, signal: str, instant, factors: Sequence[str]) -> np.ndarray:
        """(R, len(factors)): ``index`` of ``factors`` on one output; "S1", "ST", or "ST-S1" (the
        share of variance a factor explains only through interactions)."""
        j = self.outputs.index((signal, instant))
        rows = [self.factors.index(f) for f in factors]
        if index == "ST-S1":
            return self.ST[:, rows, j] - self.S1[:, rows, j]
        return getattr(self, index)[:, rows, j]


@dataclass(frozen=True, eq=False)
class IndexTable:
    """Everything evidence reads about one model: indices per study, and derived figures
    (e.g. ``{"frequency_hz": f}``) that do not come from a sensitivity study."""

    studies: Mapping[str, StudyIndices]
    figures: Mapping[str, float]
    R: int


@dataclass(frozen=True)
class Evidence:
    """One published result. ``group`` collects items of one kind of evidence for a verdict
    weighted by group (rankings, values, frequency, statements)."""

    id: str
    group: str
    text: str
    headline: bool = True  #: part of the headline verdict (False: scored, and in a second verdict)

    def details(self, table: IndexTable) -> dict[str, np.ndarray]:
        """Label -> (R,): the parts the loss is made of (per output, per instant, ...)."""
        raise NotImplementedError

    def loss(self, table: IndexTable) -> np.ndarray:
        """(R,): lower is better, 0 for a perfect match."""
        raise NotImplementedError


def concordance(values: np.ndarray, order: Sequence[int], negligible: float) -> np.ndarray:
    """(R,): the share of the ordered pairs (order[a] above order[b], a < b) that ``values``
    (R, G) do not reverse; a pair of two values below ``negligible`` is never reversed."""
    score = np.zeros(values.shape[0])
    pairs = list(combinations(order, 2))
    for hi, lo in pairs:
        both_small = (values[:, hi] < negligible) & (values[:, lo] < negligible)
        score += both_small | (values[:, hi] > values[:, lo])
    return score / len(pairs)


@dataclass(frozen=True)
class Ranking(Evidence):
    """A published ranking of factors by one index, per signal, at one instant."""

    study: str = ""
    index: str = "ST"
    instant: object = STEADY
    orders: Mapping[str, tuple[str, ...]] = None  # signal -> factors, most influential first
    negligible: float = 0.01

    def details(self, table):
        s = table.studies[self.study]
        out = {}
        for signal, order in self.orders.items():
            values = s.get(self.index, signal, self.instant, order)
            out[signal] = concordance(values, range(len(order)), self.negligible)
        return out

    def loss(self, table):
        return 1.0 - np.mean(list(self.details(table).values()), axis=0)


@dataclass(frozen=True)
class Values(Evidence):
    """Published values of one index of some factors on one signal at some instants:
    ``values[factor][k]`` at ``instants[k]``."""

    study: str = ""
    index: str = "ST"
    signal: str = ""
    instants: tuple = ()
    values: Mapping[str, tuple[float, ...]] = None

    def _errors(self, table) -> np.ndarray:
        s = table.studies[self.study]
        factors = tuple(self.values)
        paper = np.array([self.values[f] for f in factors])  # (F, T)
        ours = np.stack([s.get(self.index, self.signal, t, factors) for t in self.instants], axis=-1)
        return ours - paper  # (R, F, T)

    def details(self, table):
        err = self._errors(table)
        return {instant_label(t): np.sqrt(np.mean(err[:, :, k] ** 2, axis=1)) for k, t in enumerate(self.instants)}

    def loss(self, table):
        return np.sqrt(np.mean(self._errors(table) ** 2, axis=(1, 2)))


@dataclass(frozen=True)
class Interaction(Evidence):
    """Published ``1 - sum_i S1_i`` per signal at one instant (the paper's Table 3)."""

    study: str = ""
    instant: object = STEADY
    values: Mapping[str, float] = None

    def details(self, table):
        s = table.studies[self.study]
        return {sig: np.abs(1.0 - s.get("S1", sig, self.instant, s.factors).sum(axis=1) - v)
                for sig, v in self.values.items()}

    def loss(self, table):
        return np.sqrt(np.mean(np.square(list(self.details(table).values())), axis=0))


@dataclass(frozen=True)
class Condition:
    """One checkable part of a statement about ``index`` of ``factor`` on ``signal`` at
    ``instants``: at every instant it is at least / at most a threshold, below each of the
    factors ``below``, above each of the factors ``above``, above its own index on each of the signals ``over_signals``; or from the
    first instant to the last it ``trend``s ("rises" / "falls"). :meth:`margin` is positive
    where it holds, in index units (the smallest slack of its parts)."""

    study: str
    index: str
    signal: str
    factor: str
    instants: tuple
    at_least: float | None = None
    at_most: float | None = None
    below: tuple[str, ...] = ()
    above: tuple[str, ...] = ()
    over_signals: tuple[str, ...] = ()
    trend: str | None = None

    def margin(self, table: IndexTable) -> np.ndarray:
        s = table.studies[self.study]

        def at(signal, factors):  # (R, F, T)
            return np.stack([s.get(self.index, signal, t, factors) for t in self.instants], axis=2)

        v = at(self.signal, (self.factor,))[:, 0]  # (R, T)
        parts = []
        if self.at_least is not None:
            parts.append(np.min(v - self.at_least, axis=1))
        if self.at_most is not None:
            parts.append(np.min(self.at_most - v, axis=1))
        if self.below:
            parts.append(np.min(at(self.signal, self.below) - v[:, None, :], axis=(1, 2)))
        if self.above:
            parts.append(np.min(v[:, None, :] - at(self.signal, self.above), axis=(1, 2)))
        for other in self.over_signals:
            parts.append(np.min(v - at(other, (self.factor,))[:, 0], axis=1))
        if self.trend is not None:
            parts.append((v[:, -1] - v[:, 0]) * (1.0 if self.trend == "rises" else -1.0))
        return np.min(parts, axis=0)


@dataclass(frozen=True)
class Statement(Evidence):
    """A qualitative claim of the text, as conditions that must all hold."""

    conditions: tuple[Condition, ...] = ()

    def details(self, table):
        return {"margin": np.min([c.margin(table) for c in self.conditions], axis=0)}

    def loss(self, table):
        return np.maximum(0.0, -self.details(table)["margin"])


@dataclass(frozen=True)
class Frequency(Evidence):
    """A published frequency, read to +- reading_hz; the model's comes in ``table.figures[figure]``."""

    figure: str = "frequency_hz"
    target_hz: float = 1.0
    reading_hz: float = 0.0

    def details(self, table):
        return {"f_hz": np.full(table.R, table.figures[self.figure])}

    def loss(self, table):
        return np.abs(self.details(table)["f_hz"] - self.target_hz) / self.target_hz
