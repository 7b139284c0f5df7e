"""The streaming FSP decoder: bytes in, timed state packets out, every anomaly counted; it never
raises on input (loss, FC drops, wraps, resets, outliers: docs/design.md).

    decoder = StateDecoder()
    for packet in decoder.feed(data, arrival_time):
        ...
    decoder.stats   # packets, rejections by cause, loss, FC drops, wraps, resets
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

from wftool.fsp.clock import (
    STEADY_GAP_S,
    STEADY_STEP_US,
    U32,
    ClockEstimator,
    ClockState,
    FcClock,
    RoundTripObserver,
)
from wftool.fsp.estimators import make_estimator
from wftool.fsp.framing import (
    COMMAND_VERSIONS,
    IMMEDIATE_COMMAND_VERSIONS,
    STATE_E2_VERSIONS,
    STREAM_VERSIONS,
    UPLINK_STATUS_VERSIONS,
    Deframer,
    Rejection,
)
from wftool.fsp.packets import (
    ARMING_REQUEST_LENGTH,
    COMMAND_REPORT_LENGTH,
    DROPS_MODULUS,
    SEQ_MODULUS,
    STATE_LENGTH,
    TIME_REPLY_LENGTH,
    ArmingRequest,
    CommandPacket,
    CommandReport,
    StatePacket,
    TimeReply,
    UplinkStatus,
    parse_arming_request,
    parse_command,
    parse_command_report,
    parse_state,
    parse_time_reply,
    parse_uplink_status,
)
from wftool.fsp.twoway import RoundTripMatcher, RoundTripRejection

_SEQ_HALF = SEQ_MODULUS // 2
_HALF_U32 = U32 // 2
REPLY_PLACE_US = 1_000_000
"""A time reply's FC send time lies this close to the latest state packet's (spec §10)."""
COMMAND_REPORTS_KEPT = 4096
"""Command reports (E4) a decoder holds until they are taken: the newest ones."""


JITTER_US = 1000
"""How far a sample may be off its place in the stream, on top of half the step expected."""

Reading = tuple[int, int, "float | None", "int | None", int]
"""What `follows` looks at in a packet: its first frame's FC time, the frame period it
shows (µs, both u32), its arrival time, its E1 `seq` (None without E1) and `drops`."""


def follows(earlier: Reading, later: Reading) -> bool:
    """Whether `later` continues the stream after `earlier`: a steady step of the FC clock
    (`clock.STEADY_STEP_US`, within `clock.STEADY_GAP_S` of OBC time) and, when both carry
    E1, a `seq` ahead by less than half its range with a step as long as the frames it
    spans (sent and dropped ones) take, give or take half of that and `JITTER_US`.
    `columns` applies the same rule to arrays."""
    raw_us, period_us, obc_time, seq, drops = earlier
    next_raw_us, _, next_obc_time, next_seq, next_drops = later
    step = (next_raw_us - raw_us) % U32
    if step >= STEADY_STEP_US:
        return False
    timed = obc_time is not None and next_obc_time is not None
    if timed and not next_obc_time - obc_time < STEADY_GAP_S:  # type: ignore[operator]
        return False
    if seq is None or next_seq is None:
        return True
    sent = (next_seq - seq) % SEQ_MODULUS
    if not 0 < sent < _SEQ_HALF:
        return False
    if not 0 < period_us < STEADY_STEP_US:
        return True  # no period to hold the step against
    expected = (2 * sent + (next_drops - drops) % DROPS_MODULUS) * period_us
    return abs(step - expected) <= expected // 2 + JITTER_US


def restarted(earlier: Reading, later: Reading) -> bool:
    """Whether the FC started its stream over between `earlier` and `later`, a packet that
    did not follow it but that the next one follows. E1 tells: `seq` went back. Without
    arrival times (the OBC clock tells otherwise: `FcClock`), also when `seq` moved on by
    more than a second of packets and the FC time step is not as long as the frames sent
    and dropped meanwhile take (within 1/32 and a second): after more than 2^31 µs of
    uptime a reboot looks like a step ahead of the clock, and at a high rate of the
    sequence too. Where 2^24 packets take as long as 2^32 µs (a frame period near 128 µs)
    the two cannot be told apart."""
    raw_us, period_us, obc_time, seq, drops = earlier
    next_raw_us, _, next_obc_time, next_seq, next_drops = later
    if seq is None or next_seq is None:
        return False
    sent = (next_seq - seq) % SEQ_MODULUS
    if not 0 < sent < _SEQ_HALF:
        return True
    if (obc_time is not None and next_obc_time is not None) or not 0 < period_us < STEADY_STEP_US:
        return False
    expected = (2 * sent + (next_drops - drops) % DROPS_MODULUS) * period_us
    if expected < STEADY_STEP_US:
        return False  # the same run, a short way on: it stalled
    return abs((next_raw_us - raw_us) % U32 - expected) > expected // 32 + STEADY_STEP_US


@dataclass
class StreamStats:
    """Running totals of one decoder. Loss figures restart their baselines at an FC reset."""

    bytes: int = 0
    packets: int = 0
    frames: int = 0
    rejected: dict[Rejection, int] = field(default_factory=dict)
    lost_packets: int = 0
    """State packets missing from the E1 `seq` sequence (transport loss; E1 only), an
    outlier's among them: its frames are not in the books."""
    lost_frames: int = 0
    """Frames lost in transport: 2 per lost packet with E1, else inferred from time gaps."""
    fc_drops: int = 0
    """Frames the FC dropped because its queue was full (E1 only)."""
    e1: bool | None = None
    """Whether the latest packet carried the E1 counters."""
    wraps: int = 0
    resets: int = 0
    time_replies: int = 0
    """E2 time replies decoded (with E2 on; spec §10)."""
    uplink_statuses: int = 0
    """E3 uplink statuses decoded (spec §12)."""
    command_reports: int = 0
    """E4 command reports decoded (spec §13)."""
    outliers: int = 0
    """Packets that fit neither the stream before nor after them (`StatePacket.outlier`)."""

    @property
    def errors(self) -> int:
        """Chunks that did not decode, all causes."""
        return sum(self.rejected.values())


