"""The virtual FC process manager, against the real SITL binary."""

from __future__ import annotations

import contextlib
import os
import platform
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path
from typing import IO

import pytest

from tests.waits import wait_for
from wftool.errors import PortInUseError, SitlError
from wftool.fc.msp import Cmd, MspClient, RebootMode, encode_request
from wftool.fsp import FspReader, StatePacket
from wftool.fsp.schedule import lockstep_interval
from wftool.link import transport
from wftool.sitl.process import (
    LOOPBACK,
    MAX_PORT_BASE,
    SIM_PORT_OFFSET,
    VirtualFC,
    free_port_base,
    ports_in_use,
    scratch_workdir,
    uart_url,
)
from wftool.sitl.session import FSP_UART, Motion, VirtualFcSession
from wftool.sitl.truth import read_lateness


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def sitl_pids(port_base: int) -> list[int]:
    """The processes running a SITL with this port base (from their command lines)."""
    pids = []
    for entry in Path("/proc").iterdir():
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
        except (OSError, ValueError):
            continue
        if f"--port-base={port_base}".encode() in argv:
            pids.append(int(entry.name))
    return pids


def test_start_answers_msp_and_stop_leaves_no_process(sitl_binary: Path, tmp_path: Path) -> None:
    fc = VirtualFC(sitl_binary, tmp_path, port_base=None)
    with fc:
        assert fc._process is not None
        pid = fc._process.pid
        with MspClient.open(fc.url) as msp:
            assert msp.fc_variant() == "BTFL"
        assert (tmp_path / "eeprom.bin").exists()
    assert not fc.running
    assert not _alive(pid)
    assert f"bind port {fc.port_base + 1} for UART1".encode() in fc.log_path.read_bytes()
    assert not ports_in_use(fc.port_base)


def test_start_returns_with_uart1_let_go(
    sitl_binary: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Starting checks the loop over MSP on UART1; it returns once the FC has let go of that
    link, though the port's close does not wait for the FC (as after its 0.3 s on a loaded
    host): a client connecting at once is served, not dropped."""
    monkeypatch.setattr(transport, "RELEASE_TIMEOUT_S", 0.0)
    with VirtualFC(sitl_binary, tmp_path, port_base=None) as fc:
        log = fc.log_path.read_bytes()[fc.log_offset :]
        assert log.count(b"[NEW]UART1") == log.count(b"[CLS]UART1") == 2  # the probe, MSP


def test_stop_kills_a_process_that_ignores_sigterm(sitl_binary: Path, tmp_path: Path) -> None:
    fc = VirtualFC(sitl_binary, tmp_path, port_base=None)
    fc.start()
    assert fc._process is not None
    pid = fc._process.pid
    os.kill(pid, signal.SIGSTOP)  # a stopped process cannot act on SIGTERM
    fc.stop(grace=0.5)
    assert not _alive(pid)


def test_a_link_opened_right_after_one_closed_is_served(virtual_fc: VirtualFC) -> None:
    """A UART holds one client and drops a connection made before it let go of the last
    ("New connection on UART1, 1" in its log): closing a link waits for it to let go, so the
    next one, opened at once, is the one it serves."""
    offset = virtual_fc.log_path.stat().st_size

    def log() -> bytes:
        return virtual_fc.log_path.read_bytes()[offset:]

    for _ in range(20):
        with MspClient.open(virtual_fc.url) as msp:
            assert msp.pid_cycle_us() > 0
    assert wait_for(lambda: log().count(b"[CLS]UART1") == 20, timeout=5)
    assert (log().count(b"[NEW]UART1"), log().count(b"New connection on UART1, 1")) == (20, 0)


def test_wait_back_restarts_after_a_firmware_reset(virtual_fc: VirtualFC) -> None:
    with MspClient.open(virtual_fc.url) as msp:
        msp.reboot(RebootMode.FIRMWARE)
    virtual_fc.wait_back()
    assert virtual_fc.starts == 2
    with MspClient.open(virtual_fc.url) as msp:
        assert msp.api_version().major == 1
    assert b"[system]Reset!" in virtual_fc.log_path.read_bytes()


def test_wait_back_names_a_crash_instead_of_starting_again(virtual_fc: VirtualFC) -> None:
    """A reset ends SITL with status 0; any other end is a crash, not a reset to hide."""
    assert virtual_fc._process is not None
    os.kill(virtual_fc._process.pid, signal.SIGSEGV)
    with pytest.raises(SitlError, match="SIGSEGV"):
        virtual_fc.wait_back()
    assert not virtual_fc.running


@pytest.mark.parametrize("stage", ["_uart1_problem", "_loop_problem"])
@pytest.mark.parametrize("ending", [signal.SIGFPE, signal.SIGTERM])
def test_a_sitl_ending_while_it_starts_is_named_with_its_log(
    sitl_binary: Path,
    tmp_path: Path,
    stage: str,
    ending: signal.Signals,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The process ending while `start` waits for UART1 or for the PID loop over MSP — a
    crash (SIGFPE), or a `stop()` from another thread (SIGTERM) — is said as such: how it
    ended, and where its log is (not as the MSP client's lost peer, nor a bare assertion)."""
    fc = VirtualFC(sitl_binary, tmp_path, port_base=None)
    wait = getattr(VirtualFC, stage)

    def end_first(self: VirtualFC, *args: object) -> str:
        assert self._process is not None
        if ending == signal.SIGTERM:
            threading.Thread(target=self.stop).start()
        else:
            os.kill(self._process.pid, ending)
        return wait(self, *args)

    monkeypatch.setattr(VirtualFC, stage, end_first)
    with pytest.raises(SitlError) as error:
        fc.start()
    # a SIGFPE after SITL set up its crash report (sitl_crash.c) says who sent it
    said = {ending.name, f"{ending.name} (sent by pid {os.getpid()})"}
    assert str(error.value) in {f"SITL ended with {s} while starting: {fc.log_path}" for s in said}
    assert not fc.running


