"""A crashed SITL's own report, read from its log and named from the binary's symbols."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from wftool.sitl.crash import crash_report

LIBC = b"/lib/x86_64-linux-gnu/libc.so.6"


def report(said: bytes, frames: list[bytes]) -> bytes:
    """A log ending with a report as sitl_crash.c writes it."""
    body = b"".join(frame + b"\n" for frame in frames)
    head = b"bind port 5761 for UART1\n[SITL] fatal SIGFPE: " + said + b"\n"
    return head + body + b"[SITL] end of fatal report\n"


def frame(module: bytes, offset: int) -> bytes:
    return module + b"(+" + hex(offset).encode() + b")[0x55d0c2a00000]"


def test_a_log_without_a_report_says_nothing() -> None:
    assert crash_report(b"bind port 5761 for UART1\n", Path("sitl")) == ""


def test_a_signal_from_another_process_names_it() -> None:
    assert crash_report(report(b"sent by pid 42", []), Path("sitl")) == "sent by pid 42"


def test_without_symbols_the_fault_is_said_as_reported(tmp_path: Path) -> None:
    log = report(
        b"fault at +0x28ede (thread betaflight_SITL)",
        [frame(b"./sitl", 0xCDB2), frame(LIBC, 0x3C050), frame(b"./sitl", 0x28EDE)],
    )
    assert crash_report(log, tmp_path / "gone") == "fault at +0x28ede (thread betaflight_SITL)"


def test_the_stack_is_named_from_the_fault_outwards(sitl_binary: Path) -> None:
    """Past the handler's frame and the C library's trampoline: the faulting instruction, then
    each caller's return address (a byte past its call), up to four."""
    if shutil.which("nm") is None or shutil.which("addr2line") is None:
        pytest.skip("needs binutils (nm, addr2line)")
    symbols = {}
    for line in subprocess.run(
        ["nm", "--defined-only", str(sitl_binary)], capture_output=True, text=True, check=True
    ).stdout.splitlines():
        address, kind, name = line.split()[:3]
        if kind in "Tt":
            symbols[name] = int(address, 16)
    binary = bytes(sitl_binary)
    frames = [frame(binary, symbols["main"] + 3), frame(LIBC, 0x3C050)]  # the handler's, libc's
    frames += [frame(binary, symbols[name] + 1) for name in ("scheduler", "main")]  # returns
    frames += [frame(LIBC, 0x2724A), frame(binary, symbols["scheduler"] + 8)]  # the loader's
    said = crash_report(report(b"fault at +0x10 (thread betaflight_SITL)", frames), sitl_binary)
    assert said == "fault at +0x10 (thread betaflight_SITL) in scheduler < main"