class StateDecoder:
    """Decodes the FC → OBC stream. One instance per port; not thread-safe."""

    def __init__(
        self, clock: ClockEstimator | str | None = None, *, time_replies: bool | None = None
    ) -> None:
        """`clock`: an estimator, or its name in `estimators.ESTIMATORS` (default: "envelope").
        `time_replies`: take E2 time replies (default: when the clock takes round trips)."""
        self._fc_clock = FcClock()
        if clock is None:
            clock = make_estimator()
        elif isinstance(clock, str):
            clock = make_estimator(clock)
        self.clock: ClockEstimator = clock
        if time_replies is None:
            time_replies = isinstance(clock, RoundTripObserver)
        self.round_trips: RoundTripMatcher | None = RoundTripMatcher() if time_replies else None
        """The commands sent and the replies paired with them (E2 only): a sender records
        each command here (`FspReader` does)."""
        self._deframer = Deframer(STATE_E2_VERSIONS if time_replies else STREAM_VERSIONS)
        self.stats = StreamStats(rejected=self._deframer.rejected)
        self.uplink_status: UplinkStatus | None = None
        """The FC's newest uplink status (E3, spec §12); None before the first."""
        self.command_reports: deque[CommandReport] = deque(maxlen=COMMAND_REPORTS_KEPT)
        """The FC's reports on timed commands (E4, spec §13), oldest first, not taken yet
        (`take_command_reports`); the oldest go once `COMMAND_REPORTS_KEPT` wait."""
        self._last: StatePacket | None = None
        self._suspect: StatePacket | None = None
        """The latest packet, if it did not follow `_last`: an outlier unless the next
        packet follows it."""
        self._last_reading: Reading = (0, 0, None, None, 0)
        self._suspect_reading: Reading = self._last_reading
        self._epoch = 0

    @property
    def clock_state(self) -> ClockState:
        return self.clock.state

    @property
    def last_packet(self) -> StatePacket | None:
        """The newest packet in the books (None before the first): outliers are not."""
        return self._last

    @property
    def joined(self) -> dict[Rejection, int]:
        """Of `stats.rejected`: the chunks cut by joining the stream mid-way, the one each
        connection began in (`join`, `resync`; a new decoder is joining)."""
        return self._deframer.joined

    def take_command_reports(self) -> list[CommandReport]:
        """The command reports (E4) decoded since the last call, oldest first."""
        reports = list(self.command_reports)
        self.command_reports.clear()
        return reports

    def join(self) -> None:
        """A connection opens mid-stream: the bytes up to the next delimiter end a chunk
        whose start was never seen."""
        self._deframer.join()

    def resync(self) -> None:
        """The byte stream broke off and starts again (a reconnect): the partial chunk is
        dropped and the stream joined anew. The FC's stream goes on, and so do its clock,
        its sequence and the books: what was lost meanwhile is counted as any loss."""
        self._deframer.resync()

    def feed(self, data: bytes, arrival_time: float | None = None) -> list[StatePacket]:
        """Packets completed by `data`; `arrival_time` (OBC clock, s) enables clock alignment."""
        self.stats.bytes += len(data)
        payloads = self._deframer.feed(data)
        if min(map(len, payloads), default=STATE_LENGTH) >= STATE_LENGTH:  # state packets only
            return self._account(map(parse_state, payloads), arrival_time)
        packets: list[StatePacket] = []
        start = 0
        for index, payload in enumerate(payloads):
            if len(payload) < STATE_LENGTH:  # the stream's order matters: packets first
                packets += self._account(map(parse_state, payloads[start:index]), arrival_time)
                if len(payload) == TIME_REPLY_LENGTH:
                    self._time_reply(parse_time_reply(payload), arrival_time)
                elif len(payload) == COMMAND_REPORT_LENGTH:
                    self._command_report(parse_command_report(payload), arrival_time)
                else:
                    self._uplink_status(parse_uplink_status(payload), arrival_time)
                start = index + 1
        return packets + self._account(map(parse_state, payloads[start:]), arrival_time)

    def _account(
        self, parsed: Iterable[StatePacket], arrival_time: float | None
    ) -> list[StatePacket]:
        """Unwrap, time and count `parsed`, the stream's next state packets."""
        packets = list(parsed)
        if not packets:
            return packets
        book = self._book
        last = self._last
        last_reading = self._last_reading
        for packet in packets:
            packet.arrival_time = arrival_time
            first, second = packet.frames
            base_raw = first.values[0]
            now = (
                base_raw,
                (second.values[0] - base_raw) % U32,
                arrival_time,
                packet.seq if packet.e1 else None,
                packet.drops,
            )
            if last is None or follows(last_reading, now):
                self._suspect = None  # an earlier suspect stays an outlier
                book(packet, now, last)
            elif (suspect := self._suspect) is not None and follows(self._suspect_reading, now):
                self._suspect = None  # it began what comes next: book it, then this one
                suspect.outlier = False
                self.stats.outliers -= 1
                before = self._suspect_reading
                book(suspect, before, last, restarted(last_reading, before))
                book(packet, now, suspect)
            else:
                self._suspect, self._suspect_reading = packet, now
                self._provisional(packet, last)
                continue
            last, last_reading = packet, now
        self._last, self._last_reading = last, last_reading
        stats = self.stats
        stats.e1 = packets[-1].e1
        stats.packets += len(packets)
        stats.frames += 2 * len(packets)
        stats.wraps = self._fc_clock.wraps
        stats.resets = self._fc_clock.resets
        return packets

    def _book(
        self, packet: StatePacket, now: Reading, last: StatePacket | None, restart: bool = False
    ) -> None:
        """Put `packet` (`now` its reading) in the books after `last`, the newest in them;
        the caller makes it the newest."""
        # Unwrap the oldest instant in the packet; the others follow it within a period.
        first, second = packet.frames
        base_raw, period_us, arrival_time, _, _ = now
        if restart:
            base_us, reset = self._fc_clock.unwrap(base_raw, arrival_time, restarted=True)
        else:
            base_us, reset = self._fc_clock.unwrap(base_raw, arrival_time)
        if reset:
            self._epoch += 1
            last = None
            self.clock.reset()
        first.time_us = base_us
        second.time_us = second_us = base_us + period_us
        packet.time_us = time_us = base_us + (packet.tx_time_us - base_raw) % U32
        packet.epoch = self._epoch
        if arrival_time is not None:
            clock = self.clock
            clock.observe(time_us, arrival_time)
            to_obc = clock.to_obc
            first.obc_time = to_obc(base_us)
            second.obc_time = to_obc(second_us)
        if last is None:
            return
        # Loss since `last`: by E1 seq and drops, else by the time gap.
        stats = self.stats
        if packet.e1 and last.e1:
            gap = (packet.seq - last.seq - 1) % SEQ_MODULUS
            if gap and gap < _SEQ_HALF:  # a larger gap is a repeat or reorder: nothing lost
                stats.lost_packets += gap
                stats.lost_frames += 2 * gap
            if packet.drops != last.drops:
                stats.fc_drops += (packet.drops - last.drops) % DROPS_MODULUS
        elif period_us > 0:
            last_us = last.frames[1].time_us
            assert last_us is not None  # a packet in the books is timed
            missing = round((base_us - last_us) / period_us) - 1
            stats.lost_frames += max(0, missing)

    def _provisional(self, packet: StatePacket, last: StatePacket) -> None:
        """Time `packet` as the nearest instant to `last` and mark it an outlier."""
        packet.outlier = True
        self.stats.outliers += 1
        first, second = packet.frames
        base_raw = first.values[0]
        step = (base_raw - last.frames[0].values[0]) % U32
        first.time_us = base_us = last.frames[0].time_us + (
            step - U32 if step >= _HALF_U32 else step
        )
        second.time_us = base_us + (second.values[0] - base_raw) % U32
        packet.time_us = base_us + (packet.tx_time_us - base_raw) % U32
        packet.epoch = self._epoch
        if packet.arrival_time is not None:
            first.obc_time = self.clock.to_obc(first.time_us)
            second.obc_time = self.clock.to_obc(second.time_us)

    def _placed(self, fc_time_us: int) -> int | None:
        """An FC time (u32) sent just now, unwrapped against the latest state packet's send
        time: None when it lies more than `REPLY_PLACE_US` from it (another FC epoch's) or
        before any state packet."""
        last = self._last
        if last is None or last.time_us is None:
            return None
        ahead = (fc_time_us - last.tx_time_us) % U32
        if ahead >= _HALF_U32:
            ahead -= U32
        return last.time_us + ahead if abs(ahead) <= REPLY_PLACE_US else None

    def _command_report(self, report: CommandReport, arrival_time: float | None) -> None:
        """Keep a report, its FC times unwrapped: the event against the latest state
        packet's (it happened at most a queue's horizon before), the time asked for against
        the event (by the signed difference, as the FC compares them)."""
        self.stats.command_reports += 1
        report.arrival_time = arrival_time
        event = self._placed(report.event_us)
        if event is not None:
            report.event_time_us = event
            asked = (report.at_us - report.event_us) % U32
            report.at_time_us = event + (asked - U32 if asked >= _HALF_U32 else asked)
        self.command_reports.append(report)

    def _uplink_status(self, status: UplinkStatus, arrival_time: float | None) -> None:
        """Keep the newest status, its FC times unwrapped against the latest state packet's
        when its send time lies within `REPLY_PLACE_US` of it (as a time reply's); the
        timeout and the exit it dates lie before it (within 2^32 µs)."""
        self.stats.uplink_statuses += 1
        status.arrival_time = arrival_time
        sent_us = status.sent_us = self._placed(status.tx_time_us)
        if sent_us is not None:
            if status.timeouts:
                status.timed_out_at_us = sent_us - (status.tx_time_us - status.timed_out_us) % U32
            if status.exit and status.exit_us is not None:
                status.exit_at_us = sent_us - (status.tx_time_us - status.exit_us) % U32
        self.uplink_status = status

    def _time_reply(self, reply: TimeReply, arrival_time: float | None) -> None:
        """Place a reply's FC times against the latest state packet's, then pair it."""
        self.stats.time_replies += 1
        round_trips = self.round_trips
        assert round_trips is not None
        last = self._last
        if arrival_time is None:
            return  # no OBC time: no round trip
        ahead = (reply.tx_time_us - last.tx_time_us) % U32 if last is not None else U32
        if ahead >= _HALF_U32:
            ahead -= U32
        held = (reply.tx_time_us - reply.rx_time_us) % U32
        if held >= _HALF_U32:  # answered before it was received
            round_trips.rejected[RoundTripRejection.CLOCK_STEP] += 1
            return
        if last is None or abs(ahead) > REPLY_PLACE_US or held > REPLY_PLACE_US:
            round_trips.rejected[RoundTripRejection.STALE] += 1  # another FC epoch's reply
            return
        assert last.time_us is not None
        reply.sent_us = last.time_us + ahead
        reply.received_us = reply.sent_us - held
        reply.arrival_time = arrival_time
        trip = round_trips.match(reply)
        if trip is not None and isinstance(self.clock, RoundTripObserver):
            self.clock.observe_round_trip(
                trip.obc_sent, trip.fc_received_us, trip.fc_sent_us, trip.obc_received
            )


