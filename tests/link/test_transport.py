"""Opening links: failures become one-line PortErrors."""

from __future__ import annotations

import re
import socket

import pytest

from wftool.errors import PortError, UsageError
from wftool.fsp.reader import FspPort
from wftool.link.transport import open_port, port_errors


def test_missing_device_is_a_port_error() -> None:
    with pytest.raises(PortError, match=r"^cannot open /dev/wftool-no-such-tty: .+") as info:
        open_port("/dev/wftool-no-such-tty")
    assert "\n" not in str(info.value)


def test_refused_socket_url_is_a_port_error() -> None:
    with socket.socket() as probe:  # find a free port, then leave it closed
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(PortError, match=f"cannot open socket://127.0.0.1:{port}"):
        open_port(f"socket://127.0.0.1:{port}")


def test_bad_url_scheme_is_a_port_error() -> None:
    with pytest.raises(PortError, match="cannot open nosuchscheme://x"):
        open_port("nosuchscheme://x")


def test_a_peer_that_goes_away_is_a_port_error() -> None:
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        link = open_port(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.2)
        peer, _ = server.accept()
        peer.close()
        with pytest.raises(PortError, match="lost connection"), port_errors(link.port):
            link.read(1)
        link.close()


@pytest.mark.parametrize(
    ("url", "problem"),
    [
        ("socket://127.0.0.1:abc", "the port must be a number from 1 to 65535"),
        ("socket://127.0.0.1:99999", "the port must be a number from 1 to 65535"),
        ("socket://127.0.0.1", "the port must be a number from 1 to 65535"),
        ("rfc2217://", "no host in it; expected rfc2217://HOST:PORT"),
        ("socket://:5761", "no host in it; expected socket://HOST:PORT"),
    ],
)
def test_a_malformed_network_url_says_what_is_wrong(url: str, problem: str) -> None:
    with pytest.raises(UsageError, match=f"^cannot open {re.escape(url)}: {problem}"):
        open_port(url)


@pytest.mark.parametrize("baudrate", [0, -9600])
def test_a_baud_rate_that_is_not_positive_is_refused(baudrate: int) -> None:
    with socket.socket() as server:  # a peer that would accept: only the baud rate is wrong
        server.bind(("127.0.0.1", 0))
        server.listen()
        url = f"socket://127.0.0.1:{server.getsockname()[1]}"
        with pytest.raises(UsageError, match=f"the baud rate must be positive, not {baudrate}"):
            open_port(url, baudrate=baudrate)
        with pytest.raises(UsageError, match="baud rate must be positive"):
            FspPort(url, baudrate).open()
