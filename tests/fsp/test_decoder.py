"""Decoder bookkeeping: loss vs FC drops, with and without E1; memory; physical units."""

from __future__ import annotations

import math
import tracemalloc

import pytest

from wftool.fsp import (
    Authority,
    AuthorityExit,
    CommandOutcome,
    CommandReport,
    SensorFrame,
    StateDecoder,
    StatePacket,
    UplinkStatus,
)
from wftool.fsp.decoder import COMMAND_REPORTS_KEPT
from wftool.fsp.encoder import encode_command_report, encode_state, encode_uplink_status

PERIOD = 953


def frame(t_us: int, **values) -> SensorFrame:
    fields = dict(
        sample_time_us=t_us % 2**32, acc=(0, 0, 0), acc_1g=0, gyro_scale=0.0, gyro=(0, 0, 0),
        attitude=(0, 0, 0, 0), rc=(0,) * 6, rpm=(0,) * 4, vbat=0,
    )  # fmt: skip
    fields.update(values)
    return SensorFrame(**fields)


def stream(indices, *, e1: bool, drops=lambda i: 0) -> bytes:
    """Packets number `indices` of a steady stream (two frames each)."""
    out = b""
    for i in indices:
        t = 1_000_000 + 2 * i * PERIOD
        packet = StatePacket(t + PERIOD + 100, (frame(t), frame(t + PERIOD)), i, e1, drops(i))
        out += encode_state(packet)
    return out


def packet_at(
    seq: int, t_us: int, period: int = PERIOD, *, e1: bool = True, drops: int = 0
) -> bytes:
    """Wire bytes of the E1 packet numbered `seq` whose first frame was captured at `t_us`."""
    frames = (frame(t_us), frame(t_us + period))
    tx_us = (t_us + period + 100) % 2**32
    return encode_state(StatePacket(tx_us, frames, seq % 2**24, e1, drops % 2**16))


def feed_each(decoder: StateDecoder, wire: list[bytes], timed: bool) -> list[StatePacket]:
    """Feed one packet per read, arriving in real time if `timed`."""
    packets = []
    for index, data in enumerate(wire):
        packets += decoder.feed(data, 100.0 + index * 2 * PERIOD * 1e-6 if timed else None)
    return packets


def test_e1_separates_transport_loss_from_fc_drops():
    decoder = StateDecoder()
    kept = [i for i in range(100) if i not in (10, 11, 50)]
    decoder.feed(stream(kept, e1=True, drops=lambda i: 7 + (i >= 30) * 4))
    stats = decoder.stats
    assert (stats.lost_packets, stats.lost_frames, stats.fc_drops) == (3, 6, 4)
    assert stats.e1 is True


def test_without_e1_loss_is_inferred_from_sample_time_gaps():
    decoder = StateDecoder()
    kept = [i for i in range(100) if i not in (10, 11, 50)]
    decoder.feed(stream(kept, e1=False))
    stats = decoder.stats
    assert (stats.lost_frames, stats.lost_packets, stats.fc_drops) == (6, 0, 0)
    assert stats.e1 is False


def test_drop_counter_wraps_modulo_2_16():
    decoder = StateDecoder()
    decoder.feed(stream(range(4), e1=True, drops=lambda i: (65534 + i) % 65536))
    assert decoder.stats.fc_drops == 3


def test_seq_repeat_is_not_counted_as_loss():
    decoder = StateDecoder()
    decoder.feed(stream([0, 1, 2, 2, 3], e1=True))
    assert decoder.stats.lost_packets == 0


@pytest.mark.parametrize("period", [PERIOD, 125])  # fsp_rate_hz 1049 and 8000
def test_a_reboot_after_half_the_counter_is_a_reset_without_arrival_times(period: int):
    """Up for 2^31 µs + 10 s (35.8 min), then rebooted: modulo 2^32 the new clock looks a
    step ahead, a wrap. Only E1 `seq`, starting over and going on from there, says otherwise."""
    uptime = 2**31 + 10_000_000
    seq = uptime // (2 * period)  # > 2^23 at 8 kHz: the gap back to 0 looks like a loss
    before = [packet_at(seq + i, uptime + 2 * i * period, period) for i in range(100)]
    after = [packet_at(i, 1_500_000 + 2 * i * period, period) for i in range(100)]
    decoder = StateDecoder()
    packets = decoder.feed(b"".join(before + after[:1]))  # the reboot, last in its read
    packets += decoder.feed(b"".join(after[1:]))
    stats = decoder.stats
    assert (stats.resets, stats.wraps, stats.lost_packets) == (1, 0, 0)
    assert [p.epoch for p in packets] == [0] * 100 + [1] * 100
    assert packets[100].frames[0].time_us == 1_500_000
    assert stats.outliers == 0 and not any(p.outlier for p in packets)


