"""Statistics of a live or replayed FSP stream: what `verify` shows and judges. One decoder
reads the whole run, across reconnects; interval statistics are exact histograms
(docs/design.md).

    monitor = StreamMonitor(url, expected_rate_hz=1000.0)
    for event in events:
        monitor.apply(event)
    monitor.summary()
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

from wftool.fsp import (
    CommandOutcome,
    CommandPacket,
    CommandReport,
    ReportBook,
    SensorFrame,
    StateDecoder,
    StatePacket,
    UplinkFlag,
    UplinkStatus,
)
from wftool.fsp.clock import ClockEstimator, ClockState
from wftool.fsp.encoder import U32_MASK
from wftool.fsp.estimators import ESTIMATORS
from wftool.fsp.framing import Rejection
from wftool.fsp.packets import SEQ_MODULUS, rc_values
from wftool.fsp.twoway import RoundTrip, RoundTripRejection, TwoWayClockEstimator, TwoWayState
from wftool.recording.events import Event, StreamHealth, UplinkReport
from wftool.recording.ros2msg import SLOW_PERIOD_NS
from wftool.verify.uplink import UplinkStats, UplinkTracker

RATE_WINDOW_S = 2.0
"""The dashboard's "current rate" looks back this far."""
OUTLIER = "outlier"
"""The key of packets left out of the books (`StatePacket.outlier`) among the rejections."""


@dataclass(frozen=True)
class IntervalSummary:
    count: int
    mean_us: float
    p1_us: float
    p50_us: float
    p99_us: float

    @property
    def spread_us(self) -> float:
        """P99 − P1: the jitter figure the verdict judges."""
        return self.p99_us - self.p1_us

    @property
    def rate_hz(self) -> float | None:
        """The rate these intervals make (1 / mean); None for a zero mean."""
        return 1e6 / self.mean_us if self.mean_us > 0 else None


class IntervalHistogram:
    """Intervals in whole microseconds."""

    def __init__(self) -> None:
        self._counts: Counter[int] = Counter()
        self._total = 0
        self._sum = 0

    def add(self, interval_us: int) -> None:
        self._counts[interval_us] += 1
        self._total += 1
        self._sum += interval_us

    def summary(self) -> IntervalSummary | None:
        if not self._total:
            return None
        ranks = [0.01 * (self._total - 1), 0.5 * (self._total - 1), 0.99 * (self._total - 1)]
        found: list[float] = []
        seen = 0
        for value in sorted(self._counts):
            seen += self._counts[value]
            while ranks and seen > ranks[0]:
                found.append(float(value))
                ranks.pop(0)
        return IntervalSummary(self._total, self._sum / self._total, *found)


@dataclass(frozen=True)
class TimedSummary:
    """What the FC reported on timed commands (E4, spec §13) over a run."""

    reports: int
    outcomes: dict[str, int]
    """Commands per `CommandOutcome` name, by the FC's own counts (lost reports included)."""
    lost_reports: int
    apply: IntervalSummary | None
    """Commands applied on time: the applying PID iteration − the FC time asked for (µs;
    the FC's rule keeps it below one PID period)."""
    latest_us: int | None
    """The latest any command was applied after its time (µs; late ones included)."""

    @property
    def late(self) -> int:
        return self.outcomes[CommandOutcome.LATE.name]

    @property
    def refused(self) -> int:
        return (
            self.outcomes[CommandOutcome.TOO_FAR.name]
            + self.outcomes[CommandOutcome.QUEUE_FULL.name]
        )

    @property
    def dropped(self) -> int:
        return (
            self.outcomes[CommandOutcome.SUPERSEDED.name]
            + self.outcomes[CommandOutcome.EXPIRED.name]
        )


class TimedTracker:
    """The FC's command reports of a run, as `TimedSummary`."""

    def __init__(self) -> None:
        self.book = ReportBook()
        self.delays = IntervalHistogram()
        self.latest_us: int | None = None

    def add(self, report: CommandReport) -> None:
        self.book.add(report)
        delay = report.delay_us
        if delay is None:
            return
        if report.outcome == CommandOutcome.ON_TIME:
            self.delays.add(delay)
        self.latest_us = delay if self.latest_us is None else max(self.latest_us, delay)

    def summary(self) -> TimedSummary | None:
        book = self.book
        if not book.reports:
            return None
        return TimedSummary(
            reports=book.reports,
            outcomes={outcome.name: count for outcome, count in book.counts.items()},
            lost_reports=book.lost,
            apply=self.delays.summary(),
            latest_us=self.latest_us,
        )


