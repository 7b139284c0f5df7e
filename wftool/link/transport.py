"""Opening serial links to a flight controller, whatever the URL.

Everything that talks to an FC (MSP, CLI, the FSP reader) opens its link here, so a port
that cannot be opened, or vanishes mid-session (USB re-enumeration, SITL exit), always
surfaces as one `PortError` with a one-line message instead of a pyserial traceback.
"""

from __future__ import annotations

import array
import contextlib
import re
import select
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, cast
from urllib.parse import urlsplit

import serial
from serial.tools import list_ports
from serial.urlhandler import protocol_socket

try:
    import fcntl
    import termios
except ImportError:  # not POSIX: in_waiting it is
    fcntl = None  # type: ignore[assignment]

from wftool.errors import PortError, UsageError


@dataclass(frozen=True)
class UsbId:
    """A USB vendor:product pair, printed the way lsusb and udev rules spell it."""

    vid: int
    pid: int

    def __str__(self) -> str:
        return f"{self.vid:04x}:{self.pid:04x}"


STM32_VCP = UsbId(0x0483, 0x5740)
"""A Betaflight FC running its firmware: the STM32 USB virtual COM port."""
STM32_DFU = UsbId(0x0483, 0xDF11)
"""An STM32 in its ROM DFU bootloader."""
Port = serial.Serial
"""What `open_port` returns, whatever the URL (pyserial's URL handlers implement
`serial.Serial`'s interface, `in_waiting` and `reset_input_buffer` included)."""
NETWORK_SCHEMES = {"socket": 5761, "rfc2217": 2217}
"""pyserial URLs that name a TCP host and port, with an example port for messages."""


def open_port(url: str, baudrate: int = 115200, timeout: float = 1.0) -> Port:
    """Open a device path or pyserial URL (`socket://`, `rfc2217://`, …) for reading and writing.

    `timeout` is the read timeout in seconds; writes time out after the same interval so a
    stalled peer cannot hang the caller. A malformed URL or baud rate is a `UsageError`.
    """
    if problem := url_problem(url):
        raise UsageError(f"cannot open {url}: {problem}")
    if baudrate <= 0:
        raise UsageError(f"cannot open {url}: the baud rate must be positive, not {baudrate}")
    try:
        if urlsplit(url).scheme == "socket":
            port = SocketPort(
                url, baudrate=baudrate, timeout=timeout, write_timeout=max(timeout, 1.0)
            )
            return cast(Port, port)  # pyserial's URL handlers are `Serial`s in all but the stubs
        return serial.serial_for_url(
            url, baudrate=baudrate, timeout=timeout, write_timeout=max(timeout, 1.0)
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise PortError(f"cannot open {url}: {_reason(exc)}") from exc


RELEASE_TIMEOUT_S = 0.3
"""How long closing a socket:// port waits for the peer to let go of the connection: what
pyserial's own close sleeps every time, "in case of quick reconnects"."""


class SocketPort(protocol_socket.Serial):
    """pyserial's socket:// port, with two changes.

    Its write times out only when the peer takes nothing for the write timeout. pyserial's
    own looks at the clock after each send and raised "Write timeout" for a write that went
    out whole when the writing thread had run late (a loaded host's scheduling, a busy
    interpreter), as if the peer had stalled.

    Its close returns once the peer has closed its end too, which a one-client server (SITL's
    UARTs) does when it has let go of the connection: a reconnect is then accepted, not
    dropped. pyserial's own sleeps 0.3 s at every close for that.
    """

    _socket: socket.socket | None

    def write(self, data: Any) -> int:
        sock = self._socket
        if not self.is_open or sock is None:
            raise serial.PortNotOpenError()
        left = memoryview(bytes(data))
        length = len(left)
        while left:
            try:
                left = left[sock.send(left) :]
                continue
            except (BlockingIOError, InterruptedError):
                pass
            except OSError as exc:
                raise serial.SerialException(f"write failed: {exc}") from exc
            _, ready, _ = select.select([], [sock], [], self.write_timeout)
            if not ready:  # the peer took nothing for the whole write timeout
                raise serial.SerialTimeoutException("Write timeout")
        return length

    def close(self) -> None:
        sock, self._socket = self._socket, None
        self.is_open = False
        if sock is None:
            return
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_WR)
            _await_end_of_stream(sock, RELEASE_TIMEOUT_S)
        sock.close()


