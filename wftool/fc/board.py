"""Where a flight controller is reached, and how to find it again after it resets.

Saving, leaving the CLI, rebooting and flashing all reset the FC and drop the link. A real
board re-enumerates on USB (possibly under another /dev path); the virtual FC
(`wftool.sitl.VirtualFC`) exits and is restarted. Both offer `url` and `wait_back()`.

An FC whose CLI was left open (an interrupted session, a link that dropped) ignores MSP
until someone leaves it: `leave_open_cli` finds that out and gets it out.
"""

from __future__ import annotations

import enum
import time
from typing import Protocol

from wftool.errors import MspError, PortError, UsageError
from wftool.fc.cli_session import CliSession, cli_is_open
from wftool.fc.msp import MspClient
from wftool.link.transport import STM32_VCP, Port, open_port, usb_ports
from wftool.progress import Log, quiet

RESET_GRACE_S = 0.5
"""Pause before looking for the FC again, so we do not reach the old instance mid-reset."""
MSP_PROBE_S = 0.5
"""How long an FC in MSP mode may take to answer the probe."""
DROP_RECOVERY_S = 3.0
"""After a link dropped: how long to look for the FC on its old port before waiting for a
reset instead."""


class Board(Protocol):
    @property
    def url(self) -> str: ...

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


class FcState(enum.Enum):
    """What an FC on a port does with a probe."""

    MSP = "answers MSP"
    CLI = "sits in its CLI"
    SILENT = "does not answer"
    GONE = "cannot be reached"


def leave_open_cli(board: Board, log: Log = quiet) -> bool:
    """If the FC sits in its CLI, leave it with `exit` and wait for the reboot; True if it did.

    `exit` is the only way out that does not keep what was left unsaved (arming stays
    blocked after `exit noreboot`), so the FC comes back with its saved configuration.
    """
    link = _probe(board.url)[1]
    if link is None:
        return False
    _exit_cli(board, link, log)
    return True


def wait_after_drop(board: Board, log: Log = quiet) -> bool:
    """After the link dropped before the FC confirmed `save`/`exit`: get the FC back.

    Returns True if the FC was still sitting in its CLI, i.e. never got the command (it
    has been left with `exit`, dropping unsaved changes); False if it reset or answers MSP.
    """
    deadline = time.monotonic() + DROP_RECOVERY_S
    while True:
        time.sleep(RESET_GRACE_S)
        state, link = _probe(board.url)
        if link is not None:
            _exit_cli(board, link, log)
            return True
        if state is FcState.MSP:
            return False
        if time.monotonic() > deadline:
            board.wait_back()  # resetting (or gone for now): the board knows how to wait
            return False


def _exit_cli(board: Board, link: Port, log: Log) -> None:
    log(
        "the FC was sitting in its CLI (a session was interrupted or lost its link); "
        "leaving it with `exit`, which reboots it and drops any unsaved change"
    )
    session = CliSession(link)
    session.in_cli = True
    if session.exit():
        board.wait_back()
    else:
        wait_after_drop(board, log)


def _probe(url: str) -> tuple[FcState, Port | None]:
    """The FC's state on URL; for an FC in its CLI, with the link still open to leave it."""
    try:
        link = open_port(url, timeout=0.05)
    except PortError:
        return FcState.GONE, None
    try:
        try:
            MspClient(link, timeout=MSP_PROBE_S).api_version()
            state = FcState.MSP
        except MspError:
            state = FcState.CLI if cli_is_open(link) else FcState.SILENT
    except PortError:
        state = FcState.GONE
    except BaseException:
        link.close()
        raise
    if state is FcState.CLI:
        return state, link
    link.close()
    return state, None


def _answers_msp(url: str) -> bool:
    try:
        with MspClient.open(url, timeout=0.5) as msp:
            msp.api_version()
    except (PortError, MspError):
        return False
    return True