class CommandDecoder:
    """Decodes the OBC → FC uplink: what the FC does, for tests and simulators. `timed`: take
    E4 timed commands (spec §13) and E5 arming requests (§14), as the firmware does unless
    built without them; without, each is a chunk of bad length."""

    def __init__(self, *, timed: bool = True) -> None:
        self._deframer = Deframer(COMMAND_VERSIONS if timed else IMMEDIATE_COMMAND_VERSIONS)
        self.rejected = self._deframer.rejected

    def feed(self, data: bytes) -> list[CommandPacket | ArmingRequest]:
        """The packets completed by `data`, in the order sent."""
        return [
            parse_arming_request(payload)
            if len(payload) == ARMING_REQUEST_LENGTH
            else parse_command(payload)
            for payload in self._deframer.feed(data)
        ]


class UplinkStatusWatch:
    """The FC's newest uplink status (E3, spec §12) out of the raw bytes of its stream, and
    nothing else decoded: what a port that does not decode (`reader.FspPort`) knows of the
    FC's pulse range. Its FC times are not placed (no state packets here)."""

    def __init__(self) -> None:
        self._deframer = Deframer(UPLINK_STATUS_VERSIONS)
        self.status: UplinkStatus | None = None
        """The newest status; None before the first."""

    def feed(self, data: bytes) -> UplinkStatus | None:
        """The newest status completed by `data`, if any (it is `status` then)."""
        payloads = self._deframer.feed(data)
        if not payloads:
            return None
        self.status = parse_uplink_status(payloads[-1])
        return self.status

    def resync(self) -> None:
        """The byte stream broke off (a reconnect): forget the partial chunk."""
        self._deframer.resync()
