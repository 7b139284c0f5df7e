"""A crashed SITL's own report (sitl_crash.c): which signal, where it hit, the stack's functions."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

_REPORT = re.compile(rb"\[SITL\] fatal \w+: ([^\n]*)\n(.*?)\[SITL\] end of fatal report", re.S)
_FRAME = re.compile(rb"^(\S*)\(\+0x([0-9a-f]+)\)\[", re.M)
STACK_DEPTH = 4
"""Functions named, innermost first."""


def crash_report(log: bytes, binary: Path) -> str:
    """What the SITL said of the fatal signal that ended it, from its `log`: "sent by pid 42",
    or "fault at +0x28ede (thread betaflight_SITL) in taskGyroSample < scheduler < main" (the
    functions from `binary`'s symbols, where binutils' addr2line is installed); "" if none."""
    match = _REPORT.search(log)
    if match is None:
        return ""
    said, stack = match.group(1).decode(errors="replace"), match.group(2)
    frames = _FRAME.findall(stack)
    # the handler's own frame, then the C library's signal trampoline, then where it hit
    trampoline = next((i for i, (module, _) in enumerate(frames) if module != frames[0][0]), None)
    if trampoline is None:
        return said
    offsets: list[int] = []
    for module, offset in frames[trampoline + 1 :]:
        if module != frames[0][0] or len(offsets) == STACK_DEPTH:
            break  # on into the C library's start: the firmware's stack ends at main
        offsets.append(int(offset, 16))
    names = _function_names(binary, offsets)
    return f"{said} in {' < '.join(names)}" if names else said


def _function_names(binary: Path, offsets: list[int]) -> list[str]:
    """The functions of `binary` at `offsets`, [] without addr2line."""
    addr2line = shutil.which("addr2line")
    if addr2line is None or not offsets:
        return []
    # a caller's frame holds its return address, just past the call: the call is a byte before
    addresses = [hex(offset if i == 0 else offset - 1) for i, offset in enumerate(offsets)]
    try:
        result = subprocess.run(
            [addr2line, "-f", "-e", str(binary), *addresses],
            capture_output=True, text=True, check=True, timeout=10,
        )  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return []
    return result.stdout.splitlines()[0::2]  # a function's name, then its file:line
