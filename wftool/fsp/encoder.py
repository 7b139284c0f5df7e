"""Encoding FSP packets for the wire: the OBC's uplink (immediate and timed commands, arming
requests); state streams, time replies, uplink statuses and command reports for tests.

`CommandSender` is what an OBC program uses: one sender identity per instance, every packet
numbered (E1 `seq`) and stamped with the OBC clock, RC values within the FC's pulse range
(spec §5, §11, §14).
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable, Sequence
from numbers import Integral

from wftool.fsp.framing import encode_frame
from wftool.fsp.packets import (
    RC_CHANNELS,
    RC_PULSE_US,
    SENDER_MODULUS,
    SEQ_MODULUS,
    U32_MODULUS,
    ArmingAction,
    ArmingRequest,
    CommandPacket,
    CommandReport,
    RcValues,
    StatePacket,
    TimeReply,
    UplinkStatus,
    pack_arming_request,
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


def encode_arming_request(packet: ArmingRequest) -> bytes:
    """Wire bytes of an arming request (E5, COBS + delimiter)."""
    return encode_frame(pack_arming_request(packet))


def new_sender() -> int:
    """A random sender identity: 24 bits, not 0 (spec §11), from the OS's randomness."""
    return secrets.randbelow(SENDER_MODULUS - 1) + 1


class CommandSender:
    """An OBC's packets to the FC (spec §11): one sender identity, `seq` one more per
    packet (commands and arming requests share it), `tx_time_us` from the OBC's monotonic
    clock, RC values within the FC's pulse range.

    The identity is random per instance (`sender` sets it, for tests), so a restarted
    program is a new sender to the FC, and two programs are two. The pulse range is
    Betaflight's widest (`RC_PULSE_US`) until an uplink status reports the FC's own
    (`observe`; `FspPort` and `FspReader` show it every status they read). With
    `round_trips` (E2, spec §10) each packet is recorded there with its OBC send time, for
    the FC's time reply to be paired with.
    """

    def __init__(
        self,
        now: Callable[[], float] = time.monotonic,
        round_trips: RoundTripMatcher | None = None,
        *,
        sender: int | None = None,
    ) -> None:
        self._now = now
        self.round_trips = round_trips
        if sender is None:
            sender = new_sender()
        elif isinstance(sender, bool) or not isinstance(sender, Integral):
            raise TypeError(f"a sender identity is an int, not {type(sender).__name__}")
        elif not 0 < sender < SENDER_MODULUS:
            raise ValueError(f"a sender identity is 24 bits and not 0, not {sender}")
        self.sender: int = int(sender)
        """This sender's identity (24 bits, not 0)."""
        self.seq = 0
        """The next packet's sequence number (taken mod 2^24)."""
        self.fc_pulse_range: tuple[int, int] | None = None
        """The FC's pulse range from the newest uplink status shown (`observe`); None before
        one that reports it."""

    @property
    def pulse_range(self) -> tuple[int, int]:
        """The RC values a command may carry: the FC's range once known, else `RC_PULSE_US`."""
        return self.fc_pulse_range or RC_PULSE_US

    def observe(self, status: UplinkStatus) -> None:
        """Take the FC's pulse range from its newest uplink status (a 36-byte status of
        older firmware reports none: Betaflight's widest again)."""
        self.fc_pulse_range = status.pulse_range

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

        RC values other than six integers within `pulse_range`, or an `at_us` that is no
        u32, raise `TypeError` or `ValueError`, before anything is counted or recorded.
        """
        values = checked_rc(rc, self.fc_pulse_range)
        if at_us is not None and not (
            isinstance(at_us, Integral) and not isinstance(at_us, bool) and 0 <= at_us <= U32_MASK
        ):
            raise ValueError(f"a timed command's FC time is a u32 (µs), not {at_us!r}")
        seq, tx_time_us = self._stamp(now)
        return CommandPacket(
            values, seq, tx_time_us, None if at_us is None else int(at_us), self.sender
        )

    def arming_request(self, action: ArmingAction, now: float | None = None) -> ArmingRequest:
        """The next packet: an arming request (E5, spec §14) to arm or disarm, recorded as
        sent. The FC takes it only with a command of this sender in effect (send commands
        first) and only with the OBC alone; `ValueError` for anything but ARM or DISARM."""
        if action not in (ArmingAction.ARM, ArmingAction.DISARM):
            raise ValueError(f"an arming request arms or disarms, not {action!r}")
        seq, tx_time_us = self._stamp(now)
        return ArmingRequest(ArmingAction(action), seq, tx_time_us, self.sender)

    def _stamp(self, now: float | None) -> tuple[int, int]:
        """The next packet's `seq` and `tx_time_us`, counted and recorded as sent."""
        sent_at = self._now() if now is None else now
        seq, tx_time_us = self.seq % SEQ_MODULUS, int(sent_at * 1e6) & U32_MASK
        if self.round_trips is not None:
            self.round_trips.sent(seq, tx_time_us, sent_at)
        self.seq += 1
        return seq, tx_time_us


def checked_rc(rc: Sequence[int], pulse_range: tuple[int, int] | None = None) -> RcValues:
    """`rc` as six ints within `pulse_range` (the FC's, `rx_min_usec`..`rx_max_usec`; None:
    Betaflight's widest, `RC_PULSE_US`), or `TypeError`/`ValueError` saying why not."""
    if isinstance(rc, (str, bytes, bytearray, memoryview)):
        raise TypeError(
            f"RC values are a sequence of {len(RC_CHANNELS)} ints, not {type(rc).__name__}"
        )
    values = rc_values(tuple(rc))
    low, high = RC_PULSE_US if pulse_range is None else pulse_range
    whose = "Betaflight's" if pulse_range is None else "the FC's"
    source = "" if pulse_range is None else " (its rx_min_usec, rx_max_usec)"
    for name, value in zip(RC_CHANNELS, values):
        if isinstance(value, bool) or not isinstance(value, Integral):
            raise TypeError(f"RC {name} must be an int (µs), not {type(value).__name__} {value!r}")
        if not low <= value <= high:
            raise ValueError(
                f"RC {name} {value} µs is outside {whose} pulse range {low}..{high} µs{source}"
            )
    return tuple(int(value) for value in values)  # type: ignore[return-value]
