"""Encoding FSP packets for the wire: the OBC's command uplink; state streams and time
replies for tests.

`CommandSender` is what an OBC program uses: it numbers commands (E1 `seq`) and stamps
them with the OBC clock, so the FC side and logs can tell loss and latency.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from wftool.fsp.framing import encode_frame
from wftool.fsp.packets import (
    CommandPacket,
    StatePacket,
    TimeReply,
    pack_command,
    pack_state,
    pack_time_reply,
)

U32_MASK = 0xFFFF_FFFF


def encode_state(packet: StatePacket) -> bytes:
    """Wire bytes of a state packet (COBS + delimiter)."""
    return encode_frame(pack_state(packet))


def encode_time_reply(reply: TimeReply) -> bytes:
    """Wire bytes of a time reply (COBS + delimiter): what an FC with E2 sends, for tests."""
    return encode_frame(pack_time_reply(reply))


def encode_command(packet: CommandPacket) -> bytes:
    """Wire bytes of a command packet (COBS + delimiter)."""
    return encode_frame(pack_command(packet))


class CommandSender:
    """Builds consecutive command packets: seq counts up, tx_time_us is the OBC clock."""

    def __init__(self, now: Callable[[], float] = time.monotonic) -> None:
        self._now = now
        self.seq = 0

    def encode(self, rc: Sequence[int]) -> bytes:
        """Wire bytes of the next command carrying `rc` (roll, pitch, yaw, throttle, aux3, aux4)."""
        packet = CommandPacket(
            rc=tuple(rc), seq=self.seq, tx_time_us=int(self._now() * 1e6) & U32_MASK
        )
        wire = encode_command(packet)
        self.seq += 1
        return wire