@dataclass(frozen=True)
class StreamSummary:
    """Everything `verify` reports, as plain data (`as_json` for scripts)."""

    port: str
    duration_s: float
    connected_s: float
    packets: int
    frames: int
    frame_rate_hz: float
    packet_rate_hz: float
    current_frame_rate_hz: float
    source_rate_hz: float | None
    """1 / mean FC sample interval: the rate the FC captures at, by its own clock."""
    expected_rate_hz: float | None
    fc_interval: IntervalSummary | None
    arrival_interval: IntervalSummary | None
    lost_frames: int
    lost_packets: int
    fc_drops: int
    e1: bool | None
    rejected: dict[str, int]
    """Rejected chunks by cause (`Rejection`), and the packets left out as outliers."""
    sync_rejected: int
    """Chunks cut by joining mid-stream: the one before the first delimiter of each
    connection, if it was rejected. Not errors; the rejections in `rejected` are."""
    resets: int
    wraps: int
    reconnects: int
    clock: ClockState | None
    clock_estimator: str
    """The estimator behind `clock` and the frames' OBC times (`wftool.fsp.ESTIMATORS`)."""
    uplink: UplinkStats | None
    connected: bool
    round_trip: IntervalSummary | None = None
    """Command → time reply read, in µs, when the FC answers (E2, `fsp_time_reply`)."""
    round_trip_rejected: dict[str, int] = field(default_factory=dict)
    """Replies or round trips not used, by cause (`RoundTripRejection`)."""
    two_way: TwoWayState | None = None
    """The two-way estimate (offset uncertainty, d_min bounds) with `--clock twoway`."""
    fc_uplink: UplinkReport | None = None
    """What the FC made of the commands: its newest uplink status (E3, spec §12), once it
    sends them (from the first command it receives on)."""
    fc_uplink_age_s: float | None = None
    """How long before the summary (OBC clock) `fc_uplink` was read: the FC sends one every
    100 ms, so an old one means it stopped (a reset, a lost link)."""
    timed: TimedSummary | None = None
    """The FC's reports on timed commands (E4), when it sent any: when each acted."""

    @property
    def errors(self) -> int:
        return sum(self.rejected.values())

    @property
    def outage_s(self) -> float:
        """Time the port was gone during the run."""
        return max(0.0, self.duration_s - self.connected_s)

    @property
    def loss_pct(self) -> float:
        sent = self.frames + self.lost_frames
        return 100.0 * self.lost_frames / sent if sent else 0.0

    def health(self, latest: StatePacket | None, t: float) -> StreamHealth:
        """The counters as a `/fsp/health` snapshot taken at `t`, with the latest packet's
        seq and epoch."""
        return StreamHealth(
            t=t,
            seq=latest.seq if latest is not None else 0,
            epoch=latest.epoch if latest is not None else 0,
            e1=bool(self.e1),
            clock_locked=self.clock is not None and self.clock.locked,
            connected=self.connected,
            packets=self.packets,
            frames=self.frames,
            lost_frames=self.lost_frames,
            lost_packets=self.lost_packets,
            fc_drops=self.fc_drops,
            rejected_chunks=self.errors,
            resets=self.resets,
            reconnects=self.reconnects,
            uplink=self.fc_uplink,
        )

    def as_json(self) -> dict:
        data = asdict(self)
        data.update(errors=self.errors, loss_pct=self.loss_pct, outage_s=self.outage_s)
        for key in ("fc_interval", "arrival_interval"):
            interval = getattr(self, key)
            if interval is not None:
                data[key]["spread_us"] = interval.spread_us
        if self.timed is not None and self.timed.apply is not None:
            data["timed"]["apply"]["spread_us"] = self.timed.apply.spread_us
        for key in ("clock", "two_way"):  # NaN (not yet known) is not JSON: null
            if data[key] is not None:
                data[key] = {k: _finite_or_none(v) for k, v in data[key].items()}
        if self.fc_uplink is not None:
            data["fc_uplink"] = uplink_json(self.fc_uplink, self.fc_uplink_age_s)
        return data


