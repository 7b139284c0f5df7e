"""Opening links: failures become one-line PortErrors."""

from __future__ import annotations

import re
import select
import socket
import threading
import time

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


def test_a_write_that_went_out_whole_is_no_timeout_however_late_the_writer_ran(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """pyserial's socket write looked at the clock after each send: a thread that ran late (a
    loaded host) had its sent write reported as a timeout. A clock that jumps 2 s at each
    look (past the 1 s write timeout) stands in for that thread."""
    import itertools

    from serial.serialutil import Timeout

    ticks = itertools.count(0.0, 2.0)
    monkeypatch.setattr(Timeout, "TIME", lambda: next(ticks))
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        link = open_port(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.2)
        peer, _ = server.accept()
        with peer, port_errors("the link"):
            assert link.write(b"\x24M<\x00\x64\x64") == 6
            assert peer.recv(64) == b"\x24M<\x00\x64\x64"
        link.close()


def test_a_peer_that_reads_slowly_gets_every_byte_and_one_that_stops_times_the_write_out() -> None:
    payload = bytes(range(256)) * (1 << 14)  # 4 MiB: more than the socket buffers hold
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        link = open_port(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.2)
        peer, _ = server.accept()
        with peer:
            received = bytearray()

            def read_slowly() -> None:
                while len(received) < len(payload):
                    received.extend(peer.recv(1 << 16))
                    time.sleep(0.001)

            reader = threading.Thread(target=read_slowly)
            reader.start()
            assert link.write(payload) == len(payload)
            reader.join()
            assert bytes(received) == payload
            with pytest.raises(PortError, match="Write timeout"), port_errors("the link"):
                for _ in range(64):  # nobody reads now: the socket buffers (grown by the
                    link.write(payload)  # transfer above, up to several MiB) fill, then none
        link.close()


class _OneClientServer:
    """A server that holds one connection at a time and drops any other at once, as SITL's
    UARTs do; it lets go of a connection `release_s` after the client's end of stream."""

    def __init__(self, release_s: float) -> None:
        self.release_s = release_s
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self.listener.getsockname()[1]}"
        self.accepted = 0
        self.dropped = 0
        self._held: socket.socket | None = None
        self._stop = False
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop:
            watched = [self.listener] + ([self._held] if self._held else [])
            ready, _, _ = select.select(watched, [], [], 0.01)
            if self._held in ready and self._held is not None and not self._held.recv(64):
                time.sleep(self.release_s)
                self._held.close()
                self._held = None
            if self.listener in ready:
                connection, _ = self.listener.accept()
                if self._held is None:
                    self._held, self.accepted = connection, self.accepted + 1
                else:
                    connection.close()
                    self.dropped += 1

    def close(self) -> None:
        self._stop = True
        self._thread.join()
        self.listener.close()


def test_close_waits_for_a_one_client_peer_to_let_go_so_a_reconnect_is_held() -> None:
    server = _OneClientServer(release_s=0.05)
    try:
        for _ in range(5):
            link = open_port(server.url, timeout=0.2)
            started = time.monotonic()
            link.close()
            assert time.monotonic() - started >= 0.05  # it waited for the peer's close
        time.sleep(0.1)  # the server's loop has seen every connect
        assert (server.accepted, server.dropped) == (5, 0)
    finally:
        server.close()


def test_close_of_a_link_whose_peer_keeps_it_open_returns_after_the_release_timeout() -> None:
    from wftool.link.transport import RELEASE_TIMEOUT_S

    with socket.create_server(("127.0.0.1", 0)) as server:
        link = open_port(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.2)
        peer, _ = server.accept()
        with peer:
            peer.sendall(b"unread by the link")
            started = time.monotonic()
            link.close()
            waited = time.monotonic() - started
            assert RELEASE_TIMEOUT_S <= waited < RELEASE_TIMEOUT_S + 1.0
            assert peer.recv(64) == b""  # the link's end of stream reached the peer
        assert not link.is_open
        link.close()  # again: nothing to do
