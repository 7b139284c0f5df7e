"""A stand-in FC on a TCP port: FSP from the encoder, in real time, with faults on purpose.

Not a flight controller (the SITL is that): a capture player with a clock, for faults a real
FC will not make on request. Packet `i` is due at `i` packet periods after the start; what
is due while no client is connected (an outage) was sent to nobody and is lost, as on a
serial line that was unplugged. `wire(i, n)` makes the bytes of packet `i`, the `n`th of its
connection (None: lost in transport); `sent` lists the E1 `seq` of every packet written.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Sequence

from tests.fsp.test_decoder import PERIOD, packet_at

PACKET_S = 2 * PERIOD * 1e-6
FRAME_RATE_HZ = 1e6 / PERIOD
OPEN_DELAY_S = 0.2
"""pyserial flushes its input when it opens a socket://: talk once it is up."""


def intact(index: int, _nth: int = 0) -> bytes | None:
    return packet_at(index, 1_000_000 + 2 * index * PERIOD)


class FakeFc:
    """Streams to one client at a time. `connected_s` lists how long each connection lasts
    before the FC hangs up and `outages_s` how long the port is then gone (connections are
    refused); the last connection lasts until `stop()`."""

    def __init__(
        self,
        wire: Callable[[int, int], bytes | None] = intact,
        connected_s: Sequence[float] = (),
        outages_s: Sequence[float] = (),
    ) -> None:
        self.wire = wire
        self.phases = list(zip(connected_s, outages_s, strict=True))
        self.sent: list[int] = []
        self.connections = 0
        self._stop = threading.Event()
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = self._listener.getsockname()[1]
        self.url = f"socket://127.0.0.1:{self.port}"
        self._thread = threading.Thread(target=self._serve, daemon=True)

    def __enter__(self) -> FakeFc:
        self._start = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10)
        self._listener.close()

    def _due(self) -> int:
        """Packets due so far: the FC's own clock."""
        return int((time.monotonic() - self._start) / PACKET_S)

    def _serve(self) -> None:
        phases = iter(self.phases)
        next_index = 0
        while not self._stop.is_set():
            self._listener.settimeout(0.05)
            try:
                connection, _ = self._listener.accept()
            except TimeoutError:
                continue
            self.connections += 1
            phase = next(phases, None)
            with connection:
                time.sleep(OPEN_DELAY_S)
                next_index = first = self._due()  # what came before was sent to nobody
                hang_up = time.monotonic() + phase[0] if phase else float("inf")
                while not self._stop.is_set() and time.monotonic() < hang_up:
                    due = self._due()
                    for index in range(next_index, due):
                        data = self.wire(index, index - first)
                        if data is not None:
                            try:
                                connection.sendall(data)
                            except OSError:
                                break
                            self.sent.append(index)
                    next_index = due
                    time.sleep(0.005)
            if phase is not None:  # the port is gone: connections are refused
                self._listener.close()
                self._stop.wait(phase[1])
                self._listener = socket.create_server(("127.0.0.1", self.port))
