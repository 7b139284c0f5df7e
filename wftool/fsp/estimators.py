"""The clock estimators by name, as `--clock` and `StateDecoder(clock=...)` take them.

make_estimator("kalman")   # the paper's filter; "envelope" (default), "twoway"
"""

from __future__ import annotations

from collections.abc import Callable

from wftool.errors import UsageError
from wftool.fsp.clock import ClockEstimator, EnvelopeClockEstimator, KalmanClockEstimator
from wftool.fsp.twoway import TwoWayClockEstimator

ONE_WAY_ESTIMATORS: tuple[str, ...] = ("envelope", "kalman")
"""Those that need nothing but the stream; the first is the default."""
ESTIMATORS: tuple[str, ...] = (*ONE_WAY_ESTIMATORS, "twoway")
"""Estimator names for `make_estimator` (and `--clock`): "twoway" takes the FC's time replies
too (spec §8.3, §10), and without them is its one-way line."""
_FACTORIES: dict[str, Callable[[], ClockEstimator]] = {
    "envelope": EnvelopeClockEstimator,
    "kalman": KalmanClockEstimator,
    "twoway": TwoWayClockEstimator,
}


def make_estimator(name: str = ESTIMATORS[0]) -> ClockEstimator:
    """A fresh estimator by name: "envelope" (default), "kalman" (the paper's reference) or
    "twoway" (the envelope with round trips: `wftool.fsp.twoway`)."""
    try:
        return _FACTORIES[name]()
    except KeyError:
        raise UsageError(
            f"unknown clock estimator {name!r}: choose one of {', '.join(ESTIMATORS)}"
        ) from None
