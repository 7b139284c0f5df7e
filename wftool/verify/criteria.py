"""Pass/fail criteria for a stream, with defaults derived from its expected rate."""

from __future__ import annotations

from dataclasses import dataclass

from wftool.fsp.timed import REFUSED
from wftool.verify.monitor import StreamSummary, TimedSummary

RATE_TOLERANCE = 0.05
"""Default minimum frame rate: within 5 % of the expected rate."""
SPREAD_FRACTION = 0.5
"""Default maximum P99 − P1 of the FC sample interval: half a nominal period (the expected
one, else the FC's own mean interval)."""
RATE_UNCHECKED = "frame rate not checked: the expected rate is unknown"
"""A stream's rate is judged against what the FC was configured to send, never against
itself: without it, the verdict says so."""
MIN_UPLINK_ECHOED = 0.9
FLAGS = ("uplink", "timed")
"""`Criteria`'s fields that say what is judged, not by how much (the others are limits)."""


@dataclass(frozen=True)
class Criteria:
    min_rate_hz: float | None = None
    max_spread_ms: float | None = None
    max_loss_pct: float = 0.1
    """Transport loss (frames the link lost), % of frames."""
    max_drops_pct: float = 0.1
    """FC-side drops (frames the FC's queue had no room for), % of frames."""
    max_errors: int = 0
    """Rejected chunks and outlier packets."""
    max_outage_s: float = 0.0
    """Time the port may be gone during the run (s, all outages): 0 fails any reconnect."""
    max_timed_late_pct: float = 1.0
    """Timed commands the FC applied late (their time had come when it took them), % of
    the timed commands it reported on."""
    uplink: bool = False
    """Judge the uplink pattern's echo (`MIN_UPLINK_ECHOED`)."""
    timed: bool = False
    """Judge what the FC made of the timed commands (E4, spec §13): some applied on time,
    at most `max_timed_late_pct` late, none refused."""


def criteria_for(*, uplink: bool = False, timed: bool = False, **limits: float | None) -> Criteria:
    """The criteria for a user's limits, by `Criteria`'s field names: a limit left at None
    takes the default. A board and the virtual FC are judged alike."""
    given = {name: value for name, value in limits.items() if value is not None}
    return Criteria(uplink=uplink, timed=timed, **given)  # type: ignore[arg-type]


@dataclass(frozen=True)
class Check:
    name: str
    value: float
    limit: float
    passed: bool
    unit: str = ""
    at_least: bool = False
    """The limit is a minimum (rates, counts received), not a maximum."""
    detail: str = ""
    """What the figure is made of, when it takes more than the figure to say."""

    def describe(self) -> str:
        relation = "≥" if self.at_least else "≤"
        limit = f"{relation} {self.limit:g}{self.unit}"
        said = f"{self.name}: {self.value:g}{self.unit} (limit {limit})"
        return f"{said}: {self.detail}" if self.detail else said


@dataclass(frozen=True)
class Verdict:
    passed: bool
    checks: tuple[Check, ...]
    notes: tuple[str, ...] = ()
    """What the verdict could not judge."""

    def as_json(self) -> dict:
        return {
            "passed": self.passed,
            "checks": [
                {
                    "name": c.name,
                    "value": c.value,
                    "limit": c.limit,
                    "passed": c.passed,
                    **({"detail": c.detail} if c.detail else {}),
                }
                for c in self.checks
            ],
            "notes": list(self.notes),
        }


def judge(summary: StreamSummary, criteria: Criteria) -> Verdict:
    """Every check the criteria ask for, against the summary."""
    checks = [Check("frames received", summary.frames, 1, summary.frames >= 1, at_least=True)]
    notes = []
    min_rate = criteria.min_rate_hz
    if min_rate is None and summary.expected_rate_hz:
        min_rate = (1.0 - RATE_TOLERANCE) * summary.expected_rate_hz
    if min_rate is not None:
        rate = round(summary.frame_rate_hz, 1)
        checks.append(
            Check("frame rate", rate, round(min_rate, 1), rate >= min_rate, " Hz", at_least=True)
        )
    else:
        notes.append(RATE_UNCHECKED)
    max_spread = criteria.max_spread_ms
    period_reference = summary.expected_rate_hz or summary.source_rate_hz
    if max_spread is None and period_reference:
        max_spread = SPREAD_FRACTION * 1e3 / period_reference
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
    outage, max_outage = summary.outage_s, criteria.max_outage_s  # any reconnect fails 0
    passed = outage <= max_outage
    checks.append(Check("time disconnected", round(outage, 3), max_outage, passed, " s"))
    if criteria.uplink:
        uplink = summary.uplink
        echoed = round(uplink.echoed_fraction, 3) if uplink is not None else 0.0
        passed = uplink is not None and uplink.steps_echoed > 0 and echoed >= MIN_UPLINK_ECHOED
        checks.append(Check("uplink echoed", echoed, MIN_UPLINK_ECHOED, passed, at_least=True))
    if criteria.timed:
        checks += timed_checks(summary.timed, criteria.max_timed_late_pct)
    return Verdict(all(c.passed for c in checks), tuple(checks), tuple(notes))


def timed_checks(timed: TimedSummary | None, max_late_pct: float) -> list[Check]:
    """What the FC made of the timed commands, by its reports (E4, spec §13): some applied
    on time; at most `max_late_pct` % applied late (the lead too short for the uplink's
    delay); none refused (too far ahead, the queue full, or expired)."""
    if timed is None or not timed.commands:
        return [
            Check(
                "timed commands on time", 0, 1, False, at_least=True,
                detail="the FC reported on none (no E4 in its firmware, or the run's clock "
                "never locked to time them)",
            )
        ]  # fmt: skip
    total = timed.commands
    on_time, late, refused = timed.on_time, timed.late, timed.refused
    late_pct = round(100.0 * late / total, 3)
    how_late = ""
    if late and timed.latest_us is not None:
        how_late = f", the latest {timed.latest_us / 1e3:.3g} ms after its time"
    superseded = f"; {timed.superseded} superseded" if timed.superseded else ""
    refusals = ", ".join(
        f"{name.lower().replace('_', ' ')} {timed.outcomes[name]}"
        for name in (outcome.name for outcome in REFUSED)
        if timed.outcomes[name]
    )
    return [
        Check(
            "timed commands on time", on_time, 1, on_time >= 1, at_least=True,
            detail=f"{on_time:,} of {total:,} the FC reported on{superseded}",
        ),
        Check(
            "timed commands late", late_pct, max_late_pct, late_pct <= max_late_pct, " %",
            detail=f"{late:,} of {total:,} applied late{how_late}" if late else "",
        ),
        Check(
            "timed commands refused", refused, 0, refused == 0,
            detail=f"{refused:,} of {total:,}: {refusals}" if refused else "",
        ),
    ]  # fmt: skip
