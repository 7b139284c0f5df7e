"""E2 time replies from the real firmware (the patched SITL): off by default, and once
`fsp_time_reply` is ON, every command answered at most once with times that pair up."""

from __future__ import annotations

import time
from pathlib import Path

from tests.sitl.fresh import send_fresh
from wftool.fsp import CommandSender, FspReader, StateDecoder
from wftool.fsp.encoder import encode_command
from wftool.fsp.twoway import RoundTrip
from wftool.sitl.session import VirtualFcSession

COMMAND = (1500, 1500, 1500, 1000, 1000, 1000)
MEASURED = 100


def exchange(session: VirtualFcSession, commands: int, period_s: float = 0.02) -> StateDecoder:
    """Send `commands` commands, one per `period_s` (more than an FSP task period), once the
    stream runs; an E2 decoder pairs whatever comes back."""
    decoder = StateDecoder(time_replies=True)
    with FspReader(session.fsp_url, decoder=decoder) as reader:
        while not decoder.stats.packets:
            reader.read(0.05)
        for _ in range(commands):
            reader.send_command(COMMAND)
            due = time.monotonic() + period_s
            while (left := due - time.monotonic()) > 0:
                reader.read(left)
        until = time.monotonic() + 0.5  # the last replies
        while (left := until - time.monotonic()) > 0:
            reader.read(left)
    return decoder


def assert_clean(decoder: StateDecoder) -> None:
    """Nothing rejected but the one chunk a connection may cut by joining the stream
    mid-packet (the SITL streams whether or not a client is connected, as a UART does)."""
    joined = sum(decoder.joined.values())
    assert joined <= 1 and decoder.stats.errors == joined


def test_time_reply_is_off_by_default(sitl_binary: Path, tmp_path: Path) -> None:
    with VirtualFcSession(sitl_binary, tmp_path, port_base=None) as session:
        decoder = exchange(session, 50)
    assert decoder.stats.packets > 400
    assert decoder.stats.time_replies == 0
    assert_clean(decoder)


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
    session = VirtualFcSession(sitl_binary, tmp_path, port_base=None, time_reply=True)
    trips: list[RoundTrip] = []
    with session, FspReader(session.fsp_url, decoder=StateDecoder("twoway")) as reader:
        matcher = reader.decoder.round_trips
        assert matcher is not None
        matcher.on_round_trip = trips.append
        while not reader.decoder.stats.packets:
            reader.read(0.05)
        sender = CommandSender(round_trips=matcher)
        now = time.monotonic()
        first, second = sender.next(COMMAND, now), sender.next(COMMAND, now + 1e-6)
        reader.port.write(encode_command(first) + encode_command(second))  # one write
        until = time.monotonic() + 0.3
        while (left := until - time.monotonic()) > 0:
            reader.read(left)
    assert [trip.obc_sent for trip in trips] == [now + 1e-6]
    assert reader.decoder.stats.time_replies == 1
