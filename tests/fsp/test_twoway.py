"""Two-way timing (spec §8.3, §10): time replies paired with commands, the absolute FC→OBC
clock from round trips, and the bad input that must never move it.

A simulated link with known truth produces real wire bytes (state packets and time replies,
in the FC's send order, first in first out) and the commands the OBC sends; they go through
`StateDecoder` exactly as from a port.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

import pytest

from wftool.fsp import SensorFrame, StateDecoder, StatePacket
from wftool.fsp.clock import RoundTripObserver
from wftool.fsp.encoder import CommandSender, encode_state, encode_time_reply
from wftool.fsp.estimators import make_estimator
from wftool.fsp.framing import Rejection
from wftool.fsp.packets import TimeReply
from wftool.fsp.twoway import RoundTripRejection, TwoWayClockEstimator

U32 = 1 << 32
RC = (1500, 1500, 1500, 1000, 1000, 1000)


def frame(sample_time_us: int) -> SensorFrame:
    return SensorFrame(sample_time_us % U32, (0, 0, 4096), 4096, 0.06, (0, 0, 0), (-32768, 0, 0, 0),
                       RC, (0, 0, 0, 0), 1680)  # fmt: skip


@dataclass
class Link:
    """FC clock → OBC clock t_o = rate·t_f + offset; delays d_min + exponential, both ways;
    commands also wait up to a task period on the FC (the asymmetry two-way must live with)."""

    seed: int = 1
    rate: float = 1 + 35e-6
    offset_s: float = 1000.0
    d_min_s: float = 0.4e-3
    jitter_s: float = 0.2e-3
    task_wait_s: float = 1.0e-3
    packet_period_us: int = 1000
    command_period_s: float = 0.02
    fc_start_us: int = 5_000_000
    obc_step: tuple[float, float] = (math.inf, 0.0)
    """(true instant, step): from then on the OBC clock reads `step` s later."""
    fc_pause: tuple[int, float] = (U32 << 8, 0.0)
    """(FC µs, seconds): the FC clock stands still there that long (a virtual FC whose
    lockstep clock re-anchors after the host fell behind)."""
    """(true instant, step): from then on the OBC clock reads `step` s later."""
    events: list[tuple[float, int, str, object]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)

    def truth(self, fc_us: float) -> float:
        paused_at, pause_s = self.fc_pause
        return self.offset_s + self.rate * fc_us * 1e-6 + (pause_s if fc_us > paused_at else 0.0)

    def obc_clock(self, t: float) -> float:
        """What the OBC clock reads at true instant `t`."""
        at, step = self.obc_step
        return t + step if t >= at else t

    def fc_of(self, obc: float) -> int:
        paused_at, pause_s = self.fc_pause
        if obc >= self.truth(paused_at) + pause_s:
            obc -= pause_s
        elif obc >= self.truth(paused_at):
            return paused_at
        return round((obc - self.offset_s) / self.rate * 1e6)

    def delay(self) -> float:
        return self.d_min_s + self.rng.expovariate(1.0 / self.jitter_s)

    def build(self, seconds: float) -> list[tuple[float, int, str, object]]:
        """Time-ordered events: ("send", seq) commands and ("bytes", wire) arrivals."""
        downlink: list[tuple[int, bytes]] = []  # (FC send time, wire) in FC send order
        fc_end = self.fc_start_us + round(seconds * 1e6)
        for seq, tx in enumerate(range(self.fc_start_us, fc_end, self.packet_period_us)):
            frames = (frame(tx - 700), frame(tx - 200))
            downlink.append((tx, encode_state(StatePacket(tx % U32, frames, seq, True, 0))))
        commands = []
        t1 = self.truth(self.fc_start_us) + 0.05
        seq = 0
        while t1 < self.truth(fc_end) - 0.05:
            received = self.fc_of(t1 + self.delay() + self.rng.uniform(0, self.task_wait_s))
            sent = received + self.rng.choice((0, 0, 125))
            commands.append((t1, seq, received, sent))
            t1 += self.command_period_s
            seq += 1
        for t1, seq, received, sent in commands:
            tx_time_us = int(self.obc_clock(t1) * 1e6) % U32  # the FC echoes the OBC's stamp
            reply = TimeReply(seq, tx_time_us, received % U32, sent % U32)
            downlink.append((sent, encode_time_reply(reply)))
            self.events.append((t1, 0, "send", seq))
        downlink.sort(key=lambda item: item[0])
        arrival = -math.inf
        for tx, wire in downlink:  # a serial link is first in, first out
            arrival = max(arrival + 1e-6, self.truth(tx) + self.delay())
            self.events.append((arrival, 1, "bytes", wire))
        self.events.sort(key=lambda event: event[:2])
        return self.events


@dataclass
class Run:
    decoder: StateDecoder
    errors: list[tuple[float, float, float]] = field(default_factory=list)
    """(OBC time, frame error vs truth, reported uncertainty) for every frame decoded."""


def run(link: Link, seconds: float, decoder: StateDecoder | None = None) -> Run:
    decoder = decoder if decoder is not None else StateDecoder("twoway")
    sender = CommandSender(round_trips=decoder.round_trips)
    result = Run(decoder)
    for t, _, kind, payload in link.build(seconds):
        if kind == "send":
            sender.next(RC, now=t)
            continue
        for packet in decoder.feed(payload, t):  # type: ignore[arg-type]
            uncertainty = decoder.clock.state.uncertainty_s
            for f in packet.frames:
                truth = link.truth(link.fc_start_us + (f.time_us - link.fc_start_us))
                result.errors.append((t, f.obc_time - truth, uncertainty))
    return result


def two_way(decoder: StateDecoder) -> TwoWayClockEstimator:
    assert isinstance(decoder.clock, TwoWayClockEstimator)
    return decoder.clock


def test_twoway_is_selectable_and_takes_round_trips() -> None:
    clock = make_estimator("twoway")
    assert isinstance(clock, RoundTripObserver)
    assert StateDecoder("twoway").round_trips is not None
    assert StateDecoder().round_trips is None  # a plain decoder: v5 without E2
    assert not isinstance(make_estimator("envelope"), RoundTripObserver)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_truth_lies_within_the_reported_uncertainty(seed: int) -> None:
    link = Link(seed=seed)
    result = run(link, 20.0)
    state = two_way(result.decoder).two_way
    assert state.active and state.round_trips > 100
    late = [(e, u) for t, e, u in result.errors if t > link.truth(link.fc_start_us) + 10.0]
    assert late
    assert all(abs(e) <= u + 1e-6 for e, u in late), max(abs(e) - u for e, u in late)
    # it removes d_min, which one-way timing cannot: the error is far below it
    assert max(abs(e) for e, _ in late) < link.d_min_s / 4
    low, high = state.delay_bounds_s
    assert low - 1e-6 <= link.d_min_s <= high + 1e-6
    matcher = result.decoder.round_trips
    assert matcher is not None and matcher.matched > 900
    assert not any(matcher.rejected.values())


def test_one_way_error_is_d_min_and_two_way_removes_it() -> None:
    link = Link(seed=4)
    one_way = run(Link(seed=4), 15.0, StateDecoder("envelope"))
    late_one = [e for t, e, _ in one_way.errors if t > link.truth(link.fc_start_us) + 10.0]
    assert abs(sorted(late_one)[len(late_one) // 2] - link.d_min_s) < 50e-6
    result = run(link, 15.0)
    late_two = [e for t, e, _ in result.errors if t > link.truth(link.fc_start_us) + 10.0]
    assert max(map(abs, late_two)) < 0.25 * min(map(abs, late_one))


def snapshot(decoder: StateDecoder) -> tuple[float | None, float]:
    clock = two_way(decoder)
    return clock.to_obc(10_000_000), clock.two_way.uncertainty_s


def warmed_up(seed: int = 5) -> tuple[Link, StateDecoder, CommandSender, int]:
    """A decoder with an active two-way estimate, its sender, and the last FC packet time."""
    link = Link(seed=seed)
    result = run(link, 12.0)
    decoder = result.decoder
    assert two_way(decoder).two_way.active
    sender = CommandSender(round_trips=decoder.round_trips)
    sender.seq = 10_000  # new commands, as the same sender would number them
    last = decoder.last_packet
    assert last is not None and last.time_us is not None
    return link, decoder, sender, last.time_us


def reply_to(command_seq: int, command_tx: int, received: int, sent: int) -> bytes:
    return encode_time_reply(TimeReply(command_seq, command_tx, received % U32, sent % U32))


def test_reply_that_answers_no_command_is_counted_and_ignored() -> None:
    link, decoder, sender, fc_now = warmed_up()
    before = snapshot(decoder)
    t = link.truth(fc_now) + 1e-3
    # a command never sent, and one sent but answered with another tx time (another program's)
    packet = sender.next(RC, now=t)
    decoder.feed(reply_to(packet.seq + 7, packet.tx_time_us, fc_now, fc_now), t + 1e-3)
    decoder.feed(reply_to(packet.seq, packet.tx_time_us ^ 1, fc_now, fc_now), t + 1e-3)
    matcher = decoder.round_trips
    assert matcher is not None
    assert matcher.rejected[RoundTripRejection.UNMATCHED] == 2
    assert snapshot(decoder) == before
    # the real answer is taken, a second copy of it is not
    real = answered(link, sender, t + 0.01)
    decoder.feed(real, t + 1.1e-3)
    decoder.feed(real, t + 1.2e-3)
    assert matcher.rejected[RoundTripRejection.DUPLICATE] == 1


def test_reply_from_before_an_fc_reset_is_stale() -> None:
    link, decoder, sender, fc_now = warmed_up()
    t = link.truth(fc_now) + 1e-3
    stale = answered(link, sender, t)
    # the FC reboots: its clock starts near zero; the reply of the old epoch arrives after
    reboot = [encode_state(StatePacket(2_000_000 + k * 1000, (frame(1_999_000 + k * 1000),
              frame(1_999_500 + k * 1000)), k, True, 0)) for k in range(3)]  # fmt: skip
    for k, wire in enumerate(reboot):
        decoder.feed(wire, t + 0.1 + k * 1e-3)
    assert decoder.stats.resets == 1
    assert not two_way(decoder).two_way.active  # the reset cleared the round trips
    decoder.feed(stale, t + 0.2)
    matcher = decoder.round_trips
    assert matcher is not None and matcher.rejected[RoundTripRejection.STALE] == 1
    assert not two_way(decoder).two_way.active and two_way(decoder).accepted > 0
    # and before any state packet of a fresh connection, a reply cannot be placed at all
    fresh = StateDecoder("twoway")
    CommandSender(round_trips=fresh.round_trips).next(RC, now=t)
    fresh.feed(reply_to(0, int(t * 1e6) % U32, 5, 6), t + 1e-3)
    assert fresh.round_trips is not None
    assert fresh.round_trips.rejected[RoundTripRejection.STALE] == 1


def test_round_trip_longer_than_the_bound_is_counted_and_ignored() -> None:
    link, decoder, sender, fc_now = warmed_up()
    before = snapshot(decoder)
    t = link.truth(fc_now) + 1e-3
    # answered promptly by the FC, but read 30 ms later (a stalled OBC): far too loose
    decoder.feed(answered(link, sender, t), t + 30e-3)
    assert two_way(decoder).rejected[RoundTripRejection.TOO_LONG] == 1
    assert snapshot(decoder) == before


def test_obc_clock_step_within_a_round_trip_is_counted_and_ignored() -> None:
    link, decoder, sender, fc_now = warmed_up()
    before = snapshot(decoder)
    t = link.truth(fc_now) + 1e-3
    decoder.feed(answered(link, sender, t), t - 5e-3)  # the OBC clock stepped back 6 ms
    assert two_way(decoder).rejected[RoundTripRejection.CLOCK_STEP] == 1
    assert snapshot(decoder) == before


def answered(link: Link, sender: CommandSender, t: float, late_s: float = 0.0) -> bytes:
    """A command sent at OBC time `t` (stamped `late_s` later: its clock jumped and came
    back) and the FC's reply: 0.5 ms up, held 0.1 ms; read it 0.5 ms later, at t + 1.1 ms."""
    packet = sender.next(RC, now=t + late_s)
    received, sent = link.fc_of(t + 0.5e-3), link.fc_of(t + 0.6e-3)
    return reply_to(packet.seq, packet.tx_time_us, received, sent)