def uplink_json(report: UplinkReport, age_s: float | None = None) -> dict:
    """An uplink report as plain data: the FC's counters, its flags by name (`UplinkFlag`),
    the failsafe phase by name, and its times (FC µs, unwrapped; OBC s)."""
    status = report.status
    return {
        "command_seq": status.command_seq,
        "accepted": status.accepted,
        "stale": status.stale,
        "rejected": status.rejected,
        "timeouts": status.timeouts,
        "timeout_ms": status.timeout_ms,
        **{flag.name.lower(): status.has(flag) for flag in UplinkFlag if flag.name},
        "failsafe_phase": status.failsafe_phase_name,
        "fc_time_us": status.sent_us,
        "timed_out_fc_time_us": status.timed_out_at_us,
        "obc_time": report.t,
        "timed_out_obc_time": report.timed_out_t,
        "authority": None if status.authority is None else status.authority.name.lower(),
        "exit": None if status.exit is None else status.exit.name.lower(),
        "exit_fc_time_us": status.exit_at_us,
        "exit_obc_time": report.exit_t,
        "sender": status.sender,
        "foreign": status.foreign,
        "refused": status.refused,
        "msp_rc_refused": status.msp_rc_refused,
        "pulse_range_us": status.pulse_range,
        "age_s": age_s,
    }


def uplink_report(status: UplinkStatus, clock: ClockEstimator) -> UplinkReport:
    """`status` with its FC times on the OBC clock, as `clock` places them now."""
    t = clock.to_obc(status.sent_us) if status.sent_us is not None else None
    if t is None:
        assert status.arrival_time is not None, "a live or replayed status has its read's time"
        t = status.arrival_time
    at, exit_at = status.timed_out_at_us, status.exit_at_us
    return UplinkReport(
        status,
        t,
        clock.to_obc(at) if at is not None else None,
        clock.to_obc(exit_at) if exit_at is not None else None,
    )


def _finite_or_none(value: object) -> object:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, tuple):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, dict):
        return {str(getattr(k, "value", k)): v for k, v in value.items()}
    return value


