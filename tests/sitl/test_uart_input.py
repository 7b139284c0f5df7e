"""The virtual FC takes its UARTs' input in its own loop, in FC time: with every other thread
of the SITL stopped, an OBC's commands still reach the FC as they come (0.5–1.8 ms after they
were sent, here), judged against the SITL's true clock (`TrueClock`, the lockstep anchors)."""

from __future__ import annotations

import ctypes
import functools
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from tests.sitl.fresh import send_fresh
from wftool.fsp import FspReader, StateDecoder
from wftool.sitl.session import VirtualFcSession
from wftool.sitl.truth import TrueClock

COMMAND = (1500, 1500, 1500, 1000, 1000, 1000)
STOPPED_S = 0.5
"""How long the SITL's other threads are stopped: ten times a 50 ms command timeout."""
MEASURED = 40
"""Commands sent one at a time, each once the FC answered the one before."""
JUDGED_MIN = 5
"""Commands sent while the threads were stopped, at least."""
TAKEN_S = STOPPED_S / 2
"""The FC takes a command sooner than this after it was sent: none waited for the stopped
threads (the loop reads its sockets every millisecond of FC time, and the FSP task runs every
millisecond; the bound leaves the test's own host room to be late writing a command it has
stamped)."""

_PTRACE_DETACH = 17
_PTRACE_SEIZE = 0x4206
_PTRACE_INTERRUPT = 0x4207
_WALL = 0x40000000
_SETTLE_S = 0.001


@functools.cache
def _libc() -> ctypes.CDLL:
    libc = ctypes.CDLL(None, use_errno=True)
    libc.ptrace.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p]
    return libc


def _ptrace(request: int, tid: int) -> int:
    return int(_libc().ptrace(request, tid, None, None))


def _in_syscall(pid: int, tid: int) -> bool:
    """Whether the stopped thread `tid` is blocked in a system call (so holds no lock the loop
    could wait for: the SITL's threads take theirs between calls)."""
    fields = Path(f"/proc/{pid}/task/{tid}/syscall").read_text().split()
    return fields[0] not in ("running", "-1")


@contextmanager
def other_threads_stopped(pid: int, seconds: float) -> Iterator[threading.Event]:
    """Stop every thread of process `pid` but its first (the FC's loop) for `seconds`, each
    while blocked in a system call, as a host that does not get to run them would; the event
    is set once they are all stopped. ptrace: the thread that stops them lets them go."""
    stopped = threading.Event()
    failure: list[str] = []

    def stop_then_resume() -> None:
        held: list[int] = []
        try:
            for tid in sorted(int(t) for t in os.listdir(f"/proc/{pid}/task")):
                if tid == pid:
                    continue
                if _ptrace(_PTRACE_SEIZE, tid) != 0:
                    failure.append(f"ptrace seize {tid}: errno {ctypes.get_errno()}")
                    return
                held.append(tid)
                while True:
                    _ptrace(_PTRACE_INTERRUPT, tid)
                    os.waitpid(tid, _WALL)
                    if _in_syscall(pid, tid):
                        break
                    _ptrace(_PTRACE_DETACH, tid)  # mid-work: let it go a moment
                    time.sleep(_SETTLE_S)
                    _ptrace(_PTRACE_SEIZE, tid)
            stopped.set()
            time.sleep(seconds)
        finally:
            for tid in held:
                _ptrace(_PTRACE_DETACH, tid)
            stopped.set()

    stopper = threading.Thread(target=stop_then_resume, name="thread-stopper")
    stopper.start()
    try:
        stopped.wait()
        assert not failure, failure
        yield stopped
    finally:
        stopper.join()


def test_the_fc_takes_uart_input_with_its_other_threads_stopped(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """The host runs no thread of the SITL but its loop for STOPPED_S while an OBC sends
    commands, one at a time: the FC takes each within TAKEN_S of its sending, by its true
    clock (upstream's TCP thread, which read the UARTs, would have held them until it ran
    again: the stop). Commands whose round trip spans a re-anchoring of the FC's clock (the
    host held up the loop itself) are not judged; at least JUDGED_MIN sent while stopped
    are."""
    session = VirtualFcSession(sitl_binary, tmp_path, port_base=None, time_reply=True)
    decoder = StateDecoder(time_replies=True)
    with session, FspReader(session.fsp_url, decoder=decoder) as reader:
        process = session.fc._process
        assert process is not None
        with other_threads_stopped(process.pid, STOPPED_S):
            start = time.monotonic()
            fates = send_fresh(reader, COMMAND, MEASURED)
        end = start + STOPPED_S
        truth = TrueClock(session.fc.log_path)
    stepped = [a.monotonic_ns * 1e-9 for a in truth.anchors if a.reason != "start"]
    judged = [t for t in fates.trips if not any(t.obc_sent <= s <= t.obc_received for s in stepped)]
    late_ms = [(truth.instant(t.fc_received_us, t.obc_received) - t.obc_sent) * 1e3 for t in judged]
    assert max(late_ms) <= TAKEN_S * 1e3, f"taken this many ms after sending: {late_ms}"
    while_stopped = sum(t.obc_sent < end for t in judged)
    assert while_stopped >= JUDGED_MIN, f"{while_stopped} judged of {len(fates.trips)}: {stepped}"
