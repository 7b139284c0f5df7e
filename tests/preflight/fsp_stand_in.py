"""A STAND-IN for an FC's FSP port (not an FC: the SITL is that): a TCP server that streams
state packets every 2 ms (FC time in µs since it started), keeps every byte the OBC sends,
answers each command with a time reply (E2) and, when asked, writes uplink statuses (E3).
For what the OBC player writes and reads, without a firmware's rules in between."""

from __future__ import annotations

import socket
import threading
import time

from wftool.fsp.decoder import CommandDecoder
from wftool.fsp.encoder import encode_state, encode_time_reply, encode_uplink_status
from wftool.fsp.packets import CommandPacket, SensorFrame, StatePacket, TimeReply, UplinkStatus

PERIOD_US = 1000


def frame(t_us: int, rc: tuple[int, ...]) -> SensorFrame:
    return SensorFrame(
        sample_time_us=t_us % 2**32, acc=(0, 0, 0), acc_1g=0, gyro_scale=0.0, gyro=(0, 0, 0),
        attitude=(0, 0, 0, 0), rc=rc, rpm=(0,) * 4, vbat=0,
    )  # fmt: skip


class FspStandIn:
    """Serves one connection at a time until stopped; `received` holds every byte, `commands`
    every command decoded, `connections` counts the clients."""

    def __init__(self, *, answer_status: bool = False) -> None:
        """`answer_status`: every command is answered with an uplink status too (E3 of
        firmware before the authority: 36 bytes)."""
        self.answer_status = answer_status
        self.received = bytearray()
        self.commands: list[CommandPacket] = []
        self.connections = 0
        self.pending: list[bytes] = []
        """Bytes to write with the next state packet (statuses, say)."""
        self._decoder = CommandDecoder()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.1)
        self.url = f"socket://127.0.0.1:{self._listener.getsockname()[1]}"
        self._start = time.monotonic()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._connection: socket.socket | None = None
        self._pause_s = 0.0
        self._paused = threading.Event()

    def __enter__(self) -> FspStandIn:
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._listener.close()

    def hang_up(self) -> None:
        """Close the client's connection and stop serving (a port that vanished)."""
        self._stop.set()
        self._thread.join(5)

    def pause(self, seconds: float) -> None:
        """Read nothing for `seconds` once (a link or an FC that stalls), from before this
        returns."""
        self._paused.clear()
        with self._lock:
            self._pause_s = seconds
        self._paused.wait(5)

    def now_us(self) -> int:
        return int((time.monotonic() - self._start) * 1e6)

    def status(self, flags: int, timeouts: int = 0) -> None:
        """Queue an uplink status (E3, 36 bytes) for the next write."""
        t = self.now_us() % 2**32
        status = UplinkStatus(len(self.commands), t, len(self.commands), 0, timeouts, 0, 50,
                              flags, 0, 0)  # fmt: skip
        with self._lock:
            self.pending.append(encode_uplink_status(status))

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                connection, _ = self._listener.accept()
            except TimeoutError:
                continue
            self.connections += 1
            with connection:
                connection.settimeout(0.002)
                # Each packet at once, as a UART sends it (no waiting for the client's ACK).
                connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                if not self._talk(connection):
                    return

    def _talk(self, connection: socket.socket) -> bool:
        """Stream to `connection` until it closes (True) or the stand-in stops (False)."""
        seq = 0
        while not self._stop.is_set():
            with self._lock:
                pause, self._pause_s = self._pause_s, 0.0
            if pause:
                self._paused.set()
                time.sleep(pause)
            try:
                data = connection.recv(1 << 16)
                if not data:
                    return True
            except TimeoutError:
                data = b""
            out = b""
            with self._lock:
                self.received += data
                for command in self._decoder.feed(data):
                    self.commands.append(command)
                    t = self.now_us() % 2**32
                    out += encode_time_reply(TimeReply(command.seq, command.tx_time_us, t, t))
                    if self.answer_status:
                        out += encode_uplink_status(
                            UplinkStatus(command.seq, t, 0, len(self.commands), 0, 0, 50, 0, 0)
                        )
                rc = self.commands[-1].rc if self.commands else (0,) * 6
                t = self.now_us()
                packet = StatePacket(
                    (t + 10) % 2**32, (frame(t - PERIOD_US, rc), frame(t, rc)), seq % 2**24, True, 0
                )
                out = encode_state(packet) + out + b"".join(self.pending)
                self.pending.clear()
            seq += 1
            try:
                connection.sendall(out)
            except OSError:
                return True
        return False
