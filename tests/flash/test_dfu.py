"""The dfu-util backend, at the process boundary, against a STAND-IN dfu-util.

No USB device exists here: tests/flash/standin_dfu_util.py plays dfu-util 0.11 with an
STM32F722 bootloader (output and exit codes as the real binary's). What is real: wftool's
command lines, its parsing of that output, its handling of exit codes.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from tests.flash.standin import UNTOUCHED, StandinDfuUtil
from wftool.errors import FlashError
from wftool.flash import dfu
from wftool.flash.image import STM32F72X


def test_listing_finds_the_bootloader_and_its_layout(standin_dfu_util: StandinDfuUtil) -> None:
    devices = dfu.list_devices()
    assert [d.alt for d in devices] == [3, 2, 1, 0]
    flash = dfu.wait_for_device(timeout=1)
    assert (str(flash.usb_id), flash.path, flash.alt) == ("0483:df11", "1-1", 0)
    assert flash.layout == STM32F72X


def test_a_device_appearing_late_is_waited_for(standin_dfu_util: StandinDfuUtil) -> None:
    standin_dfu_util.configure(appear_after_lists=3)
    started = time.monotonic()
    device = dfu.wait_for_device(timeout=10, poll_interval=0.1)
    assert device.alt == 0
    assert [call for call in standin_dfu_util.calls() if call == ["-l"]] == [["-l"]] * 3
    assert time.monotonic() - started < 5


def test_no_device_times_out_with_a_hint(standin_dfu_util: StandinDfuUtil) -> None:
    standin_dfu_util.configure(appear_after_lists=1000)
    with pytest.raises(FlashError, match="no DFU device 0483:df11 appeared within 0 s: hold"):
        dfu.wait_for_device(timeout=0.3, poll_interval=0.1)


def _address_option(standin: StandinDfuUtil) -> str:
    call = standin.calls()[-1]
    return call[call.index("-s") + 1]


def _write(tmp_path: Path, data: bytes) -> Path:
    path = tmp_path / "region.bin"
    path.write_bytes(data)
    return path


def test_download_reports_progress_and_erases_only_touched_sectors(
    standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    device = dfu.wait_for_device(timeout=1)
    seen: list[tuple[str, int, int]] = []
    data = bytes(range(256)) * 160  # 40 KiB at 0x08008000: sectors 2 and 3
    result = dfu.download(
        device, 0x0800_8000, _write(tmp_path, data), leave=False, progress=lambda *a: seen.append(a)
    )
    assert not result.status_error_after_leave
    assert ("Erase", 100, len(data)) in seen
    assert seen[-1] == ("Download", 100, len(data))
    percents = [p for phase, p, _ in seen if phase == "Download"]
    assert percents == sorted(percents) and len(percents) > 3
    assert standin_dfu_util.calls()[-1] == [
        "dfu-util", "-d", "0483:df11", "-p", "1-1", "-a", "0", "-s", "0x08008000", "-D",
        str(tmp_path / "region.bin"),
    ][1:]  # fmt: skip
    flash = standin_dfu_util.flash()
    assert flash[0x8000 : 0x8000 + len(data)] == data
    assert flash[0x4000:0x8000] == bytes([UNTOUCHED]) * 0x4000  # config sector untouched


def test_get_status_error_after_leave_is_not_a_failure(
    standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    device = dfu.wait_for_device(timeout=1)
    result = dfu.download(device, 0x0800_0000, _write(tmp_path, b"\x01" * 512), leave=True)
    assert result.status_error_after_leave
    assert _address_option(standin_dfu_util) == "0x08000000:leave"


def test_clean_leave_is_fine_too(standin_dfu_util: StandinDfuUtil, tmp_path: Path) -> None:
    standin_dfu_util.configure(leave_status_error=False)
    device = dfu.wait_for_device(timeout=1)
    assert not dfu.download(
        device, 0x0800_0000, _write(tmp_path, b"\x01"), leave=True
    ).status_error_after_leave


def test_write_failure_is_a_flash_error_with_dfu_utils_reason(
    standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    standin_dfu_util.configure(fail_at_percent=50)
    device = dfu.wait_for_device(timeout=1)
    with pytest.raises(FlashError) as error:
        dfu.download(device, 0x0800_8000, _write(tmp_path, b"\x02" * 65536), leave=True)
    assert str(error.value) == (
        "dfu-util failed writing at 0x08008000 (exit 74): state(10) = dfuERROR, status(3) = "
        "Device is unable to write memory; dfu-util: Failed to write whole chunk: -1 of 2048 bytes"
    )


def test_mass_erase_wipes_the_config_sector(
    standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    device = dfu.wait_for_device(timeout=1)
    dfu.download(device, 0x0800_0000, _write(tmp_path, b"\x01" * 16), leave=False, mass_erase=True)
    assert _address_option(standin_dfu_util) == "0x08000000:mass-erase:force"
    assert standin_dfu_util.flash()[0x4000:0x8000] == b"\xff" * 0x4000


def test_missing_dfu_util_is_explained(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(FlashError, match="dfu-util is not installed"):
        dfu.list_devices()
