"""Pass/fail criteria for a stream, with defaults derived from its expected rate."""

from __future__ import annotations

from dataclasses import dataclass

from wftool.verify.monitor import StreamSummary

RATE_TOLERANCE = 0.05
"""Default minimum frame rate: within 5 % of the expected (or FC-measured) rate."""
SPREAD_FRACTION = 0.5
"""Default maximum P99 − P1 of the FC sample interval: half a nominal period."""
MIN_UPLINK_ECHOED = 0.9


@dataclass(frozen=True)
class Criteria:
    min_rate_hz: float | None = None
    max_spread_ms: float | None = None
    max_loss_pct: float = 0.1
    """Transport loss (frames the link lost), % of frames."""
    max_drops_pct: float = 0.1
    """FC-side drops (frames the FC's queue had no room for), % of frames."""
    max_errors: int = 0
    uplink: bool = False


VIRTUAL_FC = Criteria(max_spread_ms=50.0, max_drops_pct=1.0)
"""The virtual FC's allowances, where its limits differ from the defaults (the one place).

SITL is not real time: its loop sleeps between iterations and, on a shared or virtual
machine, stalls for tens of ms, long enough for the FC's 4-frame queue to overflow now and
then. On hardware the defaults apply."""


@dataclass(frozen=True)
class Check:
    name: str
    value: float
    limit: float
    passed: bool
    unit: str = ""
    at_least: bool = False
    """The limit is a minimum (rates, counts received), not a maximum."""

    def describe(self) -> str:
        relation = "≥" if self.at_least else "≤"
        return (
            f"{self.name}: {self.value:g}{self.unit} (limit {relation} {self.limit:g}{self.unit})"
        )


@dataclass(frozen=True)
class Verdict:
    passed: bool
    checks: tuple[Check, ...]

    def as_json(self) -> dict:
        return {
            "passed": self.passed,
            "checks": [
                {"name": c.name, "value": c.value, "limit": c.limit, "passed": c.passed}
                for c in self.checks
            ],
        }


def judge(summary: StreamSummary, criteria: Criteria) -> Verdict:
    """Every check the criteria ask for, against the summary."""
    checks = [Check("frames received", summary.frames, 1, summary.frames >= 1, at_least=True)]
    reference = summary.expected_rate_hz or summary.source_rate_hz
    min_rate = criteria.min_rate_hz
    if min_rate is None and reference:
        min_rate = (1.0 - RATE_TOLERANCE) * reference
    if min_rate is not None:
        rate = round(summary.frame_rate_hz, 1)
        checks.append(
            Check("frame rate", rate, round(min_rate, 1), rate >= min_rate, " Hz", at_least=True)
        )
    max_spread = criteria.max_spread_ms
    if max_spread is None and reference:
        max_spread = SPREAD_FRACTION * 1e3 / reference
    if max_spread is not None and summary.fc_interval is not None:
        spread = round(summary.fc_interval.spread_us / 1e3, 3)
        checks.append(
            Check("FC interval spread", spread, round(max_spread, 3), spread <= max_spread, " ms")
        )
    loss = round(summary.loss_pct, 3)
    checks.append(
        Check("transport loss", loss, criteria.max_loss_pct, loss <= criteria.max_loss_pct, " %")
    )
    sent = summary.frames + summary.lost_frames + summary.fc_drops
    drops = round(100.0 * summary.fc_drops / sent, 3) if sent else 0.0
    checks.append(
        Check("FC-side drops", drops, criteria.max_drops_pct, drops <= criteria.max_drops_pct, " %")
    )
    checks.append(
        Check(
            "rejected chunks",
            summary.errors,
            criteria.max_errors,
            summary.errors <= criteria.max_errors,
        )
    )
    if criteria.uplink:
        uplink = summary.uplink
        echoed = round(uplink.echoed_fraction, 3) if uplink is not None else 0.0
        passed = uplink is not None and uplink.steps_echoed > 0 and echoed >= MIN_UPLINK_ECHOED
        checks.append(Check("uplink echoed", echoed, MIN_UPLINK_ECHOED, passed, at_least=True))
    return Verdict(all(c.passed for c in checks), tuple(checks))
