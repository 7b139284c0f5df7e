"""The dfu-util backend: find the STM32 ROM bootloader, write regions to it.

Output formats are those of dfu-util 0.11 (the strings in its binary): listing lines
`Found DFU: [0483:df11] ver=…, path="1-1", alt=0, name="@Internal Flash  /0x08000000/…",
serial="…"`, progress `Download\t[====    ]  50%        12345 bytes` (updated with `\\r`),
`File downloaded successfully`, and errors prefixed `dfu-util: ` with exit status 74.
After a `:leave` download the board resets before dfu-util's final status request, which
then fails with `Error during download get_status`; that is reported, not raised — the
caller confirms the flash by talking to the firmware that comes up.
"""

from __future__ import annotations

import re
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import FlashError
from wftool.flash.backend import Device, FlashBackend, Progress
from wftool.flash.image import FlashLayout
from wftool.link.transport import STM32_DFU, UsbId

DFU_UTIL = "dfu-util"
NO_DEVICE_HINT = (
    "hold the board's BOOT button while plugging in USB to force the bootloader; if "
    "`lsusb` shows 0483:df11 but dfu-util does not, install the udev rules "
    "(`sudo wftool doctor --fix`)"
)

_FOUND = re.compile(
    r'Found DFU: \[([0-9a-f]{4}):([0-9a-f]{4})\].*?path="([^"]*)", alt=(\d+), '
    r'name="([^"]*)", serial="([^"]*)"'
)
_PROGRESS = re.compile(r"^(Erase|Download)\s*\[[= ]*\]\s*(\d+)%\s+(\d+) bytes")


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


@dataclass(frozen=True)
class DownloadResult:
    status_error_after_leave: bool
    """dfu-util ended with the expected post-`:leave` get_status error."""


def _run(args: list[str], timeout: float) -> str:
    try:
        result = subprocess.run(
            [DFU_UTIL, *args],
            capture_output=True,
            text=True,
            errors="replace",
            timeout=timeout,
            check=False,
        )
    except FileNotFoundError as exc:
        raise FlashError(
            "dfu-util is not installed (Debian/Ubuntu: apt install dfu-util); see `wftool doctor`"
        ) from exc
    except subprocess.TimeoutExpired as exc:
        raise FlashError(f"`dfu-util {' '.join(args)}` hung for {timeout:.0f} s") from exc
    return result.stdout + result.stderr


def list_devices(usb_id: UsbId = STM32_DFU) -> list[DfuDevice]:
    """Alternate settings of attached DFU devices with `usb_id`."""
    output = _run(["-l"], timeout=20)
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
    leave: bool,
    mass_erase: bool = False,
    progress: Progress | None = None,
) -> DownloadResult:
    """Write `image_file` at `address` (DfuSe raw download). `:leave` starts the firmware."""
    modifiers = [f"0x{address:08x}"]
    modifiers += ["mass-erase", "force"] if mass_erase else []
    modifiers += ["leave"] if leave else []
    command = [
        DFU_UTIL, "-d", str(device.usb_id), "-p", device.path, "-a", str(device.alt),
        "-s", ":".join(modifiers), "-D", str(image_file),
    ]  # fmt: skip
    try:
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    except FileNotFoundError as exc:
        raise FlashError("dfu-util is not installed; see `wftool doctor`") from exc
    assert process.stdout is not None
    lines: list[str] = []
    pending = b""
    while chunk := process.stdout.read1(4096):
        *complete, pending = re.split(rb"[\r\n]", pending + chunk)
        for raw in complete:
            line = raw.decode("ascii", "replace").strip()
            if not line:
                continue
            lines.append(line)
            if progress and (match := _PROGRESS.match(line)):
                progress(match[1], int(match[2]), int(match[3]))
    if pending.strip():
        lines.append(pending.decode("ascii", "replace").strip())
    status = process.wait()
    written = "File downloaded successfully" in lines
    if status == 0 and written:
        return DownloadResult(status_error_after_leave=False)
    if leave and written and "dfu-util: Error during download get_status" in lines:
        return DownloadResult(status_error_after_leave=True)
    errors = [
        line
        for line in lines
        if line.startswith("state(") or (line.startswith("dfu-util: ") and "suffix" not in line)
    ]
    reason = "; ".join(errors[-2:]) or (lines[-1] if lines else "no output")
    raise FlashError(f"dfu-util failed writing at 0x{address:08x} (exit {status}): {reason}")


class DfuBackend(FlashBackend):
    """dfu-util and the STM32 ROM bootloader (DfuSe), over `wait_for_device` and `download`."""

    def wait_for_device(self, timeout: float) -> DfuDevice:
        return wait_for_device(timeout)

    def write(
        self,
        device: Device,
        address: int,
        image_file: Path,
        *,
        leave: bool,
        mass_erase: bool = False,
        progress: Progress | None = None,
    ) -> str | None:
        assert isinstance(device, DfuDevice)
        result = download(
            device, address, image_file, leave=leave, mass_erase=mass_erase, progress=progress
        )
        if result.status_error_after_leave:
            return "dfu-util: get_status failed after leave, as usual (the board had already reset)"
        return None