@pytest.mark.parametrize("timed", [False, True])
def test_one_repeated_old_packet_is_an_outlier_not_a_reset(timed: bool):
    wire = [packet_at(i, 1_000_000 + 2 * i * PERIOD) for i in range(1000)]
    wire.insert(901, wire[500])  # packet 500 again, after packet 900
    decoder = StateDecoder()
    packets = feed_each(decoder, wire, timed)
    stats = decoder.stats
    assert (stats.resets, stats.wraps, stats.lost_packets) == (0, 0, 0)
    assert {p.epoch for p in packets} == {0}
    assert [p.frames[0].time_us for p in packets[902:904]] == [
        1_000_000 + 2 * i * PERIOD for i in (901, 902)
    ]
    assert stats.outliers == 1 and [i for i, p in enumerate(packets) if p.outlier] == [901]


@pytest.mark.parametrize("timed", [False, True])
@pytest.mark.parametrize("wild_us", [3_000_000_000, 1_000_000 + 2 * 500 * PERIOD + 400_000, 5])
def test_a_wild_sample_time_that_passed_the_crc_is_an_outlier(timed: bool, wild_us: int):
    """Far off, 0.4 s ahead (a steady step, but not with the seq it carries), or behind."""
    wire = [packet_at(i, 1_000_000 + 2 * i * PERIOD) for i in range(1000)]
    wire[500] = packet_at(500, wild_us)
    decoder = StateDecoder()
    packets = feed_each(decoder, wire, timed)
    stats = decoder.stats
    assert (stats.resets, stats.wraps) == (0, 0)
    assert {p.epoch for p in packets} == {0}
    assert (stats.lost_packets, stats.lost_frames) == (1, 2)  # its frames are not in the books
    if timed:  # the clock was not misled: every booked frame on one line
        assert decoder.clock_state.steps == 0
    assert stats.outliers == 1 and [i for i, p in enumerate(packets) if p.outlier] == [500]


def test_frame_times_unwrap_inside_a_packet_straddling_the_wrap():
    decoder = StateDecoder()
    t0 = 2**32 - 500
    packet = StatePacket((t0 + PERIOD + 50) % 2**32, (frame(t0), frame(t0 + PERIOD)))
    (decoded,) = decoder.feed(encode_state(packet))
    assert [f.time_us for f in decoded.frames] == [t0, t0 + PERIOD]


def test_obc_time_needs_an_arrival_time():
    decoder = StateDecoder()
    (no_time,) = decoder.feed(stream([0], e1=True))
    (timed,) = decoder.feed(stream([1], e1=True), arrival_time=100.0)
    assert no_time.frames[0].obc_time is None
    assert timed.arrival_time == 100.0
    assert timed.frames[1].obc_time == pytest.approx(100.0 - 100e-6)


def test_memory_stays_flat_on_endless_garbage():
    decoder = StateDecoder()
    decoder.feed(b"\x01" * 10_000)
    tracemalloc.start()
    for _ in range(500):
        decoder.feed(b"\x01" * 10_000)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 100_000
    assert decoder.stats.rejected["length"] == 1  # one endless chunk, counted once
    assert decoder.feed(stream([0], e1=True)) == []  # still inside the garbage chunk
    assert len(decoder.feed(b"\x00" + stream([1], e1=True))) == 1


def test_physical_units():
    f = frame(
        0, acc=(2048, -1024, 0), acc_1g=2048, gyro_scale=0.5, gyro=(10, -4, 0),
        attitude=(-32768, 0, 0, 0), vbat=1587,
    )  # fmt: skip
    assert f.acc_g == (1.0, -0.5, 0.0)
    assert f.gyro_dps == (5.0, -2.0, 0.0)
    assert f.quaternion == (-1.0, 0.0, 0.0, 0.0)
    assert f.vbat_v == pytest.approx(15.87)
    assert f.euler_deg == pytest.approx((0.0, 0.0, 0.0))


