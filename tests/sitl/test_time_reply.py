"""E2 time replies from the real firmware (the patched SITL): off by default, and once
`fsp_time_reply` is ON, every command answered at most once with times that pair up."""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

from tests.sitl.fresh import read_reports, read_until, reported, send_fresh
from wftool.fsp import FspReader, StateDecoder
from wftool.fsp.encoder import encode_command
from wftool.fsp.twoway import RoundTrip
from wftool.sitl.session import VirtualFcSession

COMMAND = (1500, 1500, 1500, 1000, 1000, 1000)
MEASURED = 100
OFF_MEASURED = 50
APART_S = 1e-5
"""The second command of a pair is stamped this much later: 10 µs, a `tx_time_us` ahead
whatever the rounding."""
PAIRS_MAX = 20
"""Pairs sent until the FC takes one both fresh: the first only starts a link, and each one a
loaded host delays past the timeout starts another."""


def assert_clean(decoder: StateDecoder) -> None:
    """Nothing rejected but the one chunk a connection may cut by joining the stream
    mid-packet (the SITL streams whether or not a client is connected, as a UART does)."""
    joined = sum(decoder.joined.values())
    assert joined <= 1 and decoder.stats.errors == joined


def test_time_reply_is_off_by_default(sitl_binary: Path, tmp_path: Path) -> None:
    """No reply to any of OFF_MEASURED commands the FC took fresh, by its own report (with
    `fsp_time_reply` ON it would answer each of them: the test below); an E2 decoder would
    pair any that came."""
    session = VirtualFcSession(sitl_binary, tmp_path, port_base=None)
    decoder = StateDecoder(time_replies=True)
    with session, FspReader(session.fsp_url, decoder=decoder) as reader:
        fates = send_fresh(reader, COMMAND, OFF_MEASURED)
    assert (fates.answered, fates.unanswered) == (0, OFF_MEASURED)
    assert decoder.stats.packets > 400
    assert decoder.stats.time_replies == 0
    assert_clean(decoder)
    status = decoder.uplink_status
    assert status is not None
    assert (status.accepted, status.stale) == (OFF_MEASURED, fates.sent - OFF_MEASURED)


def test_time_reply_answers_every_fresh_command_once(sitl_binary: Path, tmp_path: Path) -> None:
    """Every command the FC takes fresh, by its own report, is answered once (spec §10,
    §11). Measured on MEASURED of them, each sent alone (tests/sitl/fresh.py): the FC
    answers only the newest fresh command of an FSP task run, and one reaching it more than
    `fsp_cmd_timeout_ms` after the one before, by its clock, only starts a new link, so
    commands sent a host period apart are not all answered on a loaded host (a host stall of
    70 ms before every 10th of 100: 8 replies)."""
    session = VirtualFcSession(sitl_binary, tmp_path, port_base=None, time_reply=True)
    decoder = StateDecoder(time_replies=True)
    with session, FspReader(session.fsp_url, decoder=decoder) as reader:
        fates = send_fresh(reader, COMMAND, MEASURED)
    matcher = decoder.round_trips
    assert matcher is not None
    assert_clean(decoder)
    assert decoder.stats.lost_frames == 0
    assert (fates.answered, fates.unanswered) == (MEASURED, 0)
    assert matcher.matched == decoder.stats.time_replies == len(fates.trips) == MEASURED
    assert not any(matcher.rejected.values())
    status = decoder.uplink_status
    assert status is not None
    assert (status.accepted, status.stale) == (MEASURED, fates.sent - MEASURED)
    assert status.rejected == 0


def test_two_commands_in_one_task_run_get_one_reply_for_the_newest(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """Of two fresh commands the FC reads in one FSP task run it answers only the newest
    (spec §10). Each pair goes in one write, the next once the FC has reported the one
    before (E3): the first pair only starts a link (its first command is the candidate, never
    fresh, spec §11), and so does a pair a loaded host delays past the timeout, by the FC's
    clock; the FC's counts tell when it took both fresh. Every pair gets one reply, for its
    second command."""
    session = VirtualFcSession(sitl_binary, tmp_path, port_base=None, time_reply=True)
    trips: list[RoundTrip] = []
    with session, FspReader(session.fsp_url, decoder=StateDecoder("twoway")) as reader:
        matcher = reader.decoder.round_trips
        assert matcher is not None
        matcher.on_round_trip = trips.append
        read_until(reader, lambda: reader.decoder.stats.packets > 0, "state packet")
        newest: list[float] = []
        sent = accepted = took = 0
        while took < 2:
            assert len(newest) < PAIRS_MAX, f"the FC took no pair of {PAIRS_MAX} both fresh"
            now = time.monotonic()
            first = reader.sender.next(COMMAND, now)
            second = reader.sender.next(COMMAND, now + APART_S)
            reader.port.write(encode_command(first) + encode_command(second))  # one write
            newest.append(now + APART_S)
            sent += 2
            read_until(reader, partial(reported, reader, sent), "status counting the pair")
            status = reader.uplink_status
            assert status is not None
            took, accepted = status.accepted - accepted, status.accepted
        read_reports(reader, sent)
    assert [trip.obc_sent for trip in trips] == newest
    assert matcher.matched == reader.decoder.stats.time_replies == len(newest)
    assert not any(matcher.rejected.values())
