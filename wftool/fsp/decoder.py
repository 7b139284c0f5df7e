"""The streaming FSP decoder: bytes in, timed state packets out, every anomaly counted.

`StateDecoder.feed` takes bytes as they arrive from any transport. It never raises on
input. On top of framing (`framing.Deframer`) it keeps the books a flight needs:
transport loss (E1 `seq` gaps, or `sample_time_us` gaps without E1) apart from frames the
FC itself dropped (E1 `drops`), wraps and resets of the FC clock, and each frame's time
on the OBC clock. With E2 (spec §10) it also takes the FC's time replies, places their FC
times in the stream's and pairs them with the commands sent (`round_trips`); a decoder
without E2 counts each reply as one chunk of bad length.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, fields

from wftool.fsp.clock import (
    U32,
    ClockEstimator,
    ClockState,
    FcClock,
    RoundTripObserver,
    make_estimator,
)
from wftool.fsp.framing import (
    COMMAND_VERSIONS,
    STATE_E2_VERSIONS,
    STATE_VERSIONS,
    Deframer,
    Rejection,
)
from wftool.fsp.packets import (
    DROPS_MODULUS,
    SEQ_MODULUS,
    TIME_REPLY_LENGTH,
    CommandPacket,
    StatePacket,
    TimeReply,
    parse_command,
    parse_state,
    parse_time_reply,
)
from wftool.fsp.twoway import RoundTripMatcher, RoundTripRejection

_SEQ_HALF = SEQ_MODULUS // 2
_HALF_U32 = U32 // 2
REPLY_PLACE_US = 1_000_000
"""A time reply's FC send time lies this close to the latest state packet's (spec §10)."""


@dataclass
class StreamStats:
    """Running totals of one decoder. Loss figures restart their baselines at an FC reset."""

    bytes: int = 0
    packets: int = 0
    frames: int = 0
    rejected: dict[Rejection, int] = field(default_factory=dict)
    lost_packets: int = 0
    """State packets missing from the E1 `seq` sequence (transport loss; E1 only)."""
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

    @property
    def errors(self) -> int:
        """Chunks that did not decode, all causes."""
        return sum(self.rejected.values())

    def __add__(self, later: StreamStats) -> StreamStats:
        """The totals of two streams (say, two connections), `later` after this one."""
        summed = {
            f.name: getattr(self, f.name) + getattr(later, f.name)
            for f in fields(self)
            if f.name not in ("rejected", "e1")
        }
        rejected = {
            cause: self.rejected.get(cause, 0) + later.rejected.get(cause, 0) for cause in Rejection
        }
        e1 = later.e1 if later.e1 is not None else self.e1
        return StreamStats(**summed, rejected=rejected, e1=e1)


class StateDecoder:
    """Decodes the FC → OBC stream. One instance per port; not thread-safe."""

    def __init__(
        self, clock: ClockEstimator | str | None = None, *, time_replies: bool | None = None
    ) -> None:
        """`clock`: an estimator, or its name in `clock.ESTIMATORS` (default: "envelope").
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
        self._deframer = Deframer(STATE_E2_VERSIONS if time_replies else STATE_VERSIONS)
        self.stats = StreamStats(rejected=self._deframer.rejected)
        self._last: StatePacket | None = None
        self._epoch = 0

    @property
    def clock_state(self) -> ClockState:
        return self.clock.state

    @property
    def last_packet(self) -> StatePacket | None:
        """The newest packet decoded (None before the first)."""
        return self._last

    def feed(self, data: bytes, arrival_time: float | None = None) -> list[StatePacket]:
        """Packets completed by `data`; `arrival_time` (OBC clock, s) enables clock alignment."""
        self.stats.bytes += len(data)
        payloads = self._deframer.feed(data)
        if self.round_trips is None:
            return self._account([parse_state(payload) for payload in payloads], arrival_time)
        packets: list[StatePacket] = []
        start = 0
        for index, payload in enumerate(payloads):
            if len(payload) == TIME_REPLY_LENGTH:  # the stream's order matters: packets first
                packets += self._account(map(parse_state, payloads[start:index]), arrival_time)
                self._time_reply(parse_time_reply(payload), arrival_time)
                start = index + 1
        return packets + self._account(map(parse_state, payloads[start:]), arrival_time)

    def _account(
        self, parsed: Iterable[StatePacket], arrival_time: float | None
    ) -> list[StatePacket]:
        """Unwrap, time and count `parsed`, the stream's next state packets."""
        packets = list(parsed)
        if not packets:
            return packets
        stats = self.stats
        unwrap = self._fc_clock.unwrap
        clock = self.clock
        last = self._last
        for packet in packets:
            # Unwrap the oldest instant in the packet; the others follow it within a period.
            first, second = packet.frames
            base_raw = first.values[0]
            base_us, reset = unwrap(base_raw, arrival_time)
            if reset:
                self._epoch += 1
                last = None
                clock.reset()
            first.time_us = base_us
            second.time_us = second_us = base_us + (second.values[0] - base_raw) % U32
            packet.time_us = time_us = base_us + (packet.tx_time_us - base_raw) % U32
            packet.arrival_time = arrival_time
            packet.epoch = self._epoch
            if arrival_time is not None:
                clock.observe(time_us, arrival_time)
                first.obc_time = clock.to_obc(base_us)
                second.obc_time = clock.to_obc(second_us)
            if last is not None:
                self._count_loss(last, packet, base_us, second_us)
            last = packet
        self._last = last
        stats.e1 = last.e1
        stats.packets += len(packets)
        stats.frames += 2 * len(packets)
        stats.wraps = self._fc_clock.wraps
        stats.resets = self._fc_clock.resets
        return packets

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

    def _count_loss(
        self, last: StatePacket, packet: StatePacket, base_us: int, second_us: int
    ) -> None:
        stats = self.stats
        if packet.e1 and last.e1:
            gap = (packet.seq - last.seq - 1) % SEQ_MODULUS
            if gap and gap < _SEQ_HALF:  # a larger gap is a repeat or reorder: nothing lost
                stats.lost_packets += gap
                stats.lost_frames += 2 * gap
            if packet.drops != last.drops:
                stats.fc_drops += (packet.drops - last.drops) % DROPS_MODULUS
        else:
            period = second_us - base_us
            if period > 0:
                missing = round((base_us - last.frames[1].time_us) / period) - 1
                stats.lost_frames += max(0, missing)


class CommandDecoder:
    """Decodes the OBC → FC command stream: what the FC does, for tests and simulators."""

    def __init__(self) -> None:
        self._deframer = Deframer(COMMAND_VERSIONS)
        self.rejected = self._deframer.rejected

    def feed(self, data: bytes) -> list[CommandPacket]:
        return [parse_command(payload) for payload in self._deframer.feed(data)]
