"""`wftool bench command`: when commands act on the virtual FC, immediate ones against timed
ones (E4), judged by the SITL's own clock (`wftool.sitl.truth`; docs/bench.md).
"""

from __future__ import annotations

import bisect
import math
import random
import tempfile
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path

from wftool.errors import ClockError
from wftool.fc.msp import MspClient
from wftool.fsp import (
    CommandOutcome,
    CommandPacket,
    CommandReport,
    FspReader,
    ReportBook,
    StateDecoder,
)
from wftool.fsp.timed import REFUSED
from wftool.fsp.twoway import RoundTrip, TwoWayClockEstimator
from wftool.sitl.process import SITL_BOARD, VirtualBoard
from wftool.sitl.session import VirtualFcSession
from wftool.sitl.truth import Lateness, TrueClock, lateness_between
from wftool.stats import Distribution, quantile

RATES_HZ = (100.0, 500.0)
LEAD_S = 0.005
"""How far ahead of its time a timed command is sent: more than the uplink's delay (the
FSP task's period, the UART, the OBC's own loop) ever is on the virtual FC."""
MISPLACED_US = 1000
"""A timed command whose FC time is due this far or more after the instant meant (true clock) is
misplaced: the two-way clock errs by tens of µs (its uncertainty), a step it has not seen by
the step (a re-anchor: 50 ms or more)."""
IMMEDIATE = "immediate"
TIMED = "timed"
READ_S = 0.0005
"""The longest the loop reads before it looks at the schedule again."""
PHASE_S = 0.001
"""Each command's instant is its slot plus a random part of this (one FSP task period): an
OBC's clock keeps no fixed phase to the FC's tasks, the virtual FC's would."""
LOCK_TIMEOUT_S = 60.0
SETTLE_S = 0.2
"""After the last command: time for the last reports, replies and frames to arrive."""
SETTLE_TIMEOUT_S = 5.0
ROLL_BASE = 1000
ROLL_VALUES = 1000
"""Command k carries roll ROLL_BASE + k mod ROLL_VALUES: the stream shows which one acts."""
UNANSWERED_S = 0.5
"""How far an unanswered immediate command is looked for in the frames beside the nearest
answered one (command k's roll comes back ROLL_VALUES commands later: 1 s at 1000 Hz)."""


@dataclass(frozen=True)
class CommandRow:
    """One mode at one rate."""

    mode: str
    """`IMMEDIATE` or `TIMED`."""
    rate_hz: float
    lead_ms: float | None
    """Timed: how far ahead of its time each command was sent."""
    sent: int
    applied: int
    """Commands the FC said it applied: timed ones by their report, immediate ones by their
    time reply (it answers the newest of a task run only)."""
    late: int
    refused: int
    """Timed: never applied for what the OBC sent (`wftool.fsp.timed.REFUSED`: too far
    ahead, the queue full, expired)."""
    superseded: int
    """A newer command acted in its place. Timed: by its report; immediate: no time reply,
    and its roll never in the FC's frames between the answered commands around it (a newer
    one came in the same FSP task run; a command the FC found stale, E3, is not applied
    either)."""
    unlocked: int
    """Timed: commands not sent because the clock had lost its lock (the SITL re-anchored
    after its host fell behind: the FC clock stepped against the host's)."""
    unreported: int
    """Timed: commands with no report (not fresh, or the report lost); immediate: with no
    time reply (superseded, or applied and its reply lost)."""
    apply: Distribution | None
    """FC time of the application − the intended instant on the FC clock (true)."""
    seen: Distribution | None
    """FC time of the first frame whose RC shows the command − the intended instant."""
    asked: Distribution | None = None
    """Timed, the commands applied on time: the FC's own account, the applying PID iteration
    − the FC time asked for (its rule: at most one PID period)."""
    latest_us: float | None = None
    """Timed: the latest command applied late, by the FC's account (µs after its time)."""
    expired: int = 0
    """Timed, of `refused`: expired (spec §13), a host that stalled the OBC's loop sent them
    after their time."""
    expired_after_us: float | None = None
    """Timed, the expired ones: the least of the FC time it refused one at − its time, by
    the FC's account (expired on arrival: at least the command timeout)."""
    misplaced: int = 0
    """Timed, of `refused`: too far ahead because the OBC's clock gave them an FC time due
    `MISPLACED_US` or more after the instant meant, by the true clock: an FC clock step it had
    not seen yet (the SITL re-anchored after its host fell behind)."""
    one_way: int = 0
    """Timed: placed by the one-way line, whose FC times are d_min early: the two-way clock
    was taking its round trips again after an FC clock step (a re-anchor) cleared them."""