def test_a_simulator_sending_while_the_fc_boots_does_not_crash_it(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """A simulator that keeps sending across a reset (as `MotionFeeder` does over a CLI
    `save`) reaches SITL's simulator thread from the first instant of the next boot, before
    init() has created the virtual IMU. States this dense crashed most boots (SIGSEGV: a
    state written through the IMU's null device); `MotionFeeder`'s 40 Hz about one boot
    in 15 under load."""
    fc = VirtualFC(sitl_binary, tmp_path, port_base=free_port_base())
    stop = threading.Event()

    def simulator() -> None:
        state = Motion().state(0.0, 0.0)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            while not stop.wait(0.0002):
                sock.sendto(state, (LOOPBACK, fc.sim_state_port))

    sender = threading.Thread(target=simulator, daemon=True)
    sender.start()
    try:
        for _boot in range(6):
            fc.start()
            with MspClient.open(fc.url) as msp:
                assert msp.pid_cycle_us() > 0
            fc.stop()
    finally:
        stop.set()
        sender.join()
        fc.stop()


GDB = shutil.which("gdb")


@contextlib.contextmanager
def sitl_in_gdb(sitl_binary: Path, tmp_path: Path, script: str) -> Iterator[tuple[int, Path]]:
    """SITL on a free port base, run by gdb (batch) with `script`: (its port base, gdb's log
    with SITL's output); gdb and SITL are killed at the end."""
    base = free_port_base()
    script_path = tmp_path / "sitl.gdb"
    script_path.write_text(script)
    log = tmp_path / "gdb.log"
    with log.open("wb") as output:
        gdb = subprocess.Popen(
            [str(GDB), "-q", "-nx", "-batch", "-x", script_path, "--args", sitl_binary,
             f"--port-base={base}", f"--sim-port-base={base + SIM_PORT_OFFSET}",
             "--exit-with-parent"],
            cwd=tmp_path, stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:
        yield base, log
    finally:
        gdb.kill()
        gdb.wait()


@pytest.mark.skipif(GDB is None, reason="needs gdb (scripts/setup installs it)")
def test_a_crash_names_where_it_hit(virtual_fc: VirtualFC) -> None:
    """A fault in the running FC (gdb zeroes the PID loop denominator the gyro task divides
    by: an integer division by zero, as a bug would make) ends the SITL with SIGFPE, and the
    error names the fault and the functions on the stack from the SITL's own report: a crash
    once in hundreds of boots is found from the error alone."""
    assert virtual_fc._process is not None
    pid = virtual_fc._process.pid
    subprocess.run(
        [str(GDB), "-q", "-nx", "-batch", "-p", str(pid),
         "-ex", "set var *(unsigned char *)&activePidLoopDenom = 0", "-ex", "detach"],
        capture_output=True, check=True, timeout=60,
    )  # fmt: skip
    with pytest.raises(SitlError) as error:
        virtual_fc.wait_back()
    said = re.fullmatch(
        r"SITL ended with SIGFPE \(fault at \+0x[0-9a-f]+ \(thread \w+\) in (.+)\) "
        r"instead of resetting: (.+)",
        str(error.value),
    )
    assert said, str(error.value)
    stack = said.group(1).split(" < ")
    assert len(stack) >= 2 and "??" not in stack, stack
    assert said.group(2) == str(virtual_fc.log_path)


@pytest.mark.skipif(GDB is None, reason="needs gdb (scripts/setup installs it)")
@pytest.mark.skipif(platform.machine() != "x86_64", reason="the pause reads an x86-64 register")
def test_a_uart_takes_a_client_only_once_it_is_set_up(sitl_binary: Path, tmp_path: Path) -> None:
    """The FC paused (gdb, the main thread alone) as it announces that UART1 listens; a client
    connects and sends meanwhile, as one retrying while the FC restarts after a CLI `save`
    does. serTcpOpen() listened before it set up the port's RX buffer, and the TCP thread
    stored such bytes through a buffer of size 0: SIGFPE (about one boot in six with a client
    that sends the instant it can connect)."""
    base = free_port_base()
    script = tmp_path / "pause.gdb"
    script.write_text(
        "set pagination off\nset confirm off\nset non-stop on\nset breakpoint pending on\n"
        'break fprintf if $_streq((const char *)$rsi, "bind port %u for UART%u\\n")\n'
        "run\ndelete\necho paused\\n\n"
    )
    gdb = subprocess.Popen(
        [str(GDB), "-q", "-nx", "-x", script, "--args", sitl_binary, f"--port-base={base}",
         f"--sim-port-base={base + SIM_PORT_OFFSET}", "--exit-with-parent"],
        cwd=tmp_path, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
    assert gdb.stdin is not None and gdb.stdout is not None
    said = bytearray()

    def read(output: IO[bytes]) -> None:
        while chunk := os.read(output.fileno(), 4096):
            said.extend(chunk)

    reader = threading.Thread(target=read, args=(gdb.stdout,))
    reader.start()
    reply = b""
    try:
        assert wait_for(lambda: b"paused" in said, 30), said.decode(errors="replace")
        with socket.create_connection((LOOPBACK, base + 1), timeout=10) as client:
            client.sendall(encode_request(Cmd.STATUS))
            time.sleep(0.3)  # the TCP thread accepts and reads while the main thread waits
            gdb.stdin.write(b"continue -a\n")
            gdb.stdin.flush()
            with contextlib.suppress(OSError):
                reply = client.recv(4096)
        crash = re.findall(rb"received signal \w+", said) or [bytes(said[-300:])]
        assert reply.startswith(b"$X>"), f"no reply: {crash[-1].decode(errors='replace')}"
    finally:
        gdb.kill()
        gdb.wait()
        reader.join()


@pytest.mark.skipif(GDB is None, reason="needs gdb (scripts/setup installs it)")
@pytest.mark.skipif(platform.machine() != "x86_64", reason="the stall reads an x86-64 register")
def test_a_host_stall_before_lockstep_leaves_the_pid_loop_at_its_rate(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """The FC stopped (gdb) for 50 ms between its first gyro run and the start of lockstep
    (at its `prctl(PR_SET_TIMERSLACK)`), as a loaded host may: the scheduler, 400 gyro periods
    behind, recovered to a target between two gyro samples that the lockstep clock never
    reached, and the PID loop stalled (MSP PID cycle ~45 ms, about one start in 10-25 under
    load). It must run every gyro period."""
    script = (
        "set pagination off\nset confirm off\nbreak prctl if $rdi == 29\n"
        "commands\nsilent\nshell sleep 0.05\ndelete\ncontinue\nend\nrun\n"
    )
    with sitl_in_gdb(sitl_binary, tmp_path, script) as (base, log):
        assert wait_for(lambda: b"reason=start" in log.read_bytes(), 30), log.read_text()[-500:]
        with MspClient.open(uart_url(1, base)) as msp:
            cycles = set()
            for _ in range(20):
                cycles.add(msp.pid_cycle_us())
                time.sleep(0.05)
        assert cycles == {125}, f"PID cycles (us) after the stall: {sorted(cycles)}"


@pytest.mark.skipif(GDB is None, reason="needs gdb (scripts/setup installs it)")
def test_a_first_pass_that_runs_the_gyro_at_once_leaves_the_fc_running(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """The scheduler's first pass runs the gyro task at once, as after a host stall of a gyro
    period between schedulerInit() and that pass (gdb widens the pass's start window to make
    it so, then puts it back). The late-task statistics, due in that pass before any other
    task had run, divided by zero tasks run: SIGFPE, the log ending before the lockstep's
    start (about one boot in a few hundred under load)."""
    script = (
        "set pagination off\nset confirm off\nbreak scheduler\nrun\n"
        "set $window = *(int *)&schedLoopStartCycles\n"
        "set var *(int *)&schedLoopStartCycles = 1000000000\ncontinue\n"
        "set var *(int *)&schedLoopStartCycles = $window\ndelete\ncontinue\n"
    )
    with sitl_in_gdb(sitl_binary, tmp_path, script) as (base, log):
        wait_for(lambda: re.search(rb"reason=start|received signal", log.read_bytes()), 30)
        crash = re.findall(rb"received signal \w+", log.read_bytes())
        assert b"reason=start" in log.read_bytes() and not crash, (
            crash or [log.read_bytes()[-300:]]
        )[-1].decode()
        with MspClient.open(uart_url(1, base)) as msp:
            cycles: list[int] = []  # the first may span the stall gdb made: its own period
            settled = wait_for(lambda: cycles.append(msp.pid_cycle_us()) or cycles[-1] == 125, 5)
            cycles += [msp.pid_cycle_us() for _ in range(10)]  # and it runs on at it
        assert settled and cycles[-11:] == [125] * 11, f"PID cycles (us): {cycles}"


def test_the_sitl_says_how_late_the_host_ran_it(virtual_fc: VirtualFC) -> None:
    """Lateness totals from the first instant the clock waited for (patch 0014)."""
    assert wait_for(lambda: read_lateness(virtual_fc.log_path), 5)
    first = read_lateness(virtual_fc.log_path)[0]
    assert first.waits >= 1 and first.max_us >= 0


def test_two_virtual_fcs_run_side_by_side(
    virtual_fc: VirtualFC, sitl_binary: Path, tmp_path: Path
) -> None:
    with VirtualFC(sitl_binary, tmp_path / "b", port_base=None) as other:
        assert other.port_base != virtual_fc.port_base
        for fc in (virtual_fc, other):
            with MspClient.open(fc.url) as msp:
                assert msp.pid_cycle_us() > 0  # each runs its own flight loop


def test_a_second_sitl_on_the_same_ports_is_refused_naming_the_port(
    virtual_fc: VirtualFC, sitl_binary: Path, tmp_path: Path
) -> None:
    second = VirtualFC(sitl_binary, tmp_path / "b", port_base=virtual_fc.port_base)
    with pytest.raises(PortInUseError, match=f"TCP {virtual_fc.port_base + 1} is in use"):
        second.start()
    assert not second.running


@pytest.mark.parametrize("kind", [socket.SOCK_STREAM, socket.SOCK_DGRAM])
def test_a_port_another_program_holds_is_named(
    sitl_binary: Path, tmp_path: Path, kind: socket.SocketKind
) -> None:
    base = free_port_base()
    port = base + 2 if kind == socket.SOCK_STREAM else base + SIM_PORT_OFFSET + 3
    with socket.socket(socket.AF_INET, kind) as holder:
        holder.bind((LOOPBACK, port))
        name = "TCP" if kind == socket.SOCK_STREAM else "UDP"
        with pytest.raises(PortInUseError, match=f"^{name} {port} is in use"):
            VirtualFC(sitl_binary, tmp_path, port_base=base).start()
    assert not sitl_pids(base)


def test_ports_taken_after_they_were_found_free_are_traded_for_others(
    sitl_binary: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`port_base=None`: a program that takes one of the chosen ports before the SITL binds
    it (a race with another test run) costs a second choice, not a failed start."""
    import wftool.sitl.process as process

    first, second = free_port_base(), free_port_base(start=60000, stop=64000)
    choices = iter([first, second])
    monkeypatch.setattr(process, "free_port_base", lambda: next(choices))
    with socket.socket() as holder:
        # as servers do (and SITL): an earlier test's TIME_WAIT on the port does not count
        holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        holder.bind((LOOPBACK, first + 1))
        holder.listen()
        with VirtualFC(sitl_binary, tmp_path, port_base=None) as fc:
            assert fc.port_base == second
            with MspClient.open(fc.url) as msp:
                assert msp.pid_cycle_us() > 0


def test_missing_binary_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(SitlError, match="cannot run SITL binary"):
        VirtualFC(tmp_path / "nope", tmp_path, port_base=None).start()


def test_a_scratch_workdir_goes_after_a_clean_run_and_stays_after_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with scratch_workdir(None, "wftool-sitl-") as clean:
        (clean / "sitl.log").write_text("ran")
    with pytest.raises(SitlError), scratch_workdir(None, "wftool-sitl-") as failed:
        (failed / "sitl.log").write_text("crashed")
        raise SitlError(f"see {failed / 'sitl.log'}")
    given = tmp_path / "given"
    given.mkdir()
    with scratch_workdir(given, "wftool-sitl-") as used:
        (used / "eeprom.bin").write_bytes(b"kept")
    assert clean.parent == failed.parent == tmp_path and not clean.exists()
    assert (failed / "sitl.log").read_text() == "crashed"
    assert used == given and (given / "eeprom.bin").read_bytes() == b"kept"


@pytest.mark.parametrize("pid", [1, 4242, 65521, 99991])
def test_port_bases_are_chosen_where_every_port_exists(
    pid: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Whatever the pseudo-random start, a base near the top leaves room for the UDP ports
    (a base of 63700 made `ports_in_use` raise OverflowError); defaults stay below Linux's
    ephemeral range."""
    monkeypatch.setattr(os, "getpid", lambda: pid)
    assert free_port_base(start=60000, stop=65536) <= MAX_PORT_BASE
    assert free_port_base() < 32768


def test_uart_urls_follow_the_port_base() -> None:
    assert uart_url(1) == "socket://127.0.0.1:5761"
    assert uart_url(2, 20000) == "socket://127.0.0.1:20002"
    assert VirtualFC(Path("sitl"), Path("."), port_base=30000).uart_url(2) == uart_url(2, 30000)


@pytest.fixture
def wftool_sitl(sitl_binary: Path, tmp_path: Path) -> Iterator[tuple[subprocess.Popen, int]]:
    """`wftool sitl` running in its own process on any free ports, with the SITL it started
    up and configured: (the wftool process, the port base it took)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "wftool", "sitl", "--binary", str(sitl_binary),
         "--workdir", str(tmp_path), "--port-base", "0", "--no-motion"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        # as from a terminal: a shell's background job (CI) would start it with SIGINT ignored
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    base = 0
    try:
        assert process.stderr is not None
        said = []
        for line in process.stderr:  # configured and serving: "running; Ctrl-C stops it"
            said.append(line)
            if match := re.search(r"MSP/CLI\s+socket://127.0.0.1:(\d+)", line):
                base = int(match.group(1)) - 1
            if line.startswith("running"):
                break
        assert base and sitl_pids(base), "".join(said)
        yield process, base
    finally:
        process.kill()
        process.wait()
        for pid in sitl_pids(base) if base else []:
            os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT, signal.SIGKILL])
def test_the_sitl_ends_with_wftool_however_wftool_ends(
    wftool_sitl: tuple[subprocess.Popen, int], sig: signal.Signals
) -> None:
    """Ctrl-C, SIGTERM and SIGHUP unwind wftool, which stops the SITL; SIGKILL (a crash)
    cannot be caught, and the SITL ends by its parent-death signal."""
    process, base = wftool_sitl
    process.send_signal(sig)
    code = process.wait(30)
    assert wait_for(lambda: not sitl_pids(base), 15), "the SITL outlived wftool"
    assert wait_for(lambda: not ports_in_use(base), 5)
    # Ctrl-C is how `wftool sitl` is meant to stop: that is a success
    expected = {signal.SIGINT: 0, signal.SIGKILL: -signal.SIGKILL}.get(sig, 128 + sig)
    assert code == expected


@pytest.mark.skipif(GDB is None, reason="needs gdb (scripts/setup installs it)")
@pytest.mark.skipif(platform.machine() != "x86_64", reason="the break reads an x86-64 register")
def test_a_late_first_gyro_run_leaves_every_frame_on_the_gyro_grid(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """The boot's first gyro run 70 us after the scheduler's target, as a loaded host may run
    it (gdb moves the target as the lockstep clock starts, at its `prctl(PR_SET_TIMERSLACK)`),
    an FSP client connected before that: every frame of the first second is one lockstep
    interval after the one before. A clock started on that run rather than on the target ran
    the PID loop early at task steps that fell between a target and its sample (frames ~20 us
    early, 22 us in a full run). Whether a task's step falls there depends on the boot: the
    old clock failed this test in 2 of 11 boots (targets moved 10-110 us)."""
    with VirtualFcSession(sitl_binary, tmp_path, port_base=None) as session:
        rate_hz = session.rate_hz  # configured and saved: eeprom.bin in tmp_path
    stopped, go = tmp_path / "stopped", tmp_path / "go"
    # the scheduler's gyro target (a static: LTO names it lastTargetCycles.lto_priv.N) moved
    # 70 us (35,000 cycles at SITL's 500 MHz) before the run, as if the run came that late
    script = (
        "set pagination off\nset confirm off\nbreak prctl if $rdi == 29\n"
        "commands\nsilent\npython\nimport re\n"
        'said = gdb.execute("info variables ^lastTargetCycles", to_string=True)\n'
        'target = re.search(r"lastTargetCycles[.\\w]*$", said, re.M).group(0)\n'
        "gdb.execute(f\"set var *(unsigned int *)&'{target}' -= 35000\")\nend\n"
        f"shell touch {stopped}; while [ ! -e {go} ]; do sleep 0.01; done\n"
        "delete\ncontinue\nend\nrun\n"
    )
    with sitl_in_gdb(sitl_binary, tmp_path, script) as (base, log):
        assert wait_for(stopped.exists, 30), log.read_text()[-500:]
        with FspReader(uart_url(FSP_UART, base)) as reader:
            go.touch()
            packets: list[StatePacket] = []
            assert wait_for(lambda: packets.extend(reader.read(0.05)) or len(packets) > 1000, 30)
        with MspClient.open(uart_url(1, base)) as msp:
            looptime_us = msp.pid_looptime_us()
    times = [frame.time_us for p in packets for frame in p.frames]
    period = lockstep_interval(rate_hz, looptime_us) * looptime_us
    off = [(a, b) for a, b in pairwise(times) if b - a != period]
    assert not off, f"frames not {period} us apart: {off[:5]}"
