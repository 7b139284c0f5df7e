"""The gate's own rules, alone: a viewer's frames against the message limit, and binding.

What the gate does for the live view (viewers dropped, memory bounded) is tested through
the real Foxglove server in test_foxglove.py.
"""

from __future__ import annotations

import socket
import struct

import pytest

from wftool.errors import UsageError
from wftool.verify.viewer_gate import ViewerGate, _Frames


def frame(opcode: int, size: int, *, fin: bool = True) -> bytes:
    """A masked client frame (key 0) of `size` payload bytes."""
    if size < 126:
        length = bytes([0x80 | size])
    elif size < 1 << 16:
        length = bytes([0x80 | 126]) + struct.pack(">H", size)
    else:
        length = bytes([0x80 | 127]) + struct.pack(">Q", size)
    return bytes([(0x80 if fin else 0) | opcode]) + length + bytes(4) + b"x" * size


def test_messages_up_to_the_limit_pass_in_any_pieces():
    frames = _Frames(limit=1000)
    wire = frame(1, 1000) + frame(2, 200, fin=False) + frame(9, 5) + frame(0, 800) + frame(1, 0)
    assert all(frames.passes(wire[i : i + 7]) for i in range(0, len(wire), 7))
    assert frames.message == 0 and frames.remaining == 0


@pytest.mark.parametrize(
    "wire",
    [
        frame(1, 1001),
        frame(2, 600, fin=False) + frame(0, 401),  # fragments together
        frame(1, 10, fin=False) + frame(0, 500, fin=False) + frame(0, 491),
        frame(9, 126),  # a ping longer than a control frame may be
    ],
    ids=["one-frame", "two-fragments", "three-fragments", "long-control-frame"],
)
def test_a_message_over_the_limit_is_refused_at_its_header(wire):
    frames = _Frames(limit=1000)
    assert not all(frames.passes(wire[i : i + 16]) for i in range(0, len(wire), 16))


def test_a_port_in_use_is_a_one_line_usage_error():
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        with pytest.raises(UsageError, match=rf"cannot serve Foxglove on 127.0.0.1:{port}: "):
            ViewerGate("127.0.0.1", port, upstream_port=1)
