"""Percentiles, defined once, and the summary of many values built on them (docs/design.md,
"Statistics").

The q-quantile of n values is the value at rank ⌈q·n⌉ (at least 1) of them sorted
ascending: the smallest value with at least a fraction q of all values at or below it (the
nearest-rank definition; NumPy's method "inverted_cdf"). It is always a value that occurred.

    Distribution.of([125, 0, 62, 3000])   # count, mean, P1, P50, P99, max (µs)
    quantile(sorted(values), 0.999); median(values)
    histogram = Histogram(); histogram.add(953); histogram.summary()
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Protocol, SupportsFloat

DEFINITION = "nearest rank: the value at rank ⌈q·n⌉ of n sorted values (NumPy 'inverted_cdf')"
"""The one definition, as reports state it."""
_DENOMINATOR = 1_000_000
"""q is taken as the nearest fraction with at most this denominator: 0.07 is 7/100 exactly,
so ⌈0.07·100⌉ is 7, not the 8 floating point makes of it (7.000000000000001)."""


class Ordered(Protocol):
    """Values sorted ascending that can be indexed: a list, a tuple, a sorted NumPy array."""

    def __len__(self) -> int: ...

    def __getitem__(self, index: int, /) -> SupportsFloat: ...


def rank(q: float, count: int) -> int:
    """The index (from 0) of the q-quantile among `count` values sorted ascending."""
    if not 0.0 <= q <= 1.0:
        raise ValueError(f"a quantile is of 0 to 1, not {q!r}")
    if count < 1:
        raise ValueError("no values: no quantile")
    return max(1, math.ceil(Fraction(q).limit_denominator(_DENOMINATOR) * count)) - 1


def quantile(ordered: Ordered, q: float) -> float:
    """The q-quantile of `ordered` (sorted ascending, at least one value)."""
    return float(ordered[rank(q, len(ordered))])


def median(values: Iterable[float]) -> float:
    """P50 of `values` (any order, at least one): with an even count, the lower middle one."""
    return quantile(sorted(values), 0.5)


@dataclass(frozen=True)
class Distribution:
    """Many values in a few figures, in µs (every duration wftool sums up is): how many,
    their mean, P1, P50, P99 and the largest."""

    count: int
    mean_us: float
    p1_us: float
    p50_us: float
    p99_us: float
    max_us: float

    @property
    def spread_us(self) -> float:
        """P99 − P1: the jitter figure verdicts judge."""
        return self.p99_us - self.p1_us

    @property
    def rate_hz(self) -> float | None:
        """The rate intervals of this distribution make (1 / mean); None for a zero mean."""
        return 1e6 / self.mean_us if self.mean_us > 0 else None

    @classmethod
    def of(cls, values_us: Iterable[float]) -> Distribution | None:
        """The distribution of `values_us` (any order); None for none."""
        ordered = sorted(values_us)
        return cls.of_sorted(ordered) if ordered else None

    @classmethod
    def of_sorted(cls, ordered: Ordered, mean_us: float | None = None) -> Distribution:
        """The distribution of `ordered` (sorted ascending, at least one value); `mean_us`
        if its caller has it (NumPy's), else their exact mean."""
        count = len(ordered)
        if mean_us is None:
            mean_us = math.fsum(float(ordered[i]) for i in range(count)) / count
        return cls(
            count,
            float(mean_us),
            quantile(ordered, 0.01),
            quantile(ordered, 0.5),
            quantile(ordered, 0.99),
            float(ordered[count - 1]),
        )


class Histogram:
    """Whole numbers (intervals in µs) counted by value: exact quantiles in memory bounded by
    the number of distinct values, not by how many there are."""

    def __init__(self) -> None:
        self._counts: Counter[int] = Counter()
        self._total = 0
        self._sum = 0

    def add(self, value: int) -> None:
        self._counts[value] += 1
        self._total += 1
        self._sum += value

    def quantiles(self, qs: Sequence[float]) -> list[float]:
        """The `qs`-quantiles (each of 0 to 1, ascending) of the values added (at least one)."""
        wanted = [rank(q, self._total) for q in qs]
        found: list[float] = []
        seen = 0
        for value in sorted(self._counts):
            seen += self._counts[value]
            while len(found) < len(wanted) and wanted[len(found)] < seen:
                found.append(float(value))
        return found

    def summary(self) -> Distribution | None:
        """The distribution of the values added; None before the first."""
        if not self._total:
            return None
        p1, p50, p99, top = self.quantiles((0.01, 0.5, 0.99, 1.0))
        return Distribution(self._total, self._sum / self._total, p1, p50, p99, top)
