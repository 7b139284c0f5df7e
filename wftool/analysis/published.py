"""The paper's published Table 1, as far as this project knows it: the one place for it.

The paper's own table is not in this repository, and it could not be found from here (no
internet; the public-code and web search found neither the paper nor its numbers). So this
holds only what is known, each value with where it comes from; everything else is None and
prints as "not available". Never fill a gap with a guess: a number here is one a reader of
the paper could check.
"""

from __future__ import annotations

from dataclasses import dataclass

NOT_AVAILABLE = "not available"


@dataclass(frozen=True)
class Published:
    """One published figure and its source."""

    value: float
    source: str
    approximate: bool = False
    """Given as "about" (e.g. "~780 Hz"): shown with a "≈"."""


@dataclass(frozen=True)
class PublishedRow:
    """A protocol's row of the paper's Table 1 (intervals in µs)."""

    protocol: str
    setup: str
    expected_us: Published | None = None
    mean_us: Published | None = None
    median_us: Published | None = None
    p1_us: Published | None = None
    p99_us: Published | None = None
    spread_us: Published | None = None

    def figures(self) -> dict[str, Published | None]:
        return {
            "expected_us": self.expected_us,
            "mean_us": self.mean_us,
            "median_us": self.median_us,
            "p1_us": self.p1_us,
            "p99_us": self.p99_us,
            "spread_us": self.spread_us,
        }


_SPEC = "spec/fsp.md §7: 3148 Hz PID loop, fsp_rate 1100 Hz, N = 3, ≈1049.3 Hz"
_FSP_RATE_HZ = 3148 / 3
_MSP_RATE_HZ = 780.0

TABLE1: dict[str, PublishedRow] = {
    "FSP": PublishedRow(
        "FSP",
        "FC sample times; 3148 Hz PID loop, fsp_rate_hz 1100",
        expected_us=Published(1e6 / _FSP_RATE_HZ, _SPEC),
    ),
    "MSP": PublishedRow(
        "MSP",
        "reception times; MSP_RAW_IMU polled at 1 kHz",
        expected_us=Published(1000.0, "issue 11: the paper polled MSP_RAW_IMU at 1,000 Hz"),
        mean_us=Published(
            1e6 / _MSP_RATE_HZ,
            "the project brief: stock MSP gives ~780 Hz (mean interval = 1 / rate)",
            approximate=True,
        ),
    ),
}
"""The paper's Table 1 rows by protocol; a None figure is not available here."""
