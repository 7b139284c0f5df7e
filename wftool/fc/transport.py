"""Opening serial links to a flight controller, whatever the URL.

Everything that talks to an FC (MSP, CLI, the FSP reader) opens its link here, so a port
that cannot be opened, or vanishes mid-session (USB re-enumeration, SITL exit), always
surfaces as one `PortError` with a one-line message instead of a pyserial traceback.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import serial
from serial.tools import list_ports

from wftool.errors import PortError


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


def open_port(url: str, baudrate: int = 115200, timeout: float = 1.0) -> serial.SerialBase:
    """Open a device path or pyserial URL (`socket://`, `rfc2217://`, …) for reading and writing.

    `timeout` is the read timeout in seconds; writes time out after the same interval so a
    stalled peer cannot hang the caller.
    """
    try:
        return serial.serial_for_url(
            url, baudrate=baudrate, timeout=timeout, write_timeout=max(timeout, 1.0)
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise PortError(f"cannot open {url}: {_reason(exc)}") from exc


@contextlib.contextmanager
def port_errors(url: str) -> Iterator[None]:
    """Turn I/O failures on an open link into `PortError` ("vanished") for the block."""
    try:
        yield
    except (serial.SerialException, OSError) as exc:
        raise PortError(f"lost connection to {url}: {_reason(exc)}") from exc


def usb_ports(usb_id: UsbId) -> list[str]:
    """Device paths of the serial ports with this USB id, sorted for a stable choice."""
    return sorted(
        port.device
        for port in list_ports.comports()
        if port.vid == usb_id.vid and port.pid == usb_id.pid
    )


def _reason(exc: BaseException) -> str:
    """The shortest faithful description of an OS/pyserial error."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    text = str(exc).strip()
    # pyserial wraps OSErrors as "[Errno 2] could not open port /dev/x: [Errno 2] No such …"
    return text.rsplit("] ", 1)[-1] if text.startswith("[Errno") else text or type(exc).__name__
