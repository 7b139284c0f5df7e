"""The dfu-util backend: find the STM32 ROM bootloader, write, read back, leave.

Output formats are those of dfu-util 0.11 (`dfuse.c`, `main.c`): listing lines
`Found DFU: [0483:df11] ver=…, path="1-1", alt=0, name="@Internal Flash  /0x08000000/…",
serial="…"`, progress `Download\t[====    ]  50%        12345 bytes` (updated with `\\r`),
`File downloaded successfully`, errors prefixed `dfu-util: ` with exit status 74 (EX_IOERR)
or 76 (EX_PROTOCOL), and a failed request's `DFU state(10) = dfuERROR, status(3) = …`.

A raw DfuSe download (`-s ADDRESS -D FILE`) erases each page it touches, then writes it in
2048-byte blocks; an upload (`-s ADDRESS:LENGTH -U FILE`) reads it back. Leaving is its own
command (`-s ADDRESS:leave`): the bootloader jumps to ADDRESS, which must hold the image's
vector table (ST AN3156). Some STM32 ROMs reset before answering the leave request's status
request; dfu-util then ends with `Error during download get_status` — reported, not raised:
the flasher confirms the flash by talking to the firmware that comes up.
"""

from __future__ import annotations

import re
import subprocess
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import FlashError
from wftool.flash.backend import Device, FlashBackend, Progress
from wftool.flash.image import FlashLayout
from wftool.link.transport import STM32_DFU, UsbId

DFU_UTIL: tuple[str, ...] = ("dfu-util",)
"""How dfu-util is run (the flash tests run the real one under umockdev's wrapper)."""
NO_DEVICE_HINT = (
    "hold the board's BOOT button while plugging in USB to force the bootloader; if "
    "`lsusb` shows 0483:df11 but dfu-util does not, install the udev rules "
    "(`sudo wftool doctor --fix`)"
)
LEAVE_STATUS_ERROR = "dfu-util: Error during download get_status"

_FOUND = re.compile(
    r'Found DFU: \[([0-9a-f]{4}):([0-9a-f]{4})\].*?path="([^"]*)", alt=(\d+), '
    r'name="([^"]*)", serial="([^"]*)"'
)
_PROGRESS = re.compile(r"^(Erase|Download|Upload)\s*\[[= ]*\]\s*(\d+)%\s+(\d+) bytes")


@dataclass(frozen=True)
class DfuDevice:
    """One alternate setting of a DFU device, as `dfu-util -l` lists it."""

    usb_id: UsbId
    path: str
    alt: int
    name: str
    serial: str

    @property
    def layout(self) -> FlashLayout | None:
        return FlashLayout.from_dfuse_name(self.name)

    def options(self) -> list[str]:
        """dfu-util's options that select this device and alternate setting."""
        return ["-d", str(self.usb_id), "-p", self.path, "-a", str(self.alt)]


