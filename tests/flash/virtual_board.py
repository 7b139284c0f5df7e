"""TEST SCAFFOLDING: a VIRTUAL BOARD joined from two real halves — the virtual FC (the patched
SITL: MSP, CLI, its configuration in eeprom.bin) and the emulated STM32F722 ROM bootloader
(emulator.py: the real dfu-util and libusb through umockdev). Nothing here is product code.

What joins them, as a board's reset circuitry and flash would:
- The FC asked to reboot into its bootloader (MSP_REBOOT: SITL logs `ResetToBootloader`
  and exits) makes the bootloader appear on USB (`attach`), after `ENUMERATION_S`.
- The configuration sector: entering the bootloader copies eeprom.bin into the emulated
  flash at 0x08004000; when the firmware starts again, the sector goes back into
  eeprom.bin. An erased sector (`--full-erase`) comes back as 0xFF bytes, which the SITL
  rejects as an invalid configuration and replaces with its defaults, as a board does.
- After the bootloader left the bus, the FC comes back (SITL starts) only if the firmware
  the chip started from has a valid vector table (`Left.runs`); otherwise it stays dark.
- `IdentityBridge` (optional) presents the SITL as the board an image was built for:
  MSP_BOARD_INFO replies and the CLI's version line name that board's MCU target, board
  identifier, board and manufacturer instead of SITL's. Every other byte passes unchanged.

The SITL runs its own build, so the FC that comes back reports the SITL's build identity:
a flash is confirmed when the image carries that identity (the session's SITL and board
builds share one SOURCE_DATE_EPOCH and tree, so the real SPEEDYBEEF7V3 image does).
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from tests.flash.emulator import EmulatedBootloader
from tests.flash.images import CONFIG_SECTOR, sector_span
from wftool.errors import PortError
from wftool.fc.msp import Cmd, MspVersion, encode_request
from wftool.sitl.process import LOOPBACK, VirtualFC

ENUMERATION_S = 0.3
"""From the reset into the bootloader to the device on the bus (a USB enumeration)."""
RESET = b"[system]Reset"
"""How SITL logs its last words: `[system]Reset!` or `[system]ResetToBootloader!`."""


@dataclass(frozen=True)
class BoardIdentity:
    """What a board's firmware reports about itself (MSP_BOARD_INFO, the CLI version line)."""

    identifier: str
    target: str
    board: str
    manufacturer: str


SPEEDYBEEF7V3 = BoardIdentity("F722", "STM32F722", "SPEEDYBEEF7V3", "SPBE")
"""TARGET_BOARD_IDENTIFIER of STM32F722, and targets/configs/SPEEDYBEEF7V3/config.h."""