@dataclass(frozen=True)
class CommandBenchResult:
    seconds: float
    """Per row."""
    pid_period_us: float
    """The FC's PID period (MSP, averaged)."""
    frame_period_us: float
    """The stream's frame period: the resolution of `CommandRow.seen`."""
    gyro_hz: float
    uart_pacing: bool
    rows: tuple[CommandRow, ...]
    clock_uncertainty_us: float
    """The two-way clock's (spec §8.3) at the last timed command it placed."""
    reanchors: int = 0
    """Times the SITL fell more than 50 ms behind the host clock and re-anchored."""
    lateness: Lateness | None = None
    """How late the host let the FC reach its instants over the run (the SITL's own count)."""
    stale: int = 0
    """Commands the FC found not fresh (E3): the first of each new sequence after silence."""
    accepted: int = 0
    """Commands the FC took fresh (E3)."""
    packets: int = 0
    """Commands the OBC sent, those that locked the clock included (the FC counts each
    fresh or stale: one sender, the FC started for the run)."""
    lost_reports: int = 0
    """Command reports the FC counted (its cumulative counts) that did not arrive."""
    rejected: dict[str, int] = field(default_factory=dict)


@dataclass
class _Sent:
    packet: CommandPacket
    mode: str
    rate_hz: float
    intended: float
    """OBC (host) instant the command is meant to act at: its send instant if immediate."""


def run_command_bench(
    binary: Path,
    seconds: float = 20.0,
    rates_hz: Sequence[float] = RATES_HZ,
    lead_s: float = LEAD_S,
    board: VirtualBoard = SITL_BOARD,
    serial_update_rate_hz: int | None = None,
) -> CommandBenchResult:
    """For each rate, `seconds` of immediate commands, then as long of timed ones sent
    `lead_s` ahead, on one fresh virtual FC (what it measures: docs/bench.md)."""
    with tempfile.TemporaryDirectory(prefix="wftool-bench-") as scratch:
        session = VirtualFcSession(
            binary, Path(scratch) / "fc", port_base=None, time_reply=True, board=board,
            serial_update_rate_hz=serial_update_rate_hz,
        )  # fmt: skip
        with session:
            with MspClient.open(session.msp_url) as msp:
                pid_period_us = msp.pid_looptime_us()
            truth = TrueClock(session.fc.log_path)
            run = _Run(session.fsp_url)
            run.lock()
            start = time.monotonic()
            for rate in rates_hz:
                run.commands(IMMEDIATE, rate, seconds, lead_s)
                run.commands(TIMED, rate, seconds, lead_s)
            run.settle()
            truth.refresh()
            lateness = lateness_between(session.fc.log_path, start, time.monotonic())
    end = time.monotonic()
    rows = tuple(
        _row(run, truth, end, mode, rate, lead_s)
        for rate in rates_hz
        for mode in (IMMEDIATE, TIMED)
    )
    status = run.decoder.uplink_status
    return CommandBenchResult(
        seconds=seconds,
        pid_period_us=pid_period_us,
        frame_period_us=_frame_period_us(run.frames),
        gyro_hz=board.gyro_clock_hz or board.gyro_hz or 8000,
        uart_pacing=board.uart_pacing,
        rows=rows,
        clock_uncertainty_us=run.uncertainty_s * 1e6,
        reanchors=sum(1 for a in truth.anchors if a.reason != "start"),
        lateness=lateness,
        stale=status.stale if status is not None else 0,
        accepted=status.accepted if status is not None else 0,
        packets=run.reader.sender.seq,
        lost_reports=run.reports.lost,
        rejected={k.value: v for k, v in run.decoder.stats.rejected.items() if v},
    )


