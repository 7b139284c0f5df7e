"""Reading FSP from a port: the API an OBC program uses. `FspPort` is the port (bytes in,
commands out); `FspReader` is one with its `StateDecoder`. Any pyserial URL works.

    with FspReader("/dev/ttyTHS1", baudrate=2_000_000) as fsp:   # or socket://127.0.0.1:5762
        for frame in fsp.frames():
            print(frame.obc_time, frame.acc_g, frame.euler_deg)
            fsp.send_command((1500, 1500, 1500, 1000, 1000, 1000))
            # or, once the clock is locked, to act 5 ms from now (E4, spec §13):
            fsp.send_command((1500, 1500, 1500, 1000, 1000, 1000), at=time.monotonic() + 0.005)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from types import TracebackType
from typing import TypeVar

from wftool.errors import PortError, UsageError
from wftool.fsp.decoder import StateDecoder
from wftool.fsp.encoder import CommandSender, encode_command
from wftool.fsp.packets import CommandPacket, CommandReport, SensorFrame, StatePacket
from wftool.fsp.timed import fc_time_us
from wftool.link.transport import Port, open_port, port_errors, read_within, selectable_fd

DEFAULT_BAUDRATE = 2_000_000
"""The FSP baud rate wftool assumes unless told otherwise (`verify`, the virtual FC)."""
_Port = TypeVar("_Port", bound="FspPort")


class FspPort:
    """An FSP port: the bytes that arrive, and the command uplink. No decoding."""

    def __init__(
        self,
        url: str,
        baudrate: int = DEFAULT_BAUDRATE,
        *,
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        self.url = url
        self.baudrate = baudrate
        self._now = now
        self._sender = CommandSender(now)
        self._port: Port | None = None
        self._fd: int | None = None

    def open(self: _Port) -> _Port:
        port = open_port(self.url, self.baudrate, timeout=0)  # reads never block: see read_bytes
        self._port = port
        self._fd = selectable_fd(port)  # None (rfc2217): poll with a read timeout
        return self

    def close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def __enter__(self: _Port) -> _Port:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    @property
    def port(self) -> Port:
        if self._port is None:
            raise PortError(f"{self.url} is not open")
        return self._port

    def read_bytes(self, timeout: float) -> bytes:
        """What arrived within `timeout` seconds (returns as soon as anything did)."""
        port = self.port
        with port_errors(self.url):
            return read_within(port, self._fd, timeout)

    def send_command(
        self,
        rc: Sequence[int],
        now: float | None = None,
        *,
        at: float | None = None,
        decoder: StateDecoder | None = None,
    ) -> CommandPacket:
        """Send RC values (roll, pitch, yaw, throttle, aux3, aux4) to the FC, stamped with OBC
        time `now` (default: the clock's now); the packet sent.

        With `at` (an OBC time, s) a timed command (E4, spec §13): the FC applies it at the
        first PID iteration at or after that instant, mapped to FC time through `decoder`'s
        clock (`timed.fc_time_us`; `ClockError` until it is locked, nothing sent). The FC
        reports what became of it (`StateDecoder.take_command_reports`).
        """
        at_us = None
        if at is not None:
            if decoder is None:
                raise UsageError("a timed command needs the stream's decoder to map its OBC time")
            at_us = fc_time_us(decoder, at)
        packet = self._sender.next(rc, now, at_us=at_us)
        with port_errors(self.url):
            self.port.write(encode_command(packet))
        return packet


class FspReader(FspPort):
    """Decoded state packets from a port (an `FspPort` feeding its `StateDecoder`)."""

    def __init__(
        self,
        url: str,
        baudrate: int = DEFAULT_BAUDRATE,
        *,
        decoder: StateDecoder | None = None,
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(url, baudrate, now=now)
        self.decoder = decoder if decoder is not None else StateDecoder()
        self._sender.round_trips = self.decoder.round_trips  # E2: replies answer these

    def send_command(
        self,
        rc: Sequence[int],
        now: float | None = None,
        *,
        at: float | None = None,
        decoder: StateDecoder | None = None,
    ) -> CommandPacket:
        """`FspPort.send_command`, a timed one mapped through this reader's decoder."""
        return super().send_command(rc, now, at=at, decoder=decoder or self.decoder)

    def command_reports(self) -> list[CommandReport]:
        """The FC's reports on timed commands (E4) decoded since the last call."""
        return self.decoder.take_command_reports()

    def read(self, timeout: float = 0.1) -> list[StatePacket]:
        """Packets completed by the bytes that arrive within `timeout` (maybe none)."""
        data = self.read_bytes(timeout)
        return self.decoder.feed(data, self._now()) if data else []

    def packets(self) -> Iterator[StatePacket]:
        """Decoded packets, forever (until the port fails)."""
        while True:
            yield from self.read()

    def frames(self) -> Iterator[SensorFrame]:
        """Decoded sensor frames in capture order, forever (until the port fails)."""
        for packet in self.packets():
            yield from packet.frames
