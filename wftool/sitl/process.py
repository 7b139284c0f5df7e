"""Process manager for the virtual flight controller (Betaflight SITL).

SITL facts this relies on (Betaflight 2025.12, `src/platform/SIMULATOR`):

- UARTn is a TCP server on 127.0.0.1:5760+n, but only for UARTs that have a serial function
  configured (stock: UART1 = MSP only). Each accepts ONE client; a connection arriving
  before the previous one's close was processed is dropped at once. So a readiness probe
  must wait until SITL logs both `[NEW]UART1` (accepted) and `[CLS]UART1` (released).
- Now and then (more often on a loaded machine) UART1 binds but never accepts: the TCP
  thread's `dyad_update()` can destroy the listening stream while the main thread is still
  setting it up (dyad is not thread-safe). Such a start is detected by the probe and retried.
- Now and then (a few starts in a hundred) SITL boots with its gyro task never scheduled:
  MSP and the CLI answer, but no PID loop runs (MSP_STATUS cycle time 0). Such a start is
  detected and retried too, as a watchdog would reset a hung board.
- Every reset (CLI `save`/`exit`, MSP reboot, reboot to bootloader) ends the process with
  exit status 0; the configuration survives in `eeprom.bin` in the working directory.
- It also binds UDP 9001–9004, so two SITLs need separate network namespaces.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from pathlib import Path

from wftool.errors import SitlError
from wftool.fc.msp import MspClient

LOOPBACK = "127.0.0.1"
TCP_BASE_PORT = 5760
START_ATTEMPTS = 3
ACCEPT_TIMEOUT_S = 3.0
LOOP_TIMEOUT_S = 3.0


def uart_url(uart: int) -> str:
    """The pyserial URL of SITL's UART number `uart` (1-based)."""
    return f"socket://{LOOPBACK}:{TCP_BASE_PORT + uart}"


class VirtualFC:
    """A SITL binary running in `workdir`, restartable, never left behind.

    Use as a context manager, or call `start()`/`stop()`. `url` is UART1 (MSP and CLI).
    """

    url = uart_url(1)

    def __init__(self, binary: Path, workdir: Path, *, ready_timeout: float = 20.0) -> None:
        self.binary = Path(binary).resolve()
        self.workdir = Path(workdir)
        self.ready_timeout = ready_timeout
        self.log_path = self.workdir / "sitl.log"
        self.starts = 0
        """Successful starts so far (a restart after a reset counts, a retried start not)."""
        self._process: subprocess.Popen[bytes] | None = None
        self._start_offset = 0

    @staticmethod
    def uart_url(uart: int) -> str:
        return uart_url(uart)

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def start(self) -> None:
        """Start the process; return once UART1 has accepted (and released) a connection."""
        if self.running:
            raise SitlError("SITL is already running")
        self.workdir.mkdir(parents=True, exist_ok=True)
        problem = ""
        for _attempt in range(START_ATTEMPTS):
            self._spawn()
            problem = self._uart1_problem() or self._loop_problem()
            if not problem:
                self.starts += 1
                return
            self.stop()
        raise SitlError(f"{problem} ({START_ATTEMPTS} attempts; see {self.log_path})")

    def _spawn(self) -> None:
        self._start_offset = self.log_path.stat().st_size if self.log_path.exists() else 0
        with self.log_path.open("ab") as log:
            try:
                self._process = subprocess.Popen(
                    [str(self.binary)],
                    cwd=self.workdir,
                    stdin=subprocess.DEVNULL,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,  # own process group: stop() kills helpers too
                )
            except OSError as exc:
                raise SitlError(f"cannot run SITL binary {self.binary}: {exc.strerror}") from exc

    def _uart1_problem(self) -> str:
        """Why UART1 is not usable yet, or "" once a probe connection came and went."""
        listening = self._await_log(b"bind port 5761 for UART1", self.ready_timeout)
        if listening is None:
            return f"SITL did not open UART1 within {self.ready_timeout:.0f} s"
        if b"bind port 5761 for UART1 failed" in listening:
            return f"SITL could not listen on TCP {TCP_BASE_PORT + 1}: another SITL here?"
        offset = self.log_path.stat().st_size
        try:
            with socket.create_connection((LOOPBACK, TCP_BASE_PORT + 1), timeout=1):
                accepted = self._await_log(b"[NEW]UART1", ACCEPT_TIMEOUT_S, offset)
        except OSError as exc:
            return f"SITL's UART1 refused a connection: {exc.strerror or exc}"
        if accepted is None:
            return "SITL's UART1 listens but never accepts"
        if self._await_log(b"[CLS]UART1", ACCEPT_TIMEOUT_S, offset) is None:
            return "SITL's UART1 did not notice the probe connection closing"
        return ""

    def _loop_problem(self) -> str:
        """Why the flight loop is not running, or "" once MSP reports a PID cycle time."""
        deadline = time.monotonic() + LOOP_TIMEOUT_S
        with MspClient.open(self.url) as msp:
            while time.monotonic() < deadline:
                if msp.pid_cycle_us():
                    return ""
                time.sleep(0.05)
        return f"SITL's PID loop did not start within {LOOP_TIMEOUT_S:.0f} s"

    def _await_log(self, marker: bytes, timeout: float, offset: int = 0) -> bytes | None:
        """The log from `offset` (default: this start) once it holds `marker`, else None."""
        offset = offset or self._start_offset
        deadline = time.monotonic() + timeout
        while True:
            with self.log_path.open("rb") as log:
                log.seek(offset)
                text = log.read()
            if marker in text:
                return text
            assert self._process is not None
            status = self._process.poll()
            if status is not None:
                self._process = None
                raise SitlError(f"SITL exited with status {status} while starting: {self.log_path}")
            if time.monotonic() > deadline:
                return None
            time.sleep(0.01)

    def stop(self, grace: float = 3.0) -> None:
        """Terminate the process group, then kill it if it lingers."""
        process, self._process = self._process, None
        if process is None:
            return
        for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 10.0)):
            try:
                os.killpg(process.pid, sig)
            except ProcessLookupError:
                break
            try:
                process.wait(wait)
                break
            except subprocess.TimeoutExpired:
                continue
        process.wait()

    def restart(self) -> None:
        self.stop()
        self.start()

    def wait_back(self, timeout: float = 10.0) -> None:
        """After the firmware reset itself (save, exit, reboot): wait for the exit, start again.

        SITL cannot restart itself, so this plays the part of the board's reset circuitry.
        """
        if self._process is not None:
            try:
                self._process.wait(timeout)
            except subprocess.TimeoutExpired as exc:
                raise SitlError(f"SITL did not reset within {timeout:.0f} s") from exc
            self._process = None
        self.start()

    def __enter__(self) -> VirtualFC:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