class _Run:
    """The OBC side: one reader, its commands, and everything the FC said."""

    def __init__(self, url: str) -> None:
        self.decoder = StateDecoder("twoway")
        assert self.decoder.round_trips is not None
        clock = self.decoder.clock
        assert isinstance(clock, TwoWayClockEstimator)
        self.clock = clock
        self.decoder.round_trips.on_round_trip = self._round_trip
        self.reader = FspReader(url, decoder=self.decoder).open()
        self.sent: list[_Sent] = []
        self.by_key: dict[tuple[int, int], _Sent] = {}
        self.applied_us: dict[tuple[int, int], int] = {}
        """Immediate commands: FC time (unwrapped) the time reply says the FC took them."""
        self.reports = ReportBook()
        """Every report of the run, in the FC's order."""
        self.report_of: dict[tuple[int, int], CommandReport] = {}
        self.frames: list[tuple[int, int]] = []
        """(FC time unwrapped, roll) of every frame."""
        self.k = 0
        self.unlocked: Counter[float] = Counter()
        """Timed commands not sent, by rate: the clock was not locked."""
        self.one_way: Counter[float] = Counter()
        """Timed commands placed by the one-way line, by rate (`CommandRow.one_way`)."""
        self.uncertainty_s = math.nan
        """The two-way clock's, at the last timed command it placed (or at its lock)."""
        self.last_intended = 0.0
        self._rng = random.Random(1)
        self._sent_at: dict[float, tuple[int, int]] = {}
        """OBC send instant → (seq, tx_time_us): what a round trip answers."""

    def _round_trip(self, trip: RoundTrip) -> None:
        key = self._sent_at.get(trip.obc_sent)
        if key is not None:
            self.applied_us[key] = trip.fc_received_us

    def read(self, timeout: float) -> None:
        data = self.reader.read_bytes(timeout)
        if not data:
            return
        for packet in self.decoder.feed(data, time.monotonic()):
            for frame in packet.frames:
                if frame.time_us is not None:
                    self.frames.append((frame.time_us, frame.rc[0]))
        for report in self.decoder.take_command_reports():
            self.reports.add(report)
            self.report_of[(report.command_seq, report.command_tx_time_us)] = report

    def send(self, mode: str, rate: float, intended: float) -> None:
        rc = (ROLL_BASE + self.k % ROLL_VALUES, 1500, 1500, 1000, 1000, 1000)
        self.k += 1
        now = time.monotonic()
        if mode == TIMED:
            try:
                packet = self.reader.send_command(rc, now, at=intended)
            except ClockError:
                self.unlocked[rate] += 1
                return
            if self.clock.two_way.active:
                self.uncertainty_s = self.clock.state.uncertainty_s
            else:
                self.one_way[rate] += 1
        else:
            packet = self.reader.send_command(rc, now)
            intended = now
        record = _Sent(packet, mode, rate, intended)
        key = (packet.seq, packet.tx_time_us)
        self.sent.append(record)
        self.by_key[key] = record
        self._sent_at[now] = key
        self.last_intended = intended

    def lock(self) -> None:
        """Immediate commands at 100 Hz until the two-way clock is in use."""
        clock = self.clock
        deadline = time.monotonic() + LOCK_TIMEOUT_S
        while not (clock.state.locked and clock.two_way.active):
            if time.monotonic() > deadline:
                rejected = ", ".join(
                    f"{count} {why.value.replace('_', ' ')}"
                    for why, count in clock.rejected.items()
                    if count
                )
                raise ClockError(
                    f"the two-way clock did not lock within {LOCK_TIMEOUT_S:g} s of commands "
                    f"with time replies ({clock.accepted} round trips used, rejected: "
                    f"{rejected or 'none'}; the stream's clock started over "
                    f"{clock.one_way.state.reinits} times): is this the patched SITL?"
                )
            self.send(IMMEDIATE, 0.0, 0.0)
            until = time.monotonic() + self._rng.uniform(0.005, 0.015)
            while (left := until - time.monotonic()) > 0:
                self.read(min(READ_S, left))
        self.uncertainty_s = clock.state.uncertainty_s
        self.sent.clear()

    def commands(self, mode: str, rate: float, seconds: float, lead_s: float) -> None:
        period = 1.0 / rate
        # the previous row's commands have acted: an immediate one would supersede them
        start = max(time.monotonic(), self.last_intended + PHASE_S) + (
            lead_s if mode == TIMED else 0.0
        )
        count = round(seconds * rate)
        for k in range(count):
            intended = start + k * period + self._rng.uniform(0.0, PHASE_S)
            send_at = intended - lead_s if mode == TIMED else intended
            while (left := send_at - time.monotonic()) > 0:
                self.read(min(READ_S, left))
            self.send(mode, rate, intended)

    def settle(self) -> None:
        """Read the last reports, replies and frames, and the FC's books (E3) up to the last
        command (it sends them every 100 ms; `SETTLE_TIMEOUT_S` only bounds "never")."""
        until, deadline = time.monotonic() + SETTLE_S, time.monotonic() + SETTLE_TIMEOUT_S
        while (left := until - time.monotonic()) > 0 or (
            not self._counted() and time.monotonic() < deadline
        ):
            self.read(min(0.01, max(left, READ_S)))
        self.reader.close()

    def _counted(self) -> bool:
        """Whether the newest uplink status counts every command sent, fresh or stale."""
        status = self.decoder.uplink_status
        return status is not None and status.accepted + status.stale >= self.reader.sender.seq


