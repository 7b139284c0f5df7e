"""Where a flight controller is reached, and how to find it again after it resets.

Saving, leaving the CLI, rebooting and flashing all reset the FC and drop the link. A real
board re-enumerates on USB (possibly under another /dev path); the virtual FC
(`wftool.sitl.VirtualFC`) exits and is restarted. Both offer `url` and `wait_back()`.
"""

from __future__ import annotations

import time
from typing import Protocol

from wftool.errors import MspError, PortError, UsageError
from wftool.fc.msp import MspClient
from wftool.fc.transport import STM32_VCP, usb_ports

RESET_GRACE_S = 0.5
"""Pause before looking for the FC again, so we do not reach the old instance mid-reset."""


class Board(Protocol):
    url: str

    def wait_back(self, timeout: float = ...) -> None:
        """Block until the FC answers MSP again after a reset."""


class SerialBoard:
    """A flight controller on a serial port or pyserial URL."""

    def __init__(self, url: str, *, rediscover: bool = False) -> None:
        self.url = url
        self.rediscover = rediscover
        """Found by USB id rather than named: look it up again after a reset."""

    @classmethod
    def find(cls, port: str | None = None, *, present: bool = True) -> SerialBoard:
        """The board on `port`, or the only STM32 virtual COM port on USB.

        `present=False` is for a board that is not on USB yet (in DFU mode): its port is
        looked up when it comes back.
        """
        if port:
            return cls(port)
        if not present:
            return cls("", rediscover=True)
        ports = usb_ports(STM32_VCP)
        if not ports:
            raise PortError(
                f"no flight controller on USB (looked for {STM32_VCP}); connect it or pass --port"
            )
        if len(ports) > 1:
            raise UsageError(f"several flight controllers on USB ({', '.join(ports)}); pass --port")
        return cls(ports[0], rediscover=True)

    def wait_back(self, timeout: float = 15.0) -> None:
        time.sleep(RESET_GRACE_S)
        deadline = time.monotonic() + timeout
        while True:
            candidates = usb_ports(STM32_VCP) if self.rediscover else [self.url]
            for url in candidates:
                if _answers_msp(url):
                    self.url = url
                    return
            if time.monotonic() > deadline:
                raise PortError(f"the flight controller did not come back within {timeout:.0f} s")
            time.sleep(0.25)


def _answers_msp(url: str) -> bool:
    try:
        with MspClient.open(url, timeout=0.5) as msp:
            msp.api_version()
    except (PortError, MspError):
        return False
    return True
