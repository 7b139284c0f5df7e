"""The paper's Table 1 as `paper timing` shows it beside ours: the one place for it.

Each value comes with its source (the paper, the spec); a figure not held here is None and
prints as "not available". A number here is one a reader of the paper can check.
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
        expected_us=Published(1000.0, "the paper, §5.2: MSP_RAW_IMU polled at 1,000 Hz"),
        mean_us=Published(
            1e6 / _MSP_RATE_HZ,
            "the paper, §5.2: stock MSP gives ~780 Hz (mean interval = 1 / rate)",
            approximate=True,
        ),
    ),
}
"""The paper's Table 1 rows by protocol; a None figure is not available here."""
