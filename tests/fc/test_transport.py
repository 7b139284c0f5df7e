"""Opening links: failures become one-line PortErrors."""

from __future__ import annotations

import socket

import pytest

from wftool.errors import PortError
from wftool.fc.transport import open_port, port_errors


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
