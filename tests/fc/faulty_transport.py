"""A FAULTY TRANSPORT: the real link to the real SITL, with one fault injected at the byte
boundary. Not a fake FC: every byte still comes from (and goes to) Betaflight.

Tests put `FaultyTransport.open_port` where the code under test opens its links
(`wftool.fc.params.open_port`). The faults are those a USB serial link to a real board
shows: a reply that pauses (or loses its rest) right after a `# ` line, a link that drops
when a command is sent (before or after the FC got it), and a Ctrl-C between two bytes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import serial

from wftool.link.transport import open_port

COMMENT_START = b"\r\n# "
DIFF_END = b"\r\n# save configuration\r\nsave\r\n# "
"""How the FC ends a whole `diff all` (printConfig, then the prompt)."""


@dataclass
class FaultyTransport:
    """Opens real links that inject, once, the faults configured here."""

    stall_after_comment: int | None = None
    """Pause the `diff all` reply right after its Nth `\\r\\n# ` (a comment line start)."""
    stall_s: float | None = 0.3
    """How long the pause lasts; None: the rest of the reply never arrives."""
    drop_at: bytes | None = None
    """Drop the link when a write starts with this (e.g. b"save")."""
    drop_after_sending: bool = False
    """Whether the FC still gets that write before the link drops."""
    delay_reply_at: bytes | None = None
    """Hold back what the FC sends after a write starting with this (e.g. b"save"): a slow FC."""
    delay_s: float = 6.0
    """How long that reply is held back."""
    interrupt_at: bytes | None = None
    """Raise KeyboardInterrupt (a Ctrl-C) right after a write starting with this is sent."""
    fired: list[str] = field(default_factory=list)
    """The faults injected so far, in order."""

    def open_port(self, url: str, baudrate: int = 115200, timeout: float = 1.0) -> FaultyLink:
        return FaultyLink(open_port(url, baudrate, timeout), self)


InjectFaults = Callable[..., FaultyTransport]
"""The `inject_faults` fixture (tests/conftest.py): FaultyTransport(**faults), put in place."""


class FaultyLink:
    """A pyserial link that passes everything through but the armed fault."""

    def __init__(self, link: serial.SerialBase, faults: FaultyTransport) -> None:
        self.link = link
        self.faults = faults
        self._ready = bytearray()
        """Bytes the FC sent that the reader may have now."""
        self._held: bytes | None = None
        """The rest of a stalled reply, released at `_release_at` (None: never)."""
        self._release_at: float | None = None
        self._diff_pending = False
        self._dropped = False
        self._delay_until: float | None = None
        """Until then the FC's reply is held back (it stays unread in the real link)."""

    def __getattr__(self, name: str) -> object:
        return getattr(self.link, name)

    @property
    def in_waiting(self) -> int:
        self._check()
        if self._delaying():
            return 0
        return len(self._ready) or (0 if self._held is not None else self.link.in_waiting)

    def write(self, data: bytes) -> int | None:
        self._check()
        faults = self.faults
        if faults.drop_at is not None and data.startswith(faults.drop_at):
            faults.drop_at = None
            faults.fired.append(f"link dropped at {data!r}")
            if faults.drop_after_sending:
                self.link.write(data)
                self.link.flush()
            self._drop()
        written = self.link.write(data)
        if faults.delay_reply_at is not None and data.startswith(faults.delay_reply_at):
            faults.delay_reply_at = None
            faults.fired.append(f"reply to {data!r} held back {faults.delay_s} s")
            self._delay_until = time.monotonic() + faults.delay_s
        if data.startswith(b"diff all") and faults.stall_after_comment is not None:
            self._diff_pending = True
        if faults.interrupt_at is not None and data.startswith(faults.interrupt_at):
            faults.interrupt_at = None
            faults.fired.append(f"Ctrl-C after {data!r}")
            raise KeyboardInterrupt
        return written

    def read(self, size: int = 1) -> bytes:
        self._check()
        if self._delaying():
            time.sleep(self.link.timeout or 0.05)  # what a quiet line looks like
            return b""
        if self._diff_pending:
            self._split_diff()
        if not self._ready and self._held is not None:
            if self._release_at is None or time.monotonic() < self._release_at:
                time.sleep(self.link.timeout or 0.05)  # what a quiet line looks like
                if self._release_at is None:
                    self._held = None  # lost: what the FC sends next gets through again
                return b""
            self._ready += self._held
            self._held = None
        if self._ready:
            chunk = bytes(self._ready[:size])
            del self._ready[:size]
            return chunk
        return self.link.read(size)

    def reset_input_buffer(self) -> None:
        """Drop what arrived; a held-back rest has not arrived yet and stays held."""
        self._ready.clear()
        self.link.reset_input_buffer()

    def _split_diff(self) -> None:
        """Read the whole `diff all` reply; hand out the part before the stall point."""
        self._diff_pending = False
        nth = self.faults.stall_after_comment
        assert nth is not None
        self.faults.stall_after_comment = None
        reply = bytearray()
        deadline = time.monotonic() + 15
        while DIFF_END not in reply and time.monotonic() < deadline:
            reply += self.link.read(max(1, self.link.in_waiting))
        cut = -1
        for _ in range(nth):
            cut = reply.index(COMMENT_START, cut + 1)
        cut += len(COMMENT_START)
        self._ready += reply[:cut]
        stall = self.faults.stall_s
        self._held = bytes(reply[cut:])
        self._release_at = None if stall is None else time.monotonic() + stall
        shown = "lost the rest" if stall is None else f"paused {stall} s"
        self.faults.fired.append(f"`diff all` {shown} after {bytes(reply[:cut][-16:])!r}")

    def _delaying(self) -> bool:
        if self._delay_until is not None and time.monotonic() >= self._delay_until:
            self._delay_until = None
        return self._delay_until is not None

    def _drop(self) -> None:
        self._dropped = True
        self.link.close()
        raise serial.SerialException("the link dropped (injected)")

    def _check(self) -> None:
        if self._dropped:
            raise serial.SerialException("the link dropped (injected)")

    def close(self) -> None:
        self.link.close()