def _await_end_of_stream(sock: socket.socket, timeout: float) -> None:
    """Read (and drop) what `sock` receives until the peer closes its end, for at most
    `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        ready, _, _ = select.select([sock], [], [], left)
        if ready and not sock.recv(_READ_SIZE):
            return


@contextlib.contextmanager
def port_errors(url: str) -> Iterator[None]:
    """Turn I/O failures on an open link into `PortError` ("vanished") for the block."""
    try:
        yield
    except (serial.SerialException, OSError) as exc:
        raise PortError(f"lost connection to {url}: {_reason(exc)}") from exc


_READ_SIZE = 1 << 16


def selectable_fd(port: Port) -> int | None:
    """The port's descriptor for `select`, or None where it has none (rfc2217://)."""
    try:
        return port.fileno()
    except (AttributeError, NotImplementedError, OSError, serial.SerialException):
        return None


def read_within(port: Port, fd: int | None, timeout: float) -> bytes:
    """What arrives on `port` within `timeout` seconds; returns as soon as anything did.

    `fd` is `selectable_fd(port)`: with it, the wait is a `select` and the port may be
    opened with `timeout=0`; without it, the port's read timeout is set for the wait. The
    caller turns I/O errors into `PortError` (`port_errors`).
    """
    if fd is not None:
        ready, _, _ = select.select([fd], [], [], max(0.0, timeout))
        return port.read(_READ_SIZE) if ready else b""
    port.timeout = max(0.0, timeout)
    data = port.read(1)
    return data + port.read(port.in_waiting) if data else data


def read_size(port: Port) -> int:
    """How much to read from `port` now: what has arrived, at least 1 (a read then waits for
    it). pyserial's `in_waiting` of a socket:// port is never above 1 (it asks `select`),
    so a reply of N bytes took N reads; the kernel's count is asked instead."""
    if isinstance(port, protocol_socket.Serial) and port.is_open and fcntl is not None:
        count = array.array("i", [0])
        fcntl.ioctl(port.fileno(), termios.FIONREAD, count)
        return max(1, count[0])
    return max(1, port.in_waiting)


def url_problem(url: str) -> str | None:
    """What is wrong with a network URL (`socket://HOST:PORT`, `rfc2217://…`), or None.

    pyserial's own complaints about these are cryptic ("'debug|info|warning|error'").
    """
    try:
        parts = urlsplit(url)
    except ValueError as exc:  # an unbalanced '[' in the host: "Invalid IPv6 URL"
        return f"not a URL ({exc})"
    if parts.scheme not in NETWORK_SCHEMES:
        return None
    example = f"{parts.scheme}://127.0.0.1:{NETWORK_SCHEMES[parts.scheme]}"
    try:
        port = parts.port
    except ValueError:
        port = -1
    if not parts.hostname:
        return f"no host in it; expected {parts.scheme}://HOST:PORT, e.g. {example}"
    if port is None or not 0 < port < 65536:
        return f"the port must be a number from 1 to 65535, e.g. {example}"
    return None


def usb_ports(usb_id: UsbId) -> list[str]:
    """Device paths of the serial ports with this USB id, sorted for a stable choice."""
    return sorted(
        port.device
        for port in list_ports.comports()
        if port.vid == usb_id.vid and port.pid == usb_id.pid
    )


def _reason(exc: BaseException) -> str:
    """The shortest faithful description of an OS/pyserial error.

    pyserial wraps errors as "[Errno 2] could not open port /dev/x: [Errno 2] No such …"
    or "Could not open port URL: [Errno 111] Connection refused"; the reason is the tail.
    """
    text = (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)).strip()
    text = _ERRNO.sub("", text)
    if text.lower().startswith("could not open port ") and ": " in text:
        text = _ERRNO.sub("", text.split(": ", 1)[1])
    return text or type(exc).__name__


_ERRNO = re.compile(r"^\[Errno -?\d+\] ")
