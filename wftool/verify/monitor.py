"""Statistics of a live (or replayed) FSP stream: what `verify` shows and judges.

`StreamMonitor` is fed the same events live and on replay — connects, disconnects, byte
chunks with their OBC arrival time, commands sent — so a recording replays to the same
summary. Interval statistics live in integer-µs histograms: exact percentiles in memory
bounded by the number of distinct intervals, not by the length of the run.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace

from wftool.fsp import CommandPacket, SensorFrame, StateDecoder, StatePacket, StreamStats
from wftool.fsp.clock import ESTIMATORS, ClockState, make_estimator
from wftool.fsp.encoder import U32_MASK
from wftool.fsp.framing import Rejection
from wftool.fsp.packets import SEQ_MODULUS
from wftool.fsp.twoway import RoundTrip, RoundTripRejection, TwoWayClockEstimator, TwoWayState
from wftool.verify.uplink import UplinkStats, UplinkTracker

RATE_WINDOW_S = 2.0
"""The dashboard's "current rate" looks back this far."""
_SYNC_ALLOWANCE = 1
"""Joining a stream mid-packet cuts at most one chunk: that rejection is not an error."""


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
    sync_rejected: int
    """Chunks rejected before the first packet of each connection (joining mid-stream)."""
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

    @property
    def errors(self) -> int:
        return sum(self.rejected.values())

    @property
    def loss_pct(self) -> float:
        sent = self.frames + self.lost_frames
        return 100.0 * self.lost_frames / sent if sent else 0.0

    def as_json(self) -> dict:
        data = asdict(self)
        data.update(errors=self.errors, loss_pct=self.loss_pct)
        for key in ("fc_interval", "arrival_interval"):
            interval = getattr(self, key)
            if interval is not None:
                data[key]["spread_us"] = interval.spread_us
        for key in ("clock", "two_way"):  # NaN (not yet known) is not JSON: null
            if data[key] is not None:
                data[key] = {k: _finite_or_none(v) for k, v in data[key].items()}
        return data


def _finite_or_none(value: object) -> object:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, tuple):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, dict):
        return {str(getattr(k, "value", k)): v for k, v in value.items()}
    return value


