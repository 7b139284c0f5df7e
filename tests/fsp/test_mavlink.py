"""MAVLink messages out of the tunnel variant (needs the optional pymavlink)."""

from __future__ import annotations

from pathlib import Path

import pytest

from wftool.fsp import StateDecoder

pytest.importorskip("pymavlink", reason="pymavlink (extra 'mavlink') not installed")

from wftool.fsp.mavlink import MavlinkTunnel


def test_heartbeats_come_out_of_the_tunnel_vector(vectors_dir: Path):
    packets = StateDecoder().feed((vectors_dir / "state_mavlink.bin").read_bytes())
    assert all(p.tunnel for p in packets)
    messages = list(MavlinkTunnel().messages(packets))
    assert [m.get_type() for m in messages] == ["HEARTBEAT"] * 3
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in messages} == {(1, 1)}


def test_a_message_split_across_packets_reassembles(vectors_dir: Path):
    (first, *_) = StateDecoder().feed((vectors_dir / "state_mavlink.bin").read_bytes())
    heartbeat = first.mavlink.rstrip(b"\x00")
    tunnel = MavlinkTunnel()
    assert tunnel.feed(heartbeat[:7]) == []
    (message,) = tunnel.feed(heartbeat[7:] + bytes(64))
    assert message.get_type() == "HEARTBEAT"