def round_trip_stamped_late(
    link: Link, decoder: StateDecoder, sender: CommandSender, t: float, late_s: float
) -> None:
    decoder.feed(answered(link, sender, t, late_s), t + 1.1e-3)


def test_lone_round_trip_narrower_than_the_others_never_moves_the_offset() -> None:
    link, decoder, sender, fc_now = warmed_up()
    before = snapshot(decoder)
    round_trip_stamped_late(link, decoder, sender, link.truth(fc_now) + 1e-3, 0.8e-3)
    clock = two_way(decoder)
    assert clock.two_way.outliers == 1  # its bound lies beyond every other's: unconfirmed
    # (the window's oldest round trip made room for it: that may move the bounds a little;
    # taking the lone one's bound would move the offset by 0.36 ms)
    assert abs(snapshot(decoder)[0] - before[0]) < 10e-6  # type: ignore[operator]


def test_a_faster_packet_lowers_the_one_way_line_not_the_two_way_clock() -> None:
    """A packet arrives 40 µs faster than the one-way line allows, with no round trip after
    it: the line drops, d_min (its height) with it, and the OBC times stay where the round
    trips put them, within the uncertainty of the truth."""
    link, decoder, _, fc_now = warmed_up()
    clock = two_way(decoder)
    before, uncertainty = snapshot(decoder)
    line_before = clock.one_way.to_obc(10_000_000)
    last = decoder.last_packet
    assert last is not None and last.seq is not None
    assert before is not None and line_before is not None
    tx = fc_now + link.packet_period_us
    frames = (frame(tx - 700), frame(tx - 200))
    fast = encode_state(StatePacket(tx % U32, frames, last.seq + 1, True, 0))
    line_at_tx = clock.one_way.to_obc(tx)
    assert line_at_tx is not None
    decoder.feed(fast, line_at_tx - 40e-6)  # still 0.36 ms after it left: a delay ≥ 0
    line_after = clock.one_way.to_obc(10_000_000)
    assert line_after is not None and line_before - line_after > 20e-6  # E dropped
    after = clock.to_obc(10_000_000)
    assert after is not None and abs(after - before) < 1e-6
    assert abs(after - link.truth(10_000_000)) <= uncertainty


