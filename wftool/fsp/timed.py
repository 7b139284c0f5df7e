"""Timed commands (E4, spec §13) on the OBC: the FC time of an OBC instant, through a stream's
clock estimator, for a command that is to act then; and the books of the FC's reports on them.

    at_us = fc_time_us(decoder, time.monotonic() + 0.005)   # ClockError until locked
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from wftool.errors import ClockError
from wftool.fsp.clock import U32
from wftool.fsp.decoder import StateDecoder
from wftool.fsp.packets import OUTCOME_MODULUS, CommandOutcome, CommandReport

_HALF_U32 = U32 // 2
_RATE_SPAN_US = 1_000_000
"""The two FC instants an estimator's line is read at to invert it (it is a line)."""


def fc_time_us(decoder: StateDecoder, obc_time: float) -> int:
    """FC `micros()` (u32) at OBC instant `obc_time` (s, the clock the decoder was fed),
    by `decoder`'s clock estimator: two-way with a `twoway` decoder once its round trips
    agree (spec §8.3), else the one-way line, whose OBC times are d_min late (the FC time
    is then d_min early). `ClockError` while the clock is not locked (or before a state
    packet of the FC's current run), and for an instant 2^31 µs or more from the FC's
    present, which a u32 cannot place."""
    state = decoder.clock_state
    last = decoder.last_packet
    if not state.locked or last is None or last.time_us is None:
        raise ClockError(
            "the FC clock is not locked yet: a timed command needs it "
            "(wait until the stream's decoder.clock_state.locked)"
        )
    reference = last.time_us
    base = decoder.clock.to_obc(reference)
    later = decoder.clock.to_obc(reference + _RATE_SPAN_US)
    if base is None or later is None or not later > base:
        raise ClockError("the stream's clock estimator gives no FC→OBC line to invert")
    offset = (obc_time - base) * _RATE_SPAN_US / (later - base)
    if not (math.isfinite(offset) and abs(offset) < _HALF_U32):
        raise ClockError(
            f"OBC time {obc_time!r} s is 2^31 µs or more from the FC's present: "
            "no FC time a command can carry"
        )
    return (reference + round(offset)) % U32


REFUSED = (CommandOutcome.TOO_FAR, CommandOutcome.QUEUE_FULL, CommandOutcome.EXPIRED)
"""The outcomes of a timed command the FC never applied for what the OBC sent: too far
ahead, the queue full, or expired (the OBC gone before its time, or the command arriving a
command timeout after it). The others: applied on time, late, or superseded by a newer one."""


class ReportBook:
    """Commands per outcome over a run of the FC's command reports, from the FC's own
    cumulative counts: a lost report loses no count, and says it was lost."""

    def __init__(self) -> None:
        self.reports = 0
        """Reports taken."""
        self.counts: dict[CommandOutcome, int] = dict.fromkeys(CommandOutcome, 0)
        """Timed commands per outcome since the first report taken (that one included)."""
        self._last: CommandReport | None = None

    def add(self, report: CommandReport) -> None:
        self.reports += 1
        last = self._last
        if last is not None:
            for outcome, now, before in zip(CommandOutcome, report.counts, last.counts):
                self.counts[outcome] += (now - before) % OUTCOME_MODULUS
        elif report.outcome < len(CommandOutcome):
            self.counts[CommandOutcome(report.outcome)] += 1
        self._last = report

    def extend(self, reports: Iterable[CommandReport]) -> None:
        for report in reports:
            self.add(report)

    @property
    def commands(self) -> int:
        """Timed commands the FC reported on (all outcomes), those of lost reports included."""
        return sum(self.counts.values())

    @property
    def lost(self) -> int:
        """Reports the FC counted but that did not arrive."""
        return max(0, self.commands - self.reports)

    @property
    def applied(self) -> int:
        return self.counts[CommandOutcome.ON_TIME] + self.counts[CommandOutcome.LATE]

    @property
    def refused(self) -> int:
        """Never applied, for what the OBC sent (`REFUSED`)."""
        return sum(self.counts[outcome] for outcome in REFUSED)