def _run(
    args: Sequence[str], progress: Progress | None = None, timeout: float | None = None
) -> tuple[int, list[str]]:
    """Run dfu-util: its exit status and output lines (progress updates reported, not kept).
    A run longer than `timeout` s is killed (`FlashError`)."""
    try:
        process = subprocess.Popen(
            [*DFU_UTIL, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT
        )
    except FileNotFoundError as exc:
        raise FlashError(
            "dfu-util is not installed (Debian/Ubuntu: apt install dfu-util); see `wftool doctor`"
        ) from exc
    assert process.stdout is not None
    hung = threading.Event()

    def kill() -> None:
        hung.set()
        process.kill()

    watchdog = threading.Timer(timeout, kill) if timeout else None
    if watchdog:
        watchdog.start()
    lines: list[str] = []
    pending = b""
    try:
        while chunk := process.stdout.read1(4096):
            *complete, pending = re.split(rb"[\r\n]", pending + chunk)
            for raw in complete:
                line = raw.decode("ascii", "replace").strip()
                if match := _PROGRESS.match(line):
                    if progress:
                        progress(match[1], int(match[2]), int(match[3]))
                    line = line[match.end() :].strip()  # stderr may follow on the same line
                if line:
                    lines.append(line)
    finally:
        status = process.wait()
        process.stdout.close()
        if watchdog:
            watchdog.cancel()
    if pending.strip():
        lines.append(pending.decode("ascii", "replace").strip())
    if hung.is_set():
        raise FlashError(f"`dfu-util {' '.join(args)}` hung for {timeout:.0f} s")
    return status, lines


def _errors(lines: list[str]) -> list[str]:
    """dfu-util's error lines (its warnings about DFU suffixes are none)."""
    return [
        line
        for line in lines
        if line.startswith("DFU state(10)")
        or (line.startswith("dfu-util: ") and "suffix" not in line)
    ]


def _failure(what: str, status: int, lines: list[str]) -> FlashError:
    """dfu-util's own words on why WHAT failed, in one line."""
    reason = "; ".join(_errors(lines)[-2:]) or (lines[-1] if lines else "no output")
    return FlashError(f"dfu-util failed {what} (exit {status}): {reason}")


def list_devices(usb_id: UsbId = STM32_DFU) -> list[DfuDevice]:
    """Alternate settings of attached DFU devices with `usb_id`."""
    _status, lines = _run(["-l"], timeout=20)
    output = "\n".join(lines)
    if "LIBUSB_ERROR_ACCESS" in output and str(usb_id) in output:
        raise FlashError(
            f"a DFU device {usb_id} is attached but this user may not open it "
            "(LIBUSB_ERROR_ACCESS): install the udev rules with `sudo wftool doctor --fix`"
        )
    devices = []
    for match in _FOUND.finditer(output):
        found = UsbId(int(match[1], 16), int(match[2], 16))
        if found == usb_id:
            devices.append(DfuDevice(found, match[3], int(match[4]), match[5], match[6]))
    return devices


def wait_for_device(
    timeout: float, usb_id: UsbId = STM32_DFU, poll_interval: float = 0.5
) -> DfuDevice:
    """Poll `dfu-util -l` until the bootloader's internal flash (alt 0) shows up."""
    deadline = time.monotonic() + timeout
    while True:
        flash = [device for device in list_devices(usb_id) if device.alt == 0]
        if len({device.path for device in flash}) > 1:
            paths = ", ".join(device.path for device in flash)
            raise FlashError(f"several DFU devices {usb_id} attached ({paths}); keep only one")
        if flash:
            return flash[0]
        if time.monotonic() > deadline:
            raise FlashError(
                f"no DFU device {usb_id} appeared within {timeout:.0f} s: {NO_DEVICE_HINT}"
            )
        time.sleep(poll_interval)


def download(
    device: DfuDevice,
    address: int,
    image_file: Path,
    *,
    mass_erase: bool = False,
    progress: Progress | None = None,
) -> None:
    """Write `image_file` at `address` (a raw DfuSe download: erases the pages it touches,
    or, with `mass_erase`, the whole flash first)."""
    modifiers = [f"0x{address:08x}", *(["mass-erase", "force"] if mass_erase else [])]
    status, lines = _run(
        [*device.options(), "-s", ":".join(modifiers), "-D", str(image_file)], progress
    )
    if status != 0 or "File downloaded successfully" not in lines:
        error = _failure(f"writing at 0x{address:08x}", status, lines)
        if all(found.path != device.path for found in list_devices(device.usb_id)):
            error = FlashError(f"{error}; the board left USB (unplugged, or reset?)")
        raise error


def upload(
    device: DfuDevice, address: int, length: int, *, progress: Progress | None = None
) -> bytes:
    """Read `length` bytes at `address`."""
    with tempfile.TemporaryDirectory(prefix="wftool-dfu-") as scratch:
        readback = Path(scratch) / "readback.bin"  # dfu-util refuses to overwrite a file
        status, lines = _run(
            [*device.options(), "-s", f"0x{address:08x}:{length}", "-U", str(readback)],
            progress,
        )
        data = readback.read_bytes() if readback.exists() else b""
    if status != 0 or len(data) != length:
        if status == 0:
            lines.append(f"read {len(data)} of {length} bytes")
        raise _failure(f"reading back 0x{address:08x}", status, lines)
    return data


def leave(device: DfuDevice, address: int) -> str | None:
    """Leave the bootloader: it jumps to `address` (the image's vector table). Returns a
    remark when the ROM reset before answering the leave request."""
    status, lines = _run([*device.options(), "-s", f"0x{address:08x}:leave"])
    if "Submitting leave request..." in lines:
        if status == 0:
            return None
        if _errors(lines) == [LEAVE_STATUS_ERROR]:
            return "the bootloader reset before answering the leave request, as some STM32 ROMs do"
    raise _failure(f"leaving the bootloader for 0x{address:08x}", status, lines)


class DfuBackend(FlashBackend):
    """dfu-util and the STM32 ROM bootloader (DfuSe)."""

    def wait_for_device(self, timeout: float) -> DfuDevice:
        return wait_for_device(timeout)

    def write(
        self,
        device: Device,
        address: int,
        data: bytes,
        *,
        mass_erase: bool = False,
        progress: Progress | None = None,
    ) -> None:
        assert isinstance(device, DfuDevice)
        with tempfile.TemporaryDirectory(prefix="wftool-dfu-") as scratch:
            region = Path(scratch) / f"0x{address:08x}.bin"
            region.write_bytes(data)
            download(device, address, region, mass_erase=mass_erase, progress=progress)

    def read(
        self, device: Device, address: int, length: int, *, progress: Progress | None = None
    ) -> bytes:
        assert isinstance(device, DfuDevice)
        return upload(device, address, length, progress=progress)

    def leave(self, device: Device, address: int) -> str | None:
        assert isinstance(device, DfuDevice)
        return leave(device, address)