@dataclass
class StreamMonitor:
    """Accumulates one verify run across reconnects."""

    port: str
    expected_rate_hz: float | None = None
    fc_intervals: IntervalHistogram = field(default_factory=IntervalHistogram)
    arrival_intervals: IntervalHistogram = field(default_factory=IntervalHistogram)
    latest: SensorFrame | None = None
    uplink: UplinkTracker | None = None
    clock: str = ESTIMATORS[0]
    """The clock estimator of the run's decoder, by name (`wftool.fsp.ESTIMATORS`)."""

    def __post_init__(self) -> None:
        # An unknown clock name fails here. An FC may answer commands: spec §10.
        self.decoder = StateDecoder(self.clock, time_replies=True)
        assert self.decoder.round_trips is not None
        self.decoder.round_trips.on_round_trip = self._round_trip
        self.round_trips = IntervalHistogram()
        self.timed = TimedTracker()
        self._commands = 0
        """Commands sent on this connection (a port opened with it numbers them from 0)."""
        self._connected_at: float | None = None
        self._started: float | None = None
        self._now = 0.0
        self._connected_s = 0.0
        self._reconnects = 0
        self._recent: deque[tuple[float, int]] = deque()
        self.fc_uplink: UplinkReport | None = None
        """The FC's newest uplink status, its times placed when it arrived."""

    # -- events -----------------------------------------------------------------------------

    def apply(self, event: Event, command: CommandPacket | None = None) -> list[StatePacket]:
        """Take one event of a run, live or replayed; the packets a read completed.
        `command`: the packet a live command event sent (see `command_sent`)."""
        kind, t = event.kind, event.t
        if kind == "bytes":
            return self.feed(event.data, t)
        if kind == "connected":
            self.connected(t)
        elif kind == "disconnected":
            self.disconnected(t)
        elif kind == "command":
            self.command_sent(event.rc, t, command)
        return []

    def connected(self, t: float) -> None:
        if self._started is None:
            self._started = t
        elif self._connected_at is None:
            self._reconnects += 1
            self.decoder.resync()
        self.decoder.join()  # only the chunk cut by the connection may be excused
        self._connected_at = t
        self._commands = 0
        self._now = t

    def disconnected(self, t: float) -> None:
        if self._connected_at is None:
            return
        self._connected_s += t - self._connected_at
        self._connected_at = None
        self._now = t

    def feed(self, data: bytes, t: float) -> list[StatePacket]:
        if self._connected_at is None:
            raise RuntimeError("feed() before connected()")
        self._now = t
        decoder = self.decoder
        before = decoder.last_packet
        packets = decoder.feed(data, t)
        status = decoder.uplink_status
        if status is not None and (self.fc_uplink is None or status is not self.fc_uplink.status):
            self.fc_uplink = uplink_report(status, decoder.clock)
        for report in decoder.take_command_reports():
            self.timed.add(report)
        if not packets:
            return packets
        previous = before
        previous_us = before.frames[1].time_us if before is not None else None
        last_arrival = before.arrival_time if before is not None else None
        for packet in packets:
            if last_arrival is not None:
                self.arrival_intervals.add(round((t - last_arrival) * 1e6))
            last_arrival = t
            if packet.outlier:  # out of the books: its times would make false intervals
                continue
            first_us, second_us = packet.frames[0].time_us, packet.frames[1].time_us
            assert first_us is not None and second_us is not None  # the decoder timed them
            # Across a gap (lost packets, FC drops, a reset) the time spans frames never seen.
            if previous is not None and previous_us is not None and _contiguous(previous, packet):
                self.fc_intervals.add(first_us - previous_us)
            self.fc_intervals.add(second_us - first_us)
            previous, previous_us = packet, second_us
            if self.uplink is not None:
                self.uplink.observe(packet, t)
        if previous is not None:
            self.latest = previous.frames[1]
        recent = self._recent
        recent.append((t, 2 * len(packets)))
        while recent and recent[0][0] < t - RATE_WINDOW_S:
            recent.popleft()
        return packets

    def command_sent(
        self, rc: Sequence[int], t: float, command: CommandPacket | None = None
    ) -> None:
        """A command left at OBC time `t`: `command` is the packet (its seq and stamp pair
        the FC's time reply with it). A replay has no packet: it is the one the live loop sent,
        from a port opened with the connection (seq counting from 0), stamped with `t`."""
        if self.uplink is not None:
            report = self.fc_uplink  # a pilot engages the OBC (spec §15): only then it echoes
            self.uplink.sent(rc, t, report is None or report.status.steering is not False)
        if self._connected_at is None:
            return
        if command is None:
            seq, tx_time_us = self._commands % SEQ_MODULUS, int(t * 1e6) & U32_MASK
            command = CommandPacket(rc_values(rc), seq, tx_time_us)
        self._commands += 1
        round_trips = self.decoder.round_trips
        assert round_trips is not None
        round_trips.sent(command.seq, command.tx_time_us, t)

    def _round_trip(self, trip: RoundTrip) -> None:
        self.round_trips.add(round(trip.rtt_s * 1e6))

    # -- results ----------------------------------------------------------------------------

    def summary(self, now: float | None = None) -> StreamSummary:
        now = self._now if now is None else now
        decoder = self.decoder
        totals = decoder.stats
        connected_at = self._connected_at
        connected_s = self._connected_s
        if connected_at is not None:
            connected_s += now - connected_at
        duration_s = now - self._started if self._started is not None else 0.0
        joined = decoder.joined
        rejected = {cause.value: totals.rejected[cause] - joined[cause] for cause in Rejection}
        rejected[OUTLIER] = totals.outliers
        fc = self.fc_intervals.summary()
        trips_rejected = _trips_rejected(decoder)
        clock = decoder.clock
        frames = totals.frames
        window = [n for t, n in self._recent if t >= now - RATE_WINDOW_S]
        # Right after a (re)connect the window is as long as the connection, not 2 s.
        window_s = min(RATE_WINDOW_S, now - connected_at) if connected_at else RATE_WINDOW_S
        return StreamSummary(
            port=self.port,
            duration_s=duration_s,
            connected_s=connected_s,
            packets=totals.packets,
            frames=frames,
            frame_rate_hz=frames / duration_s if duration_s > 0 else 0.0,
            packet_rate_hz=totals.packets / duration_s if duration_s > 0 else 0.0,
            current_frame_rate_hz=sum(window) / window_s if window_s > 0 else 0.0,
            source_rate_hz=fc.rate_hz if fc is not None else None,
            expected_rate_hz=self.expected_rate_hz,
            fc_interval=fc,
            arrival_interval=self.arrival_intervals.summary(),
            lost_frames=totals.lost_frames,
            lost_packets=totals.lost_packets,
            fc_drops=totals.fc_drops,
            e1=totals.e1,
            rejected=rejected,
            sync_rejected=sum(joined.values()),
            resets=totals.resets,
            wraps=totals.wraps,
            reconnects=self._reconnects,
            clock=decoder.clock_state if self._started is not None else None,
            clock_estimator=self.clock,
            uplink=self.uplink.stats() if self.uplink is not None else None,
            connected=connected_at is not None,
            round_trip=self.round_trips.summary(),
            round_trip_rejected={cause.value: n for cause, n in trips_rejected.items() if n},
            two_way=clock.two_way if isinstance(clock, TwoWayClockEstimator) else None,
            fc_uplink=self.fc_uplink,
            fc_uplink_age_s=(
                now - self.fc_uplink.status.arrival_time
                if self.fc_uplink is not None and self.fc_uplink.status.arrival_time is not None
                else None
            ),
            timed=self.timed.summary(),
        )


