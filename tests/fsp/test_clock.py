"""Clock alignment on simulated clocks: known skew and offset, noisy one-way delay.

The FC stream is simulated at the packet level (525 packets/s, 953 µs frame period) and
decoded through the real decoder, so unwrapping, reset detection and the estimator are
tested together as the OBC uses them.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

import pytest

from tests.fsp.test_decoder import frame as blank_frame
from wftool.fsp import FcClock, KalmanClockEstimator, StateDecoder, StatePacket
from wftool.fsp.encoder import encode_state

PERIOD_US = 953
MIN_DELAY_S = 0.0006
JITTER_S = 0.0003  # mean of the exponential part of the one-way delay


@dataclass
class SimulatedLink:
    """An FC whose clock runs `skew_ppm` slow against the OBC, seen through a noisy link."""

    skew_ppm: float = 80.0
    offset_s: float = 1234.5
    fc_us: int = 5_000_000
    seed: int = 1
    decoder: StateDecoder = field(default_factory=StateDecoder)
    errors: list[float] = field(default_factory=list)
    seq: int = 0
    obc_shift_s: float = 0.0  # moves the FC→OBC mapping, e.g. at a reboot

    def __post_init__(self) -> None:
        self.random = random.Random(self.seed)

    def obc_of(self, fc_us: int) -> float:
        return (1 + self.skew_ppm * 1e-6) * fc_us * 1e-6 + self.offset_s + self.obc_shift_s

    def run(self, seconds: float) -> None:
        for _ in range(int(seconds * 1e6 / (2 * PERIOD_US))):
            f0, f1 = self.fc_us, self.fc_us + PERIOD_US
            tx = f1 + 150
            arrival = self.obc_of(tx) + MIN_DELAY_S + self.random.expovariate(1 / JITTER_S)
            packet = StatePacket(
                tx % 2**32, (blank_frame(f0), blank_frame(f1)), self.seq % 2**24, True
            )
            (decoded,) = self.decoder.feed(encode_state(packet), arrival)
            self.last = decoded
            for frame, true_fc in zip(decoded.frames, (f0, f1)):
                truth = self.obc_of(true_fc) + MIN_DELAY_S + JITTER_S
                self.errors.append(frame.obc_time - truth)
            self.fc_us += 2 * PERIOD_US
            self.seq += 1

    def worst_error_since(self, index: int) -> float:
        return max(abs(e) for e in self.errors[index:])


def test_converges_to_skew_and_tracks_ground_truth():
    link = SimulatedLink(skew_ppm=80.0)
    link.run(30)
    settled = len(link.errors)
    link.run(60)
    state = link.decoder.clock_state
    assert state.locked and state.reinits == 0
    assert state.rate_ppm == pytest.approx(80.0, abs=10.0)
    assert link.worst_error_since(settled) < 0.0015


def test_negative_skew_and_large_offset():
    link = SimulatedLink(skew_ppm=-150.0, offset_s=-50_000.0, seed=7)
    link.run(60)
    assert link.decoder.clock_state.rate_ppm == pytest.approx(-150.0, abs=20.0)
    assert link.worst_error_since(len(link.errors) // 2) < 0.0015


def test_u32_wrap_is_not_a_reset():
    link = SimulatedLink(fc_us=2**32 - 20_000_000)  # wraps 20 s in
    link.run(15)
    settled = len(link.errors)
    link.run(30)
    stats = link.decoder.stats
    assert (stats.wraps, stats.resets, stats.lost_packets) == (1, 0, 0)
    assert link.decoder.clock_state.reinits == 0
    assert link.worst_error_since(settled) < 0.0015


def test_reboot_reinitialises_and_tracks_again():
    link = SimulatedLink()
    link.run(20)
    # The FC reboots: 3 s of silence, then its clock restarts near zero.
    link.obc_shift_s = link.obc_of(link.fc_us) + 3.0 - link.obc_of(1_500_000)
    link.fc_us, link.seq = 1_500_000, 0
    before = len(link.errors)
    link.run(20)
    stats = link.decoder.stats
    assert (stats.resets, stats.wraps, stats.lost_packets) == (1, 0, 0)
    assert link.last.epoch == 1
    assert link.worst_error_since(before + 4000) < 0.0015


def test_reboot_just_before_a_wrap_is_still_a_reset():
    """Seen modulo 2^32 the new clock is 'ahead'; only the OBC clock can tell."""
    link = SimulatedLink(fc_us=2**32 - 5_000_000)
    link.run(4)  # stops ~1 s before the wrap
    link.obc_shift_s = link.obc_of(link.fc_us) + 0.5 - link.obc_of(2_000_000)
    link.fc_us = 2_000_000
    link.run(5)
    assert (link.decoder.stats.resets, link.decoder.stats.wraps) == (1, 0)


def test_paused_fc_clock_reinitialises_the_estimator():
    link = SimulatedLink()
    link.run(30)
    link.obc_shift_s += 2.0  # the FC clock stood still for 2 s (e.g. calibration)
    link.run(10)
    assert link.decoder.stats.resets == 0
    assert link.decoder.clock_state.reinits == 1
    assert link.worst_error_since(len(link.errors) - 2000) < 0.0015


def test_fc_clock_without_obc_times_uses_half_range_rule():
    clock = FcClock()
    assert clock.unwrap(2**32 - 10) == (2**32 - 10, False)
    assert clock.unwrap(5) == (2**32 + 5, False)
    assert clock.wraps == 1
    assert clock.unwrap(2**31 + 100) == (2**31 + 100, True)  # backwards by > half: reset
    assert clock.resets == 1


def test_long_gap_spanning_several_wraps():
    clock = FcClock()
    clock.unwrap(1000, obc_time=0.0)
    three_wraps_later = 3 * 2**32 + 500_000
    time_us, reset = clock.unwrap(three_wraps_later % 2**32, obc_time=three_wraps_later * 1e-6)
    assert (time_us, reset, clock.wraps) == (three_wraps_later, False, 3)


def test_estimator_updates_every_hundredth_packet():
    estimator = KalmanClockEstimator()
    for i in range(250):
        estimator.observe(i * 2000, 10.0 + i * 0.002)
    assert estimator.state.updates == 2
    assert estimator.to_obc(250 * 2000) == pytest.approx(10.5, abs=1e-6)