class VirtualBoard:
    """The virtual FC and the emulated bootloader as one board (the `Board` flash uses)."""

    def __init__(
        self,
        fc: VirtualFC,
        bootloader: EmulatedBootloader,
        *,
        identity: BoardIdentity | None = None,
        bootloader_appears: bool = True,
    ) -> None:
        self.fc = fc
        self.bootloader = bootloader
        self.bootloader_appears = bootloader_appears
        self.in_bootloader = False
        self._bridge = IdentityBridge(fc, identity) if identity else None
        self._stop = threading.Event()
        # The watcher's reset into the bootloader and a start after one take turns: judged
        # between them, the last process's `ResetToBootloader` would stop the FC just started.
        self._power = threading.RLock()
        self._watcher = threading.Thread(target=self._watch, name="virtual-board", daemon=True)

    @property
    def url(self) -> str:
        return self._bridge.url if self._bridge else self.fc.url

    @property
    def eeprom(self) -> Path:
        return self.fc.workdir / "eeprom.bin"

    def start(self) -> None:
        self.fc.start()
        if self._bridge:
            self._bridge.start()
        self._watcher.start()

    def stop(self) -> None:
        self._stop.set()
        if self._watcher.is_alive():
            self._watcher.join()
        if self._bridge:
            self._bridge.stop()
        self.fc.stop()

    def wait_back(self, timeout: float = 10.0) -> None:
        """After a reset: the FC starts again — from the bootloader only once it has left
        and the chip started firmware that runs."""
        with self._power:
            self._wait_back(timeout)

    def _wait_back(self, timeout: float) -> None:
        if self.in_bootloader:
            left = self.bootloader.wait_left(timeout)
            if left is None or not left.runs:
                raise PortError(f"the flight controller did not come back within {timeout:.0f} s")
            self._config_sector_to_eeprom()
            self.in_bootloader = False
        self.fc.wait_back(timeout)

    def enter_bootloader(self) -> None:
        """The chip starts its ROM bootloader (reset into it, or BOOT held at power-up)."""
        with self._power:
            self.fc.stop()
            self.in_bootloader = True
            self._eeprom_to_config_sector()
            self.bootloader.attach()

    def _watch(self) -> None:
        while not self._stop.wait(0.05):
            if self.in_bootloader or not self.bootloader_appears:
                continue
            with self._power:
                try:
                    running = self.fc.running
                except AttributeError:  # restarting under our feet
                    continue
                if self.in_bootloader or running:
                    continue
                if self._last_reset() == b"[system]ResetToBootloader!":
                    time.sleep(ENUMERATION_S)
                    self.enter_bootloader()

    def _last_reset(self) -> bytes:
        """The latest SITL process's last `[system]Reset…` line in its log (the reason it
        exited; none if it crashed)."""
        if not self.fc.log_path.exists():
            return b""
        with self.fc.log_path.open("rb") as log:
            log.seek(max(self.fc.log_offset, log.seek(0, 2) - 4096))
            tail = log.read()
        start = tail.rfind(RESET)
        return tail[start:].split(b"\n", 1)[0] if start >= 0 else b""

    def _eeprom_to_config_sector(self) -> None:
        start, end = sector_span(CONFIG_SECTOR)
        config = self.eeprom.read_bytes() if self.eeprom.exists() else b""
        if any(config[end - start :]):
            raise RuntimeError(f"{self.eeprom} holds more than the config sector")
        flash = bytearray(self.bootloader.flash())
        flash[start:end] = config[: end - start].ljust(end - start, b"\xff")
        self.bootloader.load(bytes(flash))

    def _config_sector_to_eeprom(self) -> None:
        start, end = sector_span(CONFIG_SECTOR)
        sector = self.bootloader.flash()[start:end]
        length = self.eeprom.stat().st_size if self.eeprom.exists() else end - start
        self.eeprom.write_bytes(sector.ljust(length, b"\0"))

    def __enter__(self) -> VirtualBoard:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()


class IdentityBridge:
    """TCP in front of the FC's UART1 that presents it as `identity` (see module docstring)."""

    def __init__(self, fc: VirtualFC, identity: BoardIdentity) -> None:
        self.fc = fc
        self.identity = identity
        self._server = socket.create_server((LOOPBACK, 0))
        self.url = f"socket://{LOOPBACK}:{self._server.getsockname()[1]}"
        self._threads: list[threading.Thread] = []
        self._closing = False

    def start(self) -> None:
        thread = threading.Thread(target=self._accept, name="identity-bridge", daemon=True)
        thread.start()
        self._threads.append(thread)

    def stop(self) -> None:
        self._closing = True
        self._server.close()

    def _accept(self) -> None:
        while not self._closing:
            try:
                client, _ = self._server.accept()
            except OSError:
                return
            try:
                upstream = socket.create_connection((LOOPBACK, self.fc.port_base + 1), timeout=2)
            except OSError:
                client.close()  # the FC is not there: as a port that is gone
                continue
            upstream.settimeout(None)
            pumps = threading.Barrier(2, action=lambda c=client, u=upstream: (c.close(), u.close()))
            for source, sink, rewrite in ((client, upstream, False), (upstream, client, True)):
                thread = threading.Thread(
                    target=self._pump, args=(source, sink, rewrite, pumps), daemon=True
                )
                thread.start()

    def _pump(
        self, source: socket.socket, sink: socket.socket, rewrite: bool, pumps: threading.Barrier
    ) -> None:
        """One direction, until its source ends; then its end goes on to the sink (a half
        close). The connection closes once both directions have ended: a client that closes
        hears the end of the FC's side only once the FC has let go of the connection, as on
        the FC's own port (wftool waits for that before it connects again)."""
        rewriter = _Rewriter(self.identity)
        with contextlib.suppress(OSError):
            while chunk := source.recv(4096):
                sink.sendall(rewriter.feed(chunk) if rewrite else chunk)
            sink.sendall(rewriter.flush() if rewrite else b"")
        with contextlib.suppress(OSError):
            sink.shutdown(socket.SHUT_WR)
        with contextlib.suppress(threading.BrokenBarrierError):
            pumps.wait()