def test_lone_round_trip_off_the_others_is_held_then_rejected() -> None:
    link, decoder, sender, fc_now = warmed_up()
    before = snapshot(decoder)
    t = link.truth(fc_now) + 1e-3
    round_trip_stamped_late(link, decoder, sender, t, 0.97e-3)  # bounds disjoint from all
    clock = two_way(decoder)
    assert len(clock._held) == 1 and snapshot(decoder) == before
    round_trip_stamped_late(link, decoder, sender, t + 0.02, 0.0)  # a good one follows
    assert clock.rejected[RoundTripRejection.INCONSISTENT] == 1 and not clock._held
    assert abs(snapshot(decoder)[0] - before[0]) < 1e-6  # type: ignore[operator]


def test_obc_clock_step_between_round_trips_is_followed_not_averaged() -> None:
    """From some instant on, every OBC time is 3 ms later (the OBC clock stepped): the
    estimate is the old one until the step is confirmed, then the new one — never between."""
    step_s = 3e-3
    at = Link().truth(Link.fc_start_us) + 10.0
    link = Link(seed=6, obc_step=(at, step_s))
    events = link.build(16.0)
    decoder = StateDecoder("twoway")
    sender = CommandSender(round_trips=decoder.round_trips)
    errors = []
    for t, _, kind, payload in events:
        shifted = link.obc_clock(t)
        if kind == "send":
            sender.next(RC, now=shifted)
            continue
        for packet in decoder.feed(payload, shifted):  # type: ignore[arg-type]
            for f in packet.frames:
                truth = link.truth(f.time_us)
                errors.append((t, f.obc_time - truth, f.obc_time - truth - step_s))
    clock = two_way(decoder)
    assert clock.steps + clock.one_way.state.steps >= 1
    before = [abs(old) for t, old, _ in errors if at - 2.0 < t < at]
    after = [abs(new) for t, _, new in errors if t > at + 3.0]
    assert max(before) < 60e-6 and max(after) < 60e-6
    # in between each frame is on the old clock or the new one, never in the middle
    between = [min(abs(old), abs(new)) for t, old, new in errors if at <= t <= at + 3.0]
    assert max(between) < 0.5 * step_s


