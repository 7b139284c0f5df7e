"""Timed commands on the OBC: an OBC instant mapped to FC time, refused while the clock is
not locked; the FC's report counts taken over a run."""

from __future__ import annotations

import pytest

from tests.fsp.test_decoder import PERIOD, packet_at
from wftool.errors import ClockError
from wftool.fsp import CommandOutcome, CommandReport, ReportBook, StateDecoder, fc_time_us
from wftool.fsp.twoway import TwoWayClockEstimator

RATE = 1 + 80e-6
"""The OBC clock runs 80 ppm fast against the FC's."""
DELAY_S = 0.0007


def obc_of(fc_us: int, first_us: int) -> float:
    """The OBC time a packet sent at FC time `fc_us` arrives at: on the envelope."""
    return 100.0 + (fc_us - first_us) * 1e-6 * RATE + DELAY_S


def locked_decoder(first_us: int = 1_000_000, seconds: float = 8.0, clock: str = "envelope"):
    """A decoder fed `seconds` of a steady stream whose every packet arrived on the line."""
    decoder = StateDecoder(clock)
    count = int(seconds * 1e6 / (2 * PERIOD))
    for seq in range(count):
        t_us = first_us + seq * 2 * PERIOD
        tx_us = t_us + PERIOD + 100
        decoder.feed(packet_at(seq, t_us), obc_of(tx_us, first_us + PERIOD + 100))
    return decoder


def test_an_obc_instant_maps_to_the_fc_time_then():
    decoder = locked_decoder()
    assert decoder.clock_state.locked
    first_tx = 1_000_000 + PERIOD + 100
    for fc_us in (9_000_000, 9_000_001, 9_012_345, 9_500_000):
        # the one-way line: an OBC time is the FC instant's plus d_min (spec §8)
        assert abs(fc_time_us(decoder, obc_of(fc_us, first_tx)) - fc_us) <= 1


def test_the_fc_clock_wraps_in_the_u32():
    first = 2**32 - 4_000_000
    decoder = locked_decoder(first)
    first_tx = first + PERIOD + 100
    target = first + 8_000_000  # 4 s past the wrap
    assert abs(fc_time_us(decoder, obc_of(target, first_tx)) - target % 2**32) <= 1


def test_refused_until_the_clock_is_locked():
    decoder = StateDecoder()
    with pytest.raises(ClockError, match="not locked"):
        fc_time_us(decoder, 100.0)  # no packet yet
    decoder.feed(packet_at(0, 1_000_000), 100.0)
    decoder.feed(packet_at(1, 1_000_000 + 2 * PERIOD), 100.002)
    assert not decoder.clock_state.locked
    with pytest.raises(ClockError, match="not locked"):
        fc_time_us(decoder, 100.01)


def test_an_instant_the_u32_cannot_place_is_refused():
    decoder = locked_decoder()
    last = decoder.last_packet
    assert last is not None and last.arrival_time is not None
    fc_time_us(decoder, last.arrival_time + 2000.0)  # half an hour ahead: fine
    for far in (last.arrival_time + 2200.0, last.arrival_time - 2200.0, float("nan")):
        with pytest.raises(ClockError, match="2\\^31"):
            fc_time_us(decoder, far)


def test_a_two_way_clock_maps_without_the_transport_delay():
    decoder = locked_decoder(clock="twoway")
    clock = decoder.clock
    assert isinstance(clock, TwoWayClockEstimator)
    first_tx = 1_000_000 + PERIOD + 100
    one_way = fc_time_us(decoder, obc_of(9_000_000, first_tx))
    # round trips that put d_min at DELAY_S: a command DELAY_S on the way each way
    for k in range(8):
        fc_rx = 8_000_000 + 10_000 * k
        clock.observe_round_trip(
            obc_of(fc_rx, first_tx) - 2 * DELAY_S, fc_rx, fc_rx + 50, obc_of(fc_rx + 50, first_tx)
        )
    assert clock.two_way.active
    two_way = fc_time_us(decoder, obc_of(9_000_000, first_tx))
    # the same OBC instant is d_min later on the FC clock once d_min is known
    assert abs((two_way - one_way) - DELAY_S * 1e6 / RATE) <= 2


def report(outcome: CommandOutcome, counts: tuple[int, ...], seq: int = 0) -> CommandReport:
    return CommandReport(seq, 0, 1000, 1060, outcome, 0, counts)  # type: ignore[arg-type]


def test_the_books_count_what_the_fc_counted_even_across_lost_reports():
    book = ReportBook()
    book.add(report(CommandOutcome.ON_TIME, (41, 2, 0, 0, 0, 0)))  # counts since the FC booted
    assert book.counts[CommandOutcome.ON_TIME] == 1 and book.commands == 1
    book.add(report(CommandOutcome.ON_TIME, (42, 2, 0, 0, 0, 0)))
    # two reports lost: a late one and a refused one
    book.add(report(CommandOutcome.ON_TIME, (43, 3, 1, 0, 0, 0)))
    assert book.reports == 3 and book.commands == 5 and book.lost == 2
    assert (book.applied, book.refused, book.counts[CommandOutcome.SUPERSEDED]) == (4, 1, 0)
    assert book.counts[CommandOutcome.LATE] == 1


def test_the_counts_wrap_at_2_16():
    book = ReportBook()
    book.add(report(CommandOutcome.SUPERSEDED, (0, 0, 0, 0, 65535, 0)))
    book.add(report(CommandOutcome.SUPERSEDED, (0, 0, 0, 0, 1, 0)))
    assert book.counts[CommandOutcome.SUPERSEDED] == 3 and book.lost == 1