def _contiguous(previous: StatePacket, packet: StatePacket) -> bool:
    """Whether `packet` came right after `previous` in the FC's stream: the same epoch and,
    with E1, the next `seq` with no frame dropped in between. Otherwise the time between
    them spans frames that never arrived: no interval of the FC's sampling."""
    if packet.epoch != previous.epoch:
        return False
    if not (packet.e1 and previous.e1):
        return True
    return (packet.seq - previous.seq) % SEQ_MODULUS == 1 and packet.drops == previous.drops


def _trips_rejected(decoder: StateDecoder) -> Counter[RoundTripRejection]:
    """What a decoder's round trips did not use: the matcher's and the estimator's counts."""
    counts: Counter[RoundTripRejection] = Counter()
    if decoder.round_trips is not None:
        counts.update(decoder.round_trips.rejected)
    if isinstance(decoder.clock, TwoWayClockEstimator):
        counts.update(decoder.clock.rejected)
    return counts


class HealthSampler:
    """The run's `StreamHealth`, taken from the monitor at most every `period_s`, and at
    once when the FC reports a change of its uplink flags or failsafe phase (RX loss, the
    override, a timeout): what the live loop hands its sinks with each read."""

    def __init__(self, monitor: StreamMonitor, period_s: float = SLOW_PERIOD_NS / 1e9) -> None:
        self._monitor = monitor
        self._period_s = period_s
        self.latest: StreamHealth | None = None

    def sample(self, packets: Sequence[StatePacket], t: float) -> StreamHealth | None:
        """The latest snapshot; a new one if `packets` arrived and the period is up, or if
        the FC's uplink status changed what it reports."""
        latest = self.latest
        monitor = self._monitor
        due = bool(packets) and (latest is None or not 0 <= t - latest.t < self._period_s)
        if due or (latest is not None and _reports_a_change(monitor.fc_uplink, latest.uplink)):
            newest = packets[-1] if packets else monitor.decoder.last_packet
            self.latest = latest = monitor.summary(t).health(newest, t)
        return latest


def _reports_a_change(new: UplinkReport | None, old: UplinkReport | None) -> bool:
    """Whether the FC's uplink status `new` says more than `old` did: it is the first, or
    its flags, failsafe phase or who flies differ (its counters move with every command)."""
    if new is None or new is old:
        return False
    if old is None:
        return True
    return _what_it_says(new.status) != _what_it_says(old.status)


def _what_it_says(status: UplinkStatus) -> tuple:
    return (status.flags, status.failsafe_phase, status.authority, status.exit, status.exit_us)
