"""Commands the FC takes fresh, by its own report: what the SITL tests of the uplink share.

The FC takes a command fresh only within `fsp_cmd_timeout_ms` of the one before, by its
clock (one arriving later only starts a new link), and answers (E2) only the newest fresh
command of an FSP task run (spec §10, §11). A loaded host delays the test's sends while FC
time goes on: commands a host period apart then reach the FC in bursts, and after timeouts.
`send_fresh` sends each command alone, once the FC has answered the one before or reported
(E3, §12) what it made of it, and tells each one's fate.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from tests.waits import wait_for
from wftool.fsp import FspReader
from wftool.fsp.encoder import encode_command
from wftool.fsp.packets import CommandPacket
from wftool.fsp.twoway import RoundTrip

NEVER_S = 5.0
"""The FC answers a command within a few ms and reports its counts every 100 ms."""
TAIL_US = 200_000
"""FC time read on after the last command, two uplink status periods: a late second reply to
a command would be in by then."""


def read_until(reader: FspReader, condition: Callable[[], bool], what: str) -> None:
    """Read the stream until `condition()` holds; NEVER_S only bounds "never"."""

    def read_then_check() -> bool:
        reader.read(0.01)
        return condition()

    assert wait_for(lambda: condition() or read_then_check(), NEVER_S, poll=0.0), (
        f"no {what} within {NEVER_S} s"
    )


def reported(reader: FspReader, sent: int, after_us: int | None = None) -> bool:
    """Whether the FC's newest uplink status (E3) counts `sent` commands, fresh or stale (the
    FC's counts since it booted: this reader's sender is its only one); with `after_us`,
    in a status it sent at or after that FC time."""
    status = reader.uplink_status
    return (
        status is not None
        and status.accepted + status.stale >= sent
        and (after_us is None or (status.sent_us is not None and status.sent_us >= after_us))
    )


def read_reports(reader: FspReader, sent: int) -> None:
    """Read on until an uplink status sent `TAIL_US` of FC time from now counts all `sent`
    commands: a late second reply to any of them is in by then."""
    newest = reader.decoder.last_packet
    assert newest is not None and newest.time_us is not None
    after_us = newest.time_us + TAIL_US
    read_until(reader, lambda: reported(reader, sent, after_us), "status counting every command")


def fate(
    reader: FspReader, trips: list[RoundTrip], packet: CommandPacket, obc_sent: float, sent: int
) -> tuple[bool, bool]:
    """What the FC made of `packet`, the last of the `sent` commands (sent at `obc_sent`):
    whether it took it fresh, and whether it answered it (a round trip). Known once its reply
    is in or its uplink status (E3) counts every command sent; a reply comes ahead of that
    status, so a fresh command without one is a reply lost."""

    def answered() -> bool:
        return bool(trips) and trips[-1].obc_sent == obc_sent

    read_until(
        reader, lambda: answered() or reported(reader, sent), f"fate of command {packet.seq}"
    )
    status = reader.uplink_status
    newest_fresh = status is not None and status.command_seq == packet.seq
    return answered() or newest_fresh, answered()


@dataclass
class Fates:
    """What became of the commands `send_fresh` sent."""

    sent: int = 0
    """Commands written, the openers of links among them."""
    answered: int = 0
    """Commands taken fresh and answered (a round trip)."""
    unanswered: int = 0
    """Commands taken fresh, by the FC's report, without a reply."""
    not_fresh: int = 0
    """Commands measured that the FC did not take fresh (they reached it after a timeout)."""
    trips: list[RoundTrip] = field(default_factory=list)
    """The round trips, in the order their replies came."""

    @property
    def fresh(self) -> int:
        return self.answered + self.unanswered


def send_fresh(reader: FspReader, rc: Sequence[int], count: int) -> Fates:
    """Send `rc` until the FC has taken `count` commands fresh, by its own report, each alone
    once the FC has answered or reported the one before. After one it did not take fresh, a
    pair in one write (no host stall comes between them): the first starts a new link, and
    is a repeat of the one not taken when there is one, so never fresh itself (spec §11: a
    repeat is stale; it is the candidate the second latches); the second is measured. Every
    fresh command is then one measured alone (the FC's `accepted` counts exactly these), and
    each reaches the FC in an FSP task run of its own.

    Ends once the FC has reported every command sent (`read_reports`)."""
    fates = Fates()
    matcher = reader.decoder.round_trips
    if matcher is not None:
        matcher.on_round_trip = fates.trips.append
    read_until(reader, lambda: reader.decoder.stats.packets > 0, "state packet")
    last: CommandPacket | None = None
    linked = False  # the first command of a link only starts it
    while fates.fresh < count:
        assert fates.not_fresh < count, f"the FC took {fates.fresh} of {fates.sent} fresh"
        obc_sent = time.monotonic()
        if linked:
            packet = reader.send_command(rc, obc_sent)
            fates.sent += 1
        else:
            opener = last if last is not None else reader.sender.next(rc, obc_sent - 1e-6)
            packet = reader.sender.next(rc, obc_sent)
            reader.port.write(encode_command(opener) + encode_command(packet))
            fates.sent += 2
        last = packet
        linked, replied = fate(reader, fates.trips, packet, obc_sent, fates.sent)
        fates.answered += replied
        fates.unanswered += linked and not replied
        fates.not_fresh += not linked
    read_reports(reader, fates.sent)
    return fates
