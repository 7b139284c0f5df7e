"""Encoding FSP packets for the wire: the OBC's command uplink (immediate and timed); state
streams, time replies, uplink statuses and command reports for tests.

`CommandSender` is what an OBC program uses: it numbers commands (E1 `seq`) and stamps
them with the OBC clock, so the FC side and logs can tell loss and latency.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from numbers import Integral

from wftool.fsp.framing import encode_frame
from wftool.fsp.packets import (
    RC_CHANNELS,
    RC_PULSE_US,
    SEQ_MODULUS,
    U32_MODULUS,
    CommandPacket,
    CommandReport,
    RcValues,
    StatePacket,
    TimeReply,
    UplinkStatus,
    pack_command,
    pack_command_report,
    pack_state,
    pack_time_reply,
    pack_uplink_status,
    rc_values,
)
from wftool.fsp.twoway import RoundTripMatcher

U32_MASK = U32_MODULUS - 1


def encode_state(packet: StatePacket) -> bytes:
    """Wire bytes of a state packet (COBS + delimiter)."""
    return encode_frame(pack_state(packet))


def encode_time_reply(reply: TimeReply) -> bytes:
    """Wire bytes of a time reply (COBS + delimiter): what an FC with E2 sends, for tests."""
    return encode_frame(pack_time_reply(reply))


def encode_uplink_status(status: UplinkStatus) -> bytes:
    """Wire bytes of an uplink status (COBS + delimiter): what an FC with E3 sends, for tests."""
    return encode_frame(pack_uplink_status(status))


def encode_command_report(report: CommandReport) -> bytes:
    """Wire bytes of a command report (COBS + delimiter): what an FC with E4 sends, for tests."""
    return encode_frame(pack_command_report(report))


def encode_command(packet: CommandPacket) -> bytes:
    """Wire bytes of a command packet (COBS + delimiter)."""
    return encode_frame(pack_command(packet))


class CommandSender:
    """Builds consecutive command packets: seq counts up, tx_time_us is the OBC clock.

    With `round_trips` (E2, spec §10) each command is recorded there with its OBC send time,
    for the FC's time reply to be paired with.
    """

    def __init__(
        self, now: Callable[[], float] = time.monotonic, round_trips: RoundTripMatcher | None = None
    ) -> None:
        self._now = now
        self.round_trips = round_trips
        self.seq = 0

    def encode(
        self, rc: Sequence[int], now: float | None = None, *, at_us: int | None = None
    ) -> bytes:
        """Wire bytes of the next command carrying `rc` (roll, pitch, yaw, throttle, aux3,
        aux4), stamped with OBC time `now` (default: the clock's now); with `at_us` a timed
        command (E4, spec §13) for that FC time (`micros()`, u32)."""
        return encode_command(self.next(rc, now, at_us=at_us))

    def next(
        self, rc: Sequence[int], now: float | None = None, *, at_us: int | None = None
    ) -> CommandPacket:
        """The next command packet (see `encode`), recorded as sent.

        RC values other than six integers within `RC_PULSE_US`, or an `at_us` that is no
        u32, raise `TypeError` or `ValueError`, before anything is counted or recorded.
        """
        values = checked_rc(rc)
        if at_us is not None and not (
            isinstance(at_us, Integral) and not isinstance(at_us, bool) and 0 <= at_us <= U32_MASK
        ):
            raise ValueError(f"a timed command's FC time is a u32 (µs), not {at_us!r}")
        sent_at = self._now() if now is None else now
        packet = CommandPacket(
            rc=values,
            seq=self.seq % SEQ_MODULUS,
            tx_time_us=int(sent_at * 1e6) & U32_MASK,
            at_us=None if at_us is None else int(at_us),
        )
        if self.round_trips is not None:
            self.round_trips.sent(packet.seq, packet.tx_time_us, sent_at)
        self.seq += 1
        return packet


def checked_rc(rc: Sequence[int]) -> RcValues:
    """`rc` as six ints within `RC_PULSE_US`, or `TypeError`/`ValueError` saying why not."""
    if isinstance(rc, (str, bytes, bytearray, memoryview)):
        raise TypeError(
            f"RC values are a sequence of {len(RC_CHANNELS)} ints, not {type(rc).__name__}"
        )
    values = rc_values(tuple(rc))
    low, high = RC_PULSE_US
    for name, value in zip(RC_CHANNELS, values):
        if isinstance(value, bool) or not isinstance(value, Integral):
            raise TypeError(f"RC {name} must be an int (µs), not {type(value).__name__} {value!r}")
        if not low <= value <= high:
            raise ValueError(
                f"RC {name} {value} µs is outside Betaflight's pulse range {low}..{high} µs"
            )
    return tuple(int(value) for value in values)  # type: ignore[return-value]
