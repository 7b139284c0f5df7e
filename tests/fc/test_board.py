"""Finding a real FC again after a reset (SerialBoard)."""

from __future__ import annotations

import socket
import time

import pytest

from tests.fc.stand_in import msp_stand_in
from wftool.errors import PortError
from wftool.fc.board import SerialBoard
from wftool.sitl.process import VirtualFC


def test_a_named_port_is_used_as_given() -> None:
    board = SerialBoard.find("/dev/ttyACM7")
    assert (board.url, board.rediscover) == ("/dev/ttyACM7", False)


def test_a_board_in_dfu_is_looked_up_when_it_comes_back() -> None:
    board = SerialBoard.find(None, present=False)
    assert (board.url, board.rediscover) == ("", True)


def test_wait_back_returns_once_msp_answers(virtual_fc: VirtualFC) -> None:
    started = time.monotonic()
    SerialBoard(virtual_fc.url).wait_back(timeout=5)
    assert time.monotonic() - started < 5


def test_wait_back_gives_up_with_a_port_error() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        url = f"socket://127.0.0.1:{probe.getsockname()[1]}"
    with pytest.raises(PortError, match="did not come back within 1 s"):
        SerialBoard(url).wait_back(timeout=1)


def test_a_long_msp_reply_over_socket_is_read_at_once() -> None:
    """A 60 KB reply to the probe: read a byte per read (pyserial's in_waiting of a
    socket:// port is 0 or 1) and parsed again after each, it took longer than the probe's
    0.5 s, and an FC that had saved was reported as not come back."""
    version = bytes([0, 1, 47])
    with msp_stand_in(lambda _command: version + bytes(60_000)) as url:
        SerialBoard(url).wait_back(timeout=3.0)
