"""The virtual flight controller's process (Betaflight SITL): started on its own ports, ready
when MSP answers, stopped with wftool however wftool ends (the SITL facts: docs/design.md).

    with VirtualFC(binary, workdir, port_base=21000) as fc:
        print(fc.url, fc.uart_url(2))
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import PortInUseError, SitlError, WftoolError
from wftool.fc.msp import MspClient
from wftool.sitl.crash import crash_report

LOOPBACK = "127.0.0.1"
DEFAULT_PORT_BASE = 5760
SIM_PORT_OFFSET = 3240
"""The simulator's UDP port base, relative to the TCP port base (5760 -> upstream's 9000)."""
SIM_STATE_PORT = 3
"""SITL's simulator state input is UDP sim base + 3 (9003 by default)."""
SIM_RC_PORT = 4
"""SITL's RC input (the simulated radio, `feature RX_UDP`) is UDP sim base + 4."""
UART_COUNT = 8
MAX_PORT_BASE = 65535 - SIM_PORT_OFFSET - UART_COUNT
"""The highest port base whose every port (TCP per UART, the simulator's UDP) exists."""
START_ATTEMPTS = 3
ACCEPT_TIMEOUT_S = 3.0
LOOP_TIMEOUT_S = 3.0
GYRO_HZ_MIN, GYRO_HZ_MAX = 100, 32000
"""The gyro rates the SITL takes (sitl_options.c)."""


@dataclass(frozen=True)
class VirtualBoard:
    """What the virtual FC emulates of a board's hardware: the SITL's own options."""

    gyro_hz: int | None = None
    """The sample rate its gyro reports, from which the FC takes its looptime (None: the
    SITL's virtual gyro, 8000 Hz)."""
    gyro_clock_hz: float | None = None
    """The rate the gyro's samples really come at, which the PID loop locks onto, as on a
    board whose gyro runs off its own oscillator (None: the reported rate)."""
    uart_pacing: bool = False
    """UARTs move bytes at their baud rate in FC time, 10 bits a byte, both ways (off: as fast
    as TCP)."""

    def __post_init__(self) -> None:
        for name in ("gyro_hz", "gyro_clock_hz"):
            value = getattr(self, name)
            if value is not None and not GYRO_HZ_MIN <= value <= GYRO_HZ_MAX:
                raise SitlError(f"{name} must be {GYRO_HZ_MIN}-{GYRO_HZ_MAX} Hz, not {value}")

    def argv(self) -> list[str]:
        """The SITL's command-line options for this board."""
        args = []
        if self.gyro_hz is not None:
            args.append(f"--gyro-hz={self.gyro_hz}")
        if self.gyro_clock_hz is not None:
            args.append(f"--gyro-clock-hz={self.gyro_clock_hz:.3f}")
        if self.uart_pacing:
            args.append("--uart-pacing")
        return args


SITL_BOARD = VirtualBoard()
"""The SITL as it is: its virtual gyro at 8000 Hz, UARTs as fast as TCP."""


def exit_status(status: int) -> str:
    """A process's exit status in words: "status 1", "SIGSEGV"."""
    if status < 0:
        try:
            return signal.Signals(-status).name
        except ValueError:
            return f"signal {-status}"
    return f"status {status}"


def uart_url(uart: int, port_base: int = DEFAULT_PORT_BASE) -> str:
    """The pyserial URL of SITL's UART number `uart` (1-based)."""
    return f"socket://{LOOPBACK}:{port_base + uart}"


def ports_in_use(port_base: int) -> list[str]:
    """Which of a virtual FC's ports (TCP per UART, UDP inputs) another program holds."""
    taken = []
    tcp = [(socket.SOCK_STREAM, port_base + uart) for uart in range(1, UART_COUNT + 1)]
    udp = [
        (socket.SOCK_DGRAM, port_base + SIM_PORT_OFFSET + n) for n in (SIM_STATE_PORT, SIM_RC_PORT)
    ]
    for kind, port in tcp + udp:
        with socket.socket(socket.AF_INET, kind) as probe:
            if kind == socket.SOCK_STREAM:  # as SITL listens: a closed connection's TIME_WAIT
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # does not count
            try:
                probe.bind((LOOPBACK, port))
            except OSError:
                taken.append(f"{'TCP' if kind == socket.SOCK_STREAM else 'UDP'} {port}")
    return taken