class _Rewriter:
    """Rewrites the FC's byte stream: MSP_BOARD_INFO replies, and the CLI version line."""

    def __init__(self, identity: BoardIdentity) -> None:
        self.identity = identity
        self.version_from = b"/ SITL (SITL) "
        self.version_to = f"/ {identity.target} ({identity.identifier}) ".encode()
        self.buffer = b""

    def feed(self, chunk: bytes) -> bytes:
        self.buffer += chunk
        out = bytearray()
        while self.buffer:
            if self.buffer[:1] == b"$":
                frame, used = self._frame(self.buffer)
                if used == 0:
                    break  # an MSP frame, not all here yet
                out += frame
                self.buffer = self.buffer[used:]
                continue
            end = self.buffer.find(b"$", 1)
            text = self.buffer if end < 0 else self.buffer[:end]
            keep = _partial_suffix(text, self.version_from) if end < 0 else 0
            out += text[: len(text) - keep].replace(self.version_from, self.version_to)
            self.buffer = self.buffer[len(text) - keep :]
            if keep:
                break
        return bytes(out)

    def flush(self) -> bytes:
        rest, self.buffer = self.buffer, b""
        return rest

    def _frame(self, data: bytes) -> tuple[bytes, int]:
        """(bytes to send, bytes consumed) for data starting with '$'; (b"", 0): need more."""
        if len(data) < 3:
            return b"", 0
        if data[1:3] not in (b"M>", b"X>", b"M!", b"X!"):
            return data[:1], 1  # a '$' in CLI text
        if data[1:2] == b"M":
            if len(data) < 5:
                return b"", 0
            size, cmd, header = data[3], data[4], 5
            if size == 255:
                return data, len(data)  # jumbo frames are not board info: pass them on
        else:
            if len(data) < 8:
                return b"", 0
            cmd, size = int.from_bytes(data[4:6], "little"), int.from_bytes(data[6:8], "little")
            header = 8
        total = header + size + 1
        if len(data) < total:
            return b"", 0
        if cmd != Cmd.BOARD_INFO or data[2:3] != b">":
            return data[:total], total
        payload = self._board_info(data[header : header + size])
        version = MspVersion.V1 if data[1:2] == b"M" else MspVersion.V2
        frame = encode_request(cmd, payload, version)
        return frame[:2] + b">" + frame[3:], total

    def _board_info(self, payload: bytes) -> bytes:
        """MSP_BOARD_INFO with this identity: identifier, then after hardware revision,
        FC type and capabilities the target, board and manufacturer strings."""
        strings, offset = [], 8
        for _ in range(3):
            length = payload[offset]
            strings.append(payload[offset + 1 : offset + 1 + length])
            offset += 1 + length
        names = (self.identity.target, self.identity.board, self.identity.manufacturer)
        packed = b"".join(bytes([len(name)]) + name.encode() for name in names)
        return self.identity.identifier.encode()[:4] + payload[4:8] + packed + payload[offset:]


def _partial_suffix(text: bytes, pattern: bytes) -> int:
    """Length of the longest end of TEXT that begins PATTERN (it may complete later)."""
    for length in range(min(len(text), len(pattern) - 1), 0, -1):
        if pattern.startswith(text[-length:]):
            return length
    return 0