def test_euler_angles_do_not_depend_on_quaternion_sign():
    half = math.sqrt(0.5)
    # 90° roll, then the same rotation written as -q
    q = (round(half * 32767), round(half * 32767), 0, 0)
    plus = frame(0, attitude=q).euler_deg
    minus = frame(0, attitude=tuple(-c for c in q)).euler_deg
    assert plus == pytest.approx(minus)
    assert plus[0] == pytest.approx(90.0, abs=0.01)


def test_acc_without_calibration_is_nan():
    assert all(math.isnan(v) for v in frame(0, acc=(1, 2, 3)).acc_g)


def test_the_chunk_cut_by_joining_is_told_apart():
    """Bytes before the first delimiter end a chunk whose start was never seen: rejected
    as any chunk, and also counted in `joined`; a resync joins anew, later garbage is not."""
    decoder = StateDecoder()
    wire = stream(range(20), e1=True)
    decoder.feed(wire[37:50], 1.0)  # inside packet 0, no delimiter yet
    decoder.feed(wire[50:], 1.1)
    assert decoder.stats.packets == 19
    assert sum(decoder.joined.values()) == sum(decoder.stats.rejected.values()) == 1
    decoder.feed(b"\x02\x07\x00", 1.2)  # after the stream was joined: an error alone
    assert sum(decoder.stats.rejected.values()) == 2 and sum(decoder.joined.values()) == 1
    decoder.resync()
    decoder.feed(wire[5:] + b"\x02\x07\x00", 1.3)  # the cut chunk, then the same garbage
    assert sum(decoder.joined.values()) == 2 and sum(decoder.stats.rejected.values()) == 4


def test_command_reports_are_kept_until_taken_and_no_more_than_a_bound():
    report = CommandReport(7, 0, 1_000_500, 1_000_600, CommandOutcome.ON_TIME, 0, (1,) * 6)
    decoder = StateDecoder()
    decoder.feed(encode_command_report(report))
    [before] = decoder.take_command_reports()
    assert before.event_time_us is None  # no state packet to place its times against yet
    decoder.feed(packet_at(0, 1_000_000))
    wire = encode_command_report(report) * (COMMAND_REPORTS_KEPT + 10)
    decoder.feed(wire)
    kept = decoder.take_command_reports()
    assert len(kept) == COMMAND_REPORTS_KEPT and decoder.stats.command_reports == len(kept) + 11
    assert kept[0].event_time_us == 1_000_600 and kept[0].at_time_us == 1_000_500


def authority_status(tx_time_us: int, exit_us: int, exit: AuthorityExit) -> bytes:
    """Wire bytes of a 64-byte uplink status (spec §12) sent at `tx_time_us`."""
    return encode_uplink_status(
        UplinkStatus(
            9, tx_time_us % 2**32, 9, 1, 1, 0, 50, 0, 0, (exit_us - 1000) % 2**32,
            Authority.PROVING, exit, 500, exit_us % 2**32, 0x5A17C3, 0, 0, 0, 885, 2115,
        )
    )  # fmt: skip


@pytest.mark.parametrize("start_us", [1_000_000, 2**32 - 2_500])
def test_an_exit_is_dated_on_the_stream_clock_like_the_timeout(start_us: int):
    """`exit_us` unwraps against the status's own send time, placed in the stream's 64-bit
    FC time: a wrap between the exit and the status changes nothing."""
    decoder = StateDecoder()
    decoder.feed(packet_at(0, start_us) + packet_at(1, start_us + 2 * PERIOD))
    last = decoder.last_packet
    assert last is not None and last.time_us is not None
    sent = last.time_us + 40
    assert (sent > 2**32) == (start_us > 2**31)  # the status after the wrap, the exit before
    exit_at = sent - 4_000
    decoder.feed(authority_status(sent, exit_at, AuthorityExit.TIMEOUT))
    status = decoder.uplink_status
    assert status is not None and status.sent_us == sent
    assert (status.exit_at_us, status.timed_out_at_us) == (exit_at, exit_at - 1000)
    assert status.authority is Authority.PROVING and status.exit is AuthorityExit.TIMEOUT
    decoder.feed(authority_status(sent + 100, 0, AuthorityExit.NONE))
    assert decoder.uplink_status is not None and decoder.uplink_status.exit_at_us is None