@dataclass
class _Connection:
    decoder: StateDecoder
    """One per connection: a new connection is a new stream (FC clock, sequence, sync)."""
    opened_at: float
    synced_errors: int | None = None
    commands: int = 0
    """Commands sent on this connection."""

    def stats(self) -> tuple[StreamStats, int]:
        """The decoder's totals without the chunk cut by joining mid-stream, and that count."""
        stats = self.decoder.stats
        sync = self.synced_errors
        if sync is None:
            sync = min(_SYNC_ALLOWANCE, stats.errors)
        if sync:  # the cut chunk: whichever cause it landed in, it is not an error
            rejected = dict(stats.rejected)
            cause = next(c for c in Rejection if rejected[c])
            rejected[cause] -= sync
            stats = replace(stats, rejected=rejected)
        return stats, sync


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
    """The clock estimator of each connection's decoder, by name (`wftool.fsp.ESTIMATORS`)."""

    def __post_init__(self) -> None:
        make_estimator(self.clock)  # an unknown name fails here, not at the first connect
        self._connection: _Connection | None = None
        self._last_decoder: StateDecoder | None = None  # for E1 and clock after a disconnect
        self._closed = StreamStats(rejected=dict.fromkeys(Rejection, 0))  # finished connections
        self._closed_sync = 0
        self._started: float | None = None
        self._now = 0.0
        self._connected_s = 0.0
        self._reconnects = 0
        self._recent: deque[tuple[float, int]] = deque()
        self.round_trips = IntervalHistogram()
        self._trips_rejected: Counter[RoundTripRejection] = Counter()  # finished connections

    # -- events -----------------------------------------------------------------------------

    def connected(self, t: float) -> None:
        if self._started is None:
            self._started = t
        elif self._connection is None:
            self._reconnects += 1
        decoder = StateDecoder(self.clock, time_replies=True)  # an FC may answer: spec §10
        assert decoder.round_trips is not None
        decoder.round_trips.on_round_trip = self._round_trip
        self._connection = _Connection(decoder, t)
        self._last_decoder = self._connection.decoder
        self._now = t

    def disconnected(self, t: float) -> None:
        connection = self._connection
        if connection is None:
            return
        self._connected_s += t - connection.opened_at
        stats, sync = connection.stats()
        self._closed += stats
        self._closed_sync += sync
        self._trips_rejected += _trips_rejected(connection.decoder)
        self._connection = None
        self._now = t

    def feed(self, data: bytes, t: float) -> list[StatePacket]:
        connection = self._connection
        if connection is None:
            raise RuntimeError("feed() before connected()")
        self._now = t
        decoder = connection.decoder
        before = decoder.last_packet
        packets = decoder.feed(data, t)
        if not packets:
            return packets
        if connection.synced_errors is None:
            connection.synced_errors = min(_SYNC_ALLOWANCE, decoder.stats.errors)
        previous = epoch = last_arrival = None
        if before is not None:
            previous, epoch, last_arrival = before.frames[1], before.epoch, before.arrival_time
        for packet in packets:
            first, second = packet.frames
            if previous is not None and packet.epoch == epoch:
                self.fc_intervals.add(first.time_us - previous.time_us)
            self.fc_intervals.add(second.time_us - first.time_us)
            if last_arrival is not None:
                self.arrival_intervals.add(round((t - last_arrival) * 1e6))
            last_arrival = t
            previous, epoch = second, packet.epoch
            if self.uplink is not None:
                self.uplink.observe(packet, t)
        self.latest = previous
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
            self.uplink.sent(rc, t)
        connection = self._connection
        if connection is None:
            return
        if command is None:
            command = CommandPacket(tuple(rc), connection.commands % SEQ_MODULUS,  # type: ignore[arg-type]
                                    int(t * 1e6) & U32_MASK)  # fmt: skip
        connection.commands += 1
        round_trips = connection.decoder.round_trips
        assert round_trips is not None
        round_trips.sent(command.seq, command.tx_time_us, t)

    def _round_trip(self, trip: RoundTrip) -> None:
        self.round_trips.add(round(trip.rtt_s * 1e6))

    # -- results ----------------------------------------------------------------------------

    def summary(self, now: float | None = None) -> StreamSummary:
        now = self._now if now is None else now
        totals, sync = self._closed, self._closed_sync
        connection = self._connection
        connected_s = self._connected_s
        if connection is not None:
            stats, current_sync = connection.stats()
            totals, sync = totals + stats, sync + current_sync
            connected_s += now - connection.opened_at
        last = self._last_decoder
        fc = self.fc_intervals.summary()
        trips_rejected = self._trips_rejected.copy()
        if connection is not None:
            trips_rejected += _trips_rejected(connection.decoder)
        clock = last.clock if last is not None else None
        frames = totals.frames
        window = [n for t, n in self._recent if t >= now - RATE_WINDOW_S]
        window_s = min(RATE_WINDOW_S, now - connection.opened_at) if connection else RATE_WINDOW_S
        return StreamSummary(
            port=self.port,
            duration_s=now - self._started if self._started is not None else 0.0,
            connected_s=connected_s,
            packets=totals.packets,
            frames=frames,
            frame_rate_hz=frames / connected_s if connected_s > 0 else 0.0,
            packet_rate_hz=totals.packets / connected_s if connected_s > 0 else 0.0,
            current_frame_rate_hz=sum(window) / window_s if window_s > 0 else 0.0,
            source_rate_hz=1e6 / fc.mean_us if fc is not None and fc.mean_us > 0 else None,
            expected_rate_hz=self.expected_rate_hz,
            fc_interval=fc,
            arrival_interval=self.arrival_intervals.summary(),
            lost_frames=totals.lost_frames,
            lost_packets=totals.lost_packets,
            fc_drops=totals.fc_drops,
            e1=last.stats.e1 if last is not None else None,
            rejected={cause.value: totals.rejected[cause] for cause in Rejection},
            sync_rejected=sync,
            resets=totals.resets,
            wraps=totals.wraps,
            reconnects=self._reconnects,
            clock=last.clock_state if last is not None else None,
            clock_estimator=self.clock,
            uplink=self.uplink.stats() if self.uplink is not None else None,
            connected=connection is not None,
            round_trip=self.round_trips.summary(),
            round_trip_rejected={cause.value: n for cause, n in trips_rejected.items() if n},
            two_way=clock.two_way if isinstance(clock, TwoWayClockEstimator) else None,
        )


def _trips_rejected(decoder: StateDecoder) -> Counter[RoundTripRejection]:
    """What a decoder's round trips did not use: the matcher's and the estimator's counts."""
    counts: Counter[RoundTripRejection] = Counter()
    if decoder.round_trips is not None:
        counts.update(decoder.round_trips.rejected)
    if isinstance(decoder.clock, TwoWayClockEstimator):
        counts.update(decoder.clock.rejected)
    return counts
