"""Handle on the EMULATED STM32F722 bootloader (dfuse_device.py) in its umockdev host
process (usbfs_host.py): attach it, inject faults, read its flash, and the command prefix
that runs the real dfu-util against it. Test scaffolding.

The host runs under the system Python, which has PyGObject and the UMockdev typelib
(Debian: python3-gi, gir1.2-umockdev-1.0); the tests run in the project's venv, which
does not. dfu-util runs under `umockdev-wrapper` (LD_PRELOAD of libumockdev-preload) with
UMOCKDEV_DIR naming the host's testbed; nothing else in the test process is preloaded.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
SYSTEM_PYTHON = "/usr/bin/python3"
"""Where Debian's python3-gi and the UMockdev typelib are importable."""
PACKAGES = "umockdev gir1.2-umockdev-1.0 python3-gi dfu-util"
FLASH_BASE = 0x0800_0000
FLASH_SIZE = 512 << 10


def unavailable() -> str | None:
    """Why the emulation cannot run here (one line), or None."""
    for tool in ("umockdev-wrapper", "dfu-util"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (apt install {PACKAGES}; scripts/setup does)"
    probe = subprocess.run(
        [SYSTEM_PYTHON, "-c", "import gi; gi.require_version('UMockdev', '1.0')"],
        capture_output=True,
        check=False,
    )
    if probe.returncode != 0:
        return f"{SYSTEM_PYTHON} cannot import UMockdev through gi (apt install {PACKAGES})"
    mounts = Path("/proc/mounts").read_text().split("\n")
    if not any(line.split()[1:3] == ["/sys", "sysfs"] for line in mounts if line.strip()):
        return "/sys is not sysfs here, and libusb under umockdev needs it to be"
    return None


class EmulatorError(RuntimeError):
    """The host process refused a command or died."""


@dataclass(frozen=True)
class Left:
    """How the bootloader left the bus (dfuse_device.Leave)."""

    address: int
    jumped: bool
    vector_table: int
    runs: bool


class EmulatedBootloader:
    """The emulated bootloader in its host process; `close()` (or `with`) ends it."""

    def __init__(self, log_path: Path) -> None:
        self.log_path = log_path
        self._log = log_path.open("ab")
        self._process = subprocess.Popen(
            [SYSTEM_PYTHON, "-m", "tests.flash.usbfs_host"],
            cwd=REPO,
            env={**os.environ, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1"},
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._log,
            text=True,
        )
        try:
            self.root = str(self._reply()["root"])
        except BaseException:
            self._process.kill()
            self._process.wait()
            self._log.close()
            raise
        self.dfu_util = ("env", f"UMOCKDEV_DIR={self.root}", "umockdev-wrapper", "dfu-util")
        """The real dfu-util, run against this emulated device."""

    def _reply(self) -> dict[str, Any]:
        assert self._process.stdout is not None
        line = self._process.stdout.readline()
        if not line:
            raise EmulatorError(f"the umockdev host died; see {self.log_path}")
        reply: dict[str, Any] = json.loads(line)
        if "error" in reply:
            raise EmulatorError(reply["error"])
        return reply

    def command(self, op: str, **arguments: Any) -> dict[str, Any]:
        assert self._process.stdin is not None
        self._process.stdin.write(json.dumps({"op": op, **arguments}) + "\n")
        self._process.stdin.flush()
        return self._reply()

    def attach(self) -> None:
        """The board enters its ROM bootloader: the device appears on the bus."""
        self.command("attach")

    def detach(self) -> None:
        """The device leaves the bus (unplugged)."""
        self.command("detach")

    def inject(self, **faults: Any) -> None:
        """Faults from now on (dfuse_device.Faults fields); none given: no faults."""
        self.command("faults", **faults)

    def configure(self, **settings: Any) -> None:
        """serial=, time_scale=, read_protected=."""
        self.command("configure", **settings)

    def load(self, flash: bytes) -> None:
        """Set the whole flash (what the board held before)."""
        assert len(flash) == FLASH_SIZE
        self.command("load", flash=base64.b64encode(flash).decode())

    def flash(self) -> bytes:
        return base64.b64decode(self.command("flash")["flash"])

    def status(self) -> dict[str, Any]:
        return self.command("status")

    @property
    def attached(self) -> bool:
        return bool(self.status()["attached"])

    def events(self, kind: str | None = None) -> list[list[Any]]:
        events = self.status()["events"]
        return [event for event in events if kind is None or event[0] == kind]

    def left(self) -> Left | None:
        left = self.status()["left"]
        return Left(**left) if left else None

    def wait_left(self, timeout: float) -> Left | None:
        deadline = time.monotonic() + timeout
        while (left := self.left()) is None and time.monotonic() < deadline:
            time.sleep(0.05)
        return left

    def close(self) -> None:
        if self._process.poll() is None:
            assert self._process.stdin is not None
            self._process.stdin.close()
            try:
                status = self._process.wait(5)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
            else:  # a host that crashed as it ended (a fatal GLib error) is seen here
                assert status == 0, f"the USB host ended with status {status}: {self.log_path}"
        assert self._process.stdout is not None
        self._process.stdout.close()
        self._log.close()
        shutil.rmtree(self.root, ignore_errors=True)  # if the host could not

    def __enter__(self) -> EmulatedBootloader:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
