"""E2 time replies from the real firmware (the patched SITL): off by default, and once
`fsp_time_reply` is ON, every command answered at most once with times that pair up."""

from __future__ import annotations

import time
from pathlib import Path

from wftool.fsp import CommandSender, FspReader, StateDecoder
from wftool.fsp.encoder import encode_command
from wftool.fsp.twoway import RoundTrip
from wftool.sitl.session import VirtualFcSession

COMMAND = (1500, 1500, 1500, 1000, 1000, 1000)


def exchange(
    session: VirtualFcSession, commands: int, period_s: float = 0.02, *, answered: bool = False
) -> StateDecoder:
    """Send `commands` commands, one per `period_s` (more than an FSP task period), once the
    stream runs; an E2 decoder pairs whatever comes back. `answered`: each fresh command
    (all but the first) goes out only once the previous one's reply is in, or 1 s has passed:
    the FC answers the newest command of an FSP task run (spec §10), and a loaded host would
    otherwise now and then deliver two in one."""
    decoder = StateDecoder(time_replies=True)
    with FspReader(session.fsp_url, decoder=decoder) as reader:
        while not decoder.stats.packets:
            reader.read(0.05)
        for k in range(commands):
            replies = decoder.stats.time_replies
            reader.send_command(COMMAND)
            due = time.monotonic() + period_s
            awaits = answered and k > 0
            while (now := time.monotonic()) < due or (
                awaits and decoder.stats.time_replies == replies and now < due + 1.0
            ):
                reader.read(max(due - now, 0.001))
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
    """The first command of a sequence only sets the FC's reference (spec §11): the other 99
    are fresh, and each is answered once."""
    session = VirtualFcSession(sitl_binary, tmp_path, port_base=None, time_reply=True)
    with session:
        decoder = exchange(session, 100, answered=True)
    matcher = decoder.round_trips
    assert matcher is not None
    assert_clean(decoder)
    assert decoder.stats.lost_frames == 0
    assert matcher.matched == decoder.stats.time_replies == 99
    assert not any(matcher.rejected.values())
    status = decoder.uplink_status
    assert status is not None and (status.accepted, status.stale) == (99, 1)


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
