"""Reading FSP from a port: the API an OBC program uses. `FspPort` is the port (bytes in,
packets out); `FspReader` is one with its `StateDecoder`. Any pyserial URL works.

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
from wftool.fsp.decoder import StateDecoder, UplinkStatusWatch
from wftool.fsp.encoder import CommandSender, encode_arming_request, encode_command
from wftool.fsp.packets import (
    ArmingAction,
    ArmingRequest,
    CommandPacket,
    CommandReport,
    SensorFrame,
    StatePacket,
    UplinkStatus,
)
from wftool.fsp.timed import fc_time_us
from wftool.link.transport import Port, open_port, port_errors, read_within, selectable_fd

DEFAULT_BAUDRATE = 2_000_000
"""The FSP baud rate wftool assumes unless told otherwise (`verify`, the virtual FC)."""
_Port = TypeVar("_Port", bound="FspPort")


class FspPort:
    """An FSP port: the bytes that arrive, and the uplink (commands, arming requests) of one
    sender (`sender`, a `CommandSender`: a new identity per port unless one is given, e.g.
    to keep one across reconnects). No decoding, but the FC's uplink statuses are watched
    for its pulse range, which every command is checked against (spec §5)."""

    def __init__(
        self,
        url: str,
        baudrate: int = DEFAULT_BAUDRATE,
        *,
        now: Callable[[], float] = time.monotonic,
        sender: CommandSender | None = None,
    ) -> None:
        self.url = url
        self.baudrate = baudrate
        self._now = now
        self.sender = sender if sender is not None else CommandSender(now)
        """Who this port's packets come from, and their sequence (spec §11)."""
        self._watch = UplinkStatusWatch()
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
        """What arrived within `timeout` seconds (returns as soon as anything did). The FC's
        newest uplink status among them sets the sender's pulse range."""
        port = self.port
        with port_errors(self.url):
            data = read_within(port, self._fd, timeout)
        if data and (status := self._watch.feed(data)) is not None:
            self.sender.observe(status)
        return data

    @property
    def uplink_status(self) -> UplinkStatus | None:
        """The FC's newest uplink status read on this port (E3, spec §12); None before one."""
        return self._watch.status

    def send_command(
        self,
        rc: Sequence[int],
        now: float | None = None,
        *,
        at: float | None = None,
        decoder: StateDecoder | None = None,
    ) -> CommandPacket:
        """Send RC values (roll, pitch, yaw, throttle, aux3, aux4) to the FC, stamped with OBC
        time `now` (default: the clock's now); the packet sent. Values outside the FC's pulse
        range (`sender.pulse_range`) are a `ValueError`, nothing sent: the FC would refuse
        the command whole.

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
        packet = self.sender.next(rc, now, at_us=at_us)
        with port_errors(self.url):
            self.port.write(encode_command(packet))
        return packet

    def send_arming(self, action: ArmingAction, now: float | None = None) -> ArmingRequest:
        """Ask the FC to arm or disarm (E5, spec §14); the packet sent. The FC takes it only
        while a command of this sender is in effect, and only with the OBC alone (the FC
        holds the ARM switch on AUX1 for it); `UplinkFlag.ARM_SWITCH` and `ARMED` in the
        uplink status say what came of it."""
        packet = self.sender.arming_request(action, now)
        with port_errors(self.url):
            self.port.write(encode_arming_request(packet))
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
        sender: CommandSender | None = None,
    ) -> None:
        super().__init__(url, baudrate, now=now, sender=sender)
        self.decoder = decoder if decoder is not None else StateDecoder()
        self.sender.round_trips = self.decoder.round_trips  # E2: replies answer these

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

    @property
    def uplink_status(self) -> UplinkStatus | None:
        """The FC's newest uplink status (E3, spec §12), as the decoder took it (its FC
        times placed in the stream's)."""
        return self.decoder.uplink_status

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
