"""MAVLink messages relayed through the 180-byte tunnel variant (spec §3).

The tunnel field carries raw MAVLink bytes, zero-padded to 64. The padding is harmless to a
MAVLink parser, which resynchronises on the start-of-frame byte, so the fields of
consecutive packets are simply concatenated. Parsing needs `pymavlink`
(`pip install wftool[mavlink]`); the raw bytes are always on `StatePacket.mavlink`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

from wftool.extras import require
from wftool.fsp.packets import StatePacket


class MavlinkTunnel:
    """Reassembles MAVLink messages from consecutive tunnel packets."""

    def __init__(self, dialect: str = "common") -> None:
        require("mavlink", what="parsing tunnelled MAVLink")
        from pymavlink import mavutil

        mavutil.set_dialect(dialect)
        self._parser = mavutil.mavlink.MAVLink(None)
        self._parser.robust_parsing = True  # padding and junk become BAD_DATA, not exceptions

    def feed(self, tunnel_bytes: bytes) -> list[Any]:
        """Messages completed by `tunnel_bytes` (one packet's 64-byte field, or any slice)."""
        messages = self._parser.parse_buffer(tunnel_bytes) or []
        return [m for m in messages if m.get_type() != "BAD_DATA"]

    def messages(self, packets: Iterable[StatePacket]) -> Iterator[Any]:
        """Messages carried by the tunnel fields of `packets`, in order."""
        for packet in packets:
            if packet.mavlink is not None:
                yield from self.feed(packet.mavlink)