def free_port_base(start: int = 20000, stop: int = 32700, step: int = 50) -> int:
    """A port base none of whose ports is in use now, from a pseudo-random start (so that
    test runs side by side rarely even probe the same one).

    Below Linux's ephemeral range (32768-60999): there any outgoing connection on the
    machine may be given one of the ports between this check and the SITL's bind, or while
    the SITL restarts after a save (seen as PortInUseError from `wait_back`).
    """
    stop = min(stop, MAX_PORT_BASE + 1)
    first = start + (os.getpid() * 7919 % ((stop - start) // step)) * step
    for base in [*range(first, stop, step), *range(start, first, step)]:
        if not ports_in_use(base):
            return base
    raise SitlError(f"no free port base between {start} and {stop}")


def _ended(process: subprocess.Popen[bytes], within: float) -> int | None:
    """`process`'s exit status once it has ended within `within` s, else None."""
    try:
        return process.wait(within)
    except subprocess.TimeoutExpired:
        return None


@contextlib.contextmanager
def scratch_workdir(workdir: Path | None, prefix: str) -> Iterator[Path]:
    """`workdir` as it is; or, None, a new temporary directory (named from `prefix`), removed
    when the block ends without an error and kept after one, whose sitl.log it names."""
    if workdir is not None:
        yield workdir
        return
    scratch = Path(tempfile.mkdtemp(prefix=prefix))
    yield scratch
    shutil.rmtree(scratch, ignore_errors=True)


class VirtualFC:
    """A SITL binary running in `workdir`, restartable, never left behind.

    Use as a context manager, or call `start()`/`stop()`. `url` is UART1 (MSP and CLI).
    `port_base=None` takes any free port base at the first start (another one if a program
    takes a port meanwhile) and keeps it across restarts, so clients find the FC again.
    """

    def __init__(
        self,
        binary: Path,
        workdir: Path,
        *,
        port_base: int | None = DEFAULT_PORT_BASE,
        ready_timeout: float = 20.0,
        board: VirtualBoard = SITL_BOARD,
        idle_timeout_s: int | None = None,
    ) -> None:
        self.binary = Path(binary).resolve()
        self.board = board
        self.idle_timeout_s = idle_timeout_s
        """How long a UART's client may go without traffic either way before the SITL lets
        it go (None: the SITL's own, 120 s)."""
        self.workdir = Path(workdir)
        self._fixed_base = port_base is not None
        self._port_base = port_base
        self.ready_timeout = ready_timeout
        self.log_path = self.workdir / "sitl.log"
        self.starts = 0
        """Successful starts so far (a restart after a reset counts, a retried start not)."""
        self._process: subprocess.Popen[bytes] | None = None
        self.log_offset = 0
        """Where the output of the latest process started begins in `log_path`."""

    @property
    def port_base(self) -> int:
        """The TCP port base (chosen at the first start when none was given)."""
        if self._port_base is None:
            raise SitlError("the virtual FC has no port base before it starts")
        return self._port_base

    def uart_url(self, uart: int) -> str:
        return uart_url(uart, self.port_base)

    @property
    def url(self) -> str:
        return self.uart_url(1)

    @property
    def sim_state_port(self) -> int:
        """The UDP port of SITL's simulator state input (motion)."""
        return self.port_base + SIM_PORT_OFFSET + SIM_STATE_PORT

    @property
    def sim_rc_port(self) -> int:
        """The UDP port of SITL's RC input (the simulated radio)."""
        return self.port_base + SIM_PORT_OFFSET + SIM_RC_PORT

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def start(self) -> None:
        """Start the process; return once UART1 has accepted (and released) a connection."""
        if self.running:
            raise SitlError("SITL is already running")
        for attempt in range(START_ATTEMPTS):
            if self._port_base is None:
                self._port_base = free_port_base()
            try:
                self._start_on_ports()
                return
            except PortInUseError:
                if self._fixed_base or self.starts or attempt + 1 == START_ATTEMPTS:
                    raise
                self._port_base = None  # taken since it was found free: take another

    def _start_on_ports(self) -> None:
        if taken := ports_in_use(self.port_base):
            raise PortInUseError(
                f"{taken[0]} is in use: another virtual FC (or program) holds it; "
                f"choose another port base (--port-base)"
            )
        self.workdir.mkdir(parents=True, exist_ok=True)
        problem = ""
        for _attempt in range(START_ATTEMPTS):
            process = self._spawn()
            try:
                problem = self._uart1_problem(process) or self._loop_problem()
            except WftoolError as exc:
                status = None if isinstance(exc, SitlError) else _ended(process, 1.0)
                self.stop()
                if status is not None:
                    raise self._died(status) from exc  # MSP lost its peer: say why
                raise
            except BaseException:
                self.stop()
                raise
            if not problem:
                self.starts += 1
                return
            self.stop()
        raise SitlError(f"{problem} ({START_ATTEMPTS} attempts; see {self.log_path})")

    def _died(self, status: int) -> SitlError:
        return SitlError(f"SITL ended with {self._ending(status)} while starting: {self.log_path}")

    def _ending(self, status: int) -> str:
        """How the latest process ended, with what it said of a fatal signal."""
        report = ""
        if status < 0 and self.log_path.exists():
            with self.log_path.open("rb") as log:
                log.seek(self.log_offset)
                report = crash_report(log.read(), self.binary)
        return f"{exit_status(status)} ({report})" if report else exit_status(status)

    def _argv(self) -> list[str]:
        return [
            str(self.binary),
            f"--port-base={self.port_base}",
            f"--sim-port-base={self.port_base + SIM_PORT_OFFSET}",
            "--exit-with-parent",
            *self.board.argv(),
            *([] if self.idle_timeout_s is None else [f"--tcp-idle-timeout={self.idle_timeout_s}"]),
        ]

    def _spawn(self) -> subprocess.Popen[bytes]:
        self.log_offset = self.log_path.stat().st_size if self.log_path.exists() else 0
        with self.log_path.open("ab") as log:
            try:
                process = subprocess.Popen(
                    self._argv(),
                    cwd=self.workdir,
                    stdin=subprocess.DEVNULL,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,  # own process group: stop() kills helpers too
                )
            except OSError as exc:
                raise SitlError(f"cannot run SITL binary {self.binary}: {exc.strerror}") from exc
        self._process = process
        return process

    def _uart1_problem(self, process: subprocess.Popen[bytes]) -> str:
        """Why UART1 is not usable yet, or "" once a probe connection came and went."""
        port = self.port_base + 1
        marker = f"bind port {port} for UART1".encode()
        listening = self._await_log(marker, self.ready_timeout, process=process)
        if listening is None:
            return f"SITL did not open UART1 within {self.ready_timeout:.0f} s"
        if f"bind port {port} for UART1 failed".encode() in listening:
            raise PortInUseError(f"TCP {port} is in use: SITL could not listen on it")
        offset = self.log_path.stat().st_size
        try:
            with socket.create_connection((LOOPBACK, port), timeout=1):
                accepted = self._await_log(b"[NEW]UART1", ACCEPT_TIMEOUT_S, offset, process=process)
        except OSError as exc:
            if (status := process.poll()) is not None:
                raise self._died(status) from exc
            return f"SITL's UART1 refused a connection: {exc.strerror or exc}"
        if accepted is None:
            return "SITL's UART1 listens but never accepts"
        if self._await_log(b"[CLS]UART1", ACCEPT_TIMEOUT_S, offset, process=process) is None:
            return "SITL's UART1 did not notice the probe connection closing"
        return ""

    def _loop_problem(self) -> str:
        """Why the flight loop is not running, or "" once MSP reports a PID cycle time; UART1
        let go of again either way, so the caller's first link is the one it serves."""
        deadline = time.monotonic() + LOOP_TIMEOUT_S
        msp = MspClient.open(self.url)
        try:
            while time.monotonic() < deadline:
                if msp.pid_cycle_us():
                    return ""
                time.sleep(0.05)
        finally:
            self.close_client(1, msp.close)
        return f"SITL's PID loop did not start within {LOOP_TIMEOUT_S:.0f} s"

    def close_client(self, uart: int, close: Callable[[], object], timeout: float = 2.0) -> bool:
        """Run `close` (which closes this program's connection to UARTn) and wait until SITL
        has released it (`[CLS]UARTn`): a connection made before that is dropped at once."""
        offset = self.log_path.stat().st_size
        process = self._process
        close()
        if process is None:
            return True
        try:
            closed = self._await_log(f"[CLS]UART{uart}".encode(), timeout, offset, process=process)
        except SitlError:
            return True  # it ended: nothing holds the connection (how it ended is for wait_back)
        return closed is not None

    def _await_log(
        self, marker: bytes, timeout: float, offset: int = 0, *, process: subprocess.Popen[bytes]
    ) -> bytes | None:
        """The log from `offset` (default: this start) once it holds `marker`, else None;
        `process` ending first is a SitlError naming how it ended."""
        offset = offset or self.log_offset
        deadline = time.monotonic() + timeout
        while True:
            with self.log_path.open("rb") as log:
                log.seek(offset)
                text = log.read()
            if marker in text:
                return text
            if (status := process.poll()) is not None:
                raise self._died(status)
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
                status = self._process.wait(timeout)
            except subprocess.TimeoutExpired as exc:
                raise SitlError(f"SITL did not reset within {timeout:.0f} s") from exc
            self._process = None
            if status != 0:  # a reset exits with 0: anything else is a crash, not to be hidden
                raise SitlError(f"SITL ended with {self._ending(status)} instead of resetting: "
                                f"{self.log_path}")  # fmt: skip
        self.start()

    def __enter__(self) -> VirtualFC:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