@pytest.mark.parametrize("paused_after_s", [2.0, 10.0])
def test_fc_clock_standing_still_is_followed_and_never_led(paused_after_s: float) -> None:
    """The FC clock stands still for 0.3 s (a virtual FC re-anchoring its lockstep clock),
    while the one-way line is still learning its rate or already locked: the estimate may lag
    (the old mapping) until the step is seen, never run ahead of the truth, and is back
    within its uncertainty once the round trips are."""
    pause_s = 0.3
    link = Link(seed=7, fc_pause=(Link.fc_start_us + round(paused_after_s * 1e6), pause_s))
    result = run(link, 25.0)
    clock = two_way(result.decoder)
    assert clock.one_way.state.steps >= 1
    start = link.truth(link.fc_start_us)
    assert max(e for _, e, _ in result.errors) < 0.01 * pause_s  # never ahead of the truth
    late = [(e, u) for t, e, u in result.errors if t > start + paused_after_s + pause_s + 8.0]
    assert clock.two_way.active and late
    assert all(abs(e) <= u + 1e-6 for e, u in late), max(abs(e) - u for e, u in late)
    assert max(abs(e) for e, _ in late) < 60e-6


def test_reply_decoded_without_e2_counts_one_chunk_and_loses_nothing() -> None:
    link = Link(seed=7)
    plain = StateDecoder()
    packets = [p for t, _, kind, wire in link.build(3.0) if kind == "bytes"
               for p in plain.feed(wire, t)]  # type: ignore[arg-type]  # fmt: skip
    replies = sum(1 for _, _, kind, _ in link.events if kind == "send")
    assert plain.stats.rejected[Rejection.LENGTH] == plain.stats.errors == replies
    assert len(packets) == plain.stats.packets and plain.stats.lost_packets == 0
    assert plain.stats.time_replies == 0