def _never_acted(run: _Run, sent: list[_Sent], frame_times: list[int]) -> int:
    """Immediate commands with no time reply whose roll no frame shows between the answered
    commands before and after it (FC times of their replies): the FC never applied them."""
    taken = [run.applied_us.get((s.packet.seq, s.packet.tx_time_us)) for s in sent]
    before_of, after_of = _latest_before(taken), _latest_before(taken[::-1])[::-1]
    window_us = round(UNANSWERED_S * 1e6)
    never = 0
    for k, record in enumerate(sent):
        if taken[k] is not None:
            continue
        before, after = before_of[k], after_of[k]
        if before is not None:
            low, high = before, before + window_us if after is None else after
        elif after is not None:
            low, high = after - window_us, after
        else:
            continue  # nothing to bound it by
        frames = run.frames[
            bisect.bisect_right(frame_times, low) : bisect.bisect_left(frame_times, high)
        ]
        never += all(roll != record.packet.rc[0] for _, roll in frames)
    return never


def _latest_before(values: list[int | None]) -> list[int | None]:
    """For each position, the latest value before it that is not None (None: there is none)."""
    latest: list[int | None] = []
    last = None
    for value in values:
        latest.append(last)
        if value is not None:
            last = value
    return latest


def _frame_period_us(frames: list[tuple[int, int]]) -> float:
    steps = sorted(b[0] - a[0] for a, b in pairwise(frames))
    return quantile(steps, 0.5) if steps else math.nan


def _row(
    run: _Run, truth: TrueClock, end: float, mode: str, rate: float, lead_s: float
) -> CommandRow:
    sent = [s for s in run.sent if s.mode == mode and s.rate_hz == rate]
    frame_times = [t for t, _ in run.frames]

    def fc_instant(fc_us: int) -> float:
        return truth.instant(fc_us, end)

    def seen_us(record: _Sent, applied_us: int) -> float | None:
        """The first frame at or after the application whose roll is the command's."""
        roll = record.packet.rc[0]
        index = bisect.bisect_left(frame_times, applied_us)
        for time_us, value in run.frames[index : index + 50]:
            if value == roll:
                return (fc_instant(time_us) - record.intended) * 1e6
        return None

    apply: list[float] = []
    seen: list[float] = []
    asked: list[float] = []
    outcomes: Counter[CommandOutcome] = Counter()
    if mode == IMMEDIATE:
        outcomes[CommandOutcome.SUPERSEDED] = _never_acted(run, sent, frame_times)
    answered = 0
    latest = -math.inf
    expired_after = math.inf
    misplaced = 0
    for record in sent:
        key = (record.packet.seq, record.packet.tx_time_us)
        if mode == TIMED:
            report = run.report_of.get(key)
            if report is None:
                continue
            answered += 1
            outcomes[CommandOutcome(report.outcome)] += 1
            if report.outcome == CommandOutcome.EXPIRED:
                expired_after = min(expired_after, float(report.after_us))
            if report.outcome == CommandOutcome.TOO_FAR:
                placed_s = fc_instant(report.at_us) - record.intended
                misplaced += placed_s >= MISPLACED_US * 1e-6
            if not report.applied or report.event_time_us is None or report.delay_us is None:
                continue
            applied_us = report.event_time_us
            if report.outcome == CommandOutcome.ON_TIME:
                asked.append(float(report.delay_us))
            else:
                latest = max(latest, float(report.delay_us))
        else:
            applied = run.applied_us.get(key)
            if applied is None:
                continue
            answered += 1
            applied_us = applied
        apply.append((fc_instant(applied_us) - record.intended) * 1e6)
        delay = seen_us(record, applied_us)
        if delay is not None:
            seen.append(delay)
    return CommandRow(
        mode=mode,
        rate_hz=rate,
        lead_ms=lead_s * 1e3 if mode == TIMED else None,
        sent=len(sent),
        applied=len(apply),
        late=outcomes[CommandOutcome.LATE],
        refused=sum(outcomes[outcome] for outcome in REFUSED),
        superseded=outcomes[CommandOutcome.SUPERSEDED],
        unlocked=run.unlocked[rate] if mode == TIMED else 0,
        one_way=run.one_way[rate] if mode == TIMED else 0,
        unreported=len(sent) - answered,
        apply=Distribution.of(apply),
        seen=Distribution.of(seen),
        asked=Distribution.of(asked) if mode == TIMED else None,
        latest_us=latest if math.isfinite(latest) else None,
        expired=outcomes[CommandOutcome.EXPIRED],
        expired_after_us=expired_after if math.isfinite(expired_after) else None,
        misplaced=misplaced,
    )
