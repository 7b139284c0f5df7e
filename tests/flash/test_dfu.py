"""The dfu-util backend: the real dfu-util 0.11 and libusb against the emulated STM32F722
ROM bootloader (tests/flash/emulator.py, through umockdev). What is emulated: the USB
device; what is judged: the emulated flash, read after the fact."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from tests.flash.emulator import EmulatedBootloader
from tests.flash.images import CONFIG_SECTOR, FLASH_BASE, OLD_FLASH, sector, sector_span
from wftool.errors import FlashError
from wftool.flash import dfu
from wftool.flash.image import STM32F72X


def _file(tmp_path: Path, data: bytes) -> Path:
    path = tmp_path / "region.bin"
    path.write_bytes(data)
    return path


def _device(bootloader: EmulatedBootloader) -> dfu.DfuDevice:
    bootloader.attach()
    return dfu.wait_for_device(timeout=5)


def test_listing_finds_the_bootloader_and_its_layout(bootloader: EmulatedBootloader) -> None:
    bootloader.attach()
    devices = dfu.list_devices()
    assert [d.alt for d in devices] == [3, 2, 1, 0]
    flash = dfu.wait_for_device(timeout=1)
    assert (str(flash.usb_id), flash.path, flash.alt, flash.serial) == (
        "0483:df11", "1-1", 0, "STM32FxSTM32"
    )  # fmt: skip
    assert flash.name == "@Internal Flash  /0x08000000/04*016Kg,01*64Kg,03*128Kg"
    assert flash.layout == STM32F72X


def test_a_device_appearing_late_is_waited_for(bootloader: EmulatedBootloader) -> None:
    assert dfu.list_devices() == []
    timer = threading.Timer(1.0, bootloader.attach)
    timer.start()
    started = time.monotonic()
    try:
        device = dfu.wait_for_device(timeout=10, poll_interval=0.1)
    finally:
        timer.join()
    assert device.alt == 0 and 1.0 <= time.monotonic() - started < 5


def test_a_device_that_never_appears_times_out_with_a_hint(
    bootloader: EmulatedBootloader,
) -> None:
    with pytest.raises(FlashError, match="no DFU device 0483:df11 appeared within 0 s: hold"):
        dfu.wait_for_device(timeout=0.3, poll_interval=0.1)


def test_download_erases_the_sectors_it_touches_and_nothing_else(
    bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    device = _device(bootloader)
    seen: list[tuple[str, int, int]] = []
    data = bytes(range(256)) * 96  # 24 KiB at 0x08008000: sectors 2 and 3
    dfu.download(device, 0x0800_8000, _file(tmp_path, data), progress=lambda *a: seen.append(a))
    assert ("Erase", 100, len(data)) in seen and seen[-1] == ("Download", 100, len(data))
    percents = [p for phase, p, _ in seen if phase == "Download"]
    assert percents == sorted(percents) and len(percents) > 3
    flash = bootloader.flash()
    assert flash[0x8000 : 0x8000 + len(data)] == data
    assert flash[0x8000 + len(data) : 0x10000] == b"\xff" * (0x8000 - len(data))  # sector 3
    for untouched in (0, CONFIG_SECTOR, 4, 5, 6, 7):
        assert sector(flash, untouched) == sector(OLD_FLASH, untouched), untouched
    assert [e[1] for e in bootloader.events("erase")] == [0x0800_8000, 0x0800_C000]


def test_upload_reads_back_what_the_flash_holds(bootloader: EmulatedBootloader) -> None:
    device = _device(bootloader)
    seen: list[tuple[str, int, int]] = []
    data = dfu.upload(device, 0x0800_3F00, 0x1300, progress=lambda *a: seen.append(a))
    assert data == OLD_FLASH[0x3F00:0x5200]  # across sectors 0 and 1, a partial last block
    assert seen[-1] == ("Upload", 100, 0x1300)
    assert bootloader.events("erase") == [] and bootloader.events("write") == []


def test_mass_erase_wipes_the_config_sector(bootloader: EmulatedBootloader, tmp_path: Path) -> None:
    device = _device(bootloader)
    dfu.download(device, FLASH_BASE, _file(tmp_path, b"\x01" * 16), mass_erase=True)
    flash = bootloader.flash()
    assert flash[:16] == b"\x01" * 16
    assert flash[16:] == b"\xff" * (len(flash) - 16)
    assert bootloader.events("mass_erase") and not bootloader.events("erase")


def test_leave_starts_the_firmware_at_the_address(bootloader: EmulatedBootloader) -> None:
    device = _device(bootloader)
    assert dfu.leave(device, FLASH_BASE) is None  # "Transitioning to dfuMANIFEST state"
    left = bootloader.left()
    assert left is not None and (left.address, left.jumped, left.runs) == (FLASH_BASE, True, True)
    assert not bootloader.attached  # it left the bus
    assert dfu.list_devices() == []


def test_a_rom_that_resets_before_the_leave_status_is_not_a_failure(
    bootloader: EmulatedBootloader,
) -> None:
    bootloader.inject(reset_before_leave_status=True)
    device = _device(bootloader)
    assert dfu.leave(device, FLASH_BASE) == (
        "the bootloader reset before answering the leave request, as some STM32 ROMs do"
    )
    assert bootloader.left() is not None


def test_a_failed_write_is_a_flash_error_in_dfu_utils_words(
    bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    bootloader.inject(write_fails_at=0x0800_8000 + 5000)
    device = _device(bootloader)
    with pytest.raises(FlashError) as error:
        dfu.download(device, 0x0800_8000, _file(tmp_path, b"\x02" * 65536))
    assert str(error.value) == (
        "dfu-util failed writing at 0x08008000 (exit 74): DFU state(10) = dfuERROR, "
        "status(3) = Device is unable to write memory; "
        "dfu-util: Failed to write whole chunk: -1 of 2048 bytes"
    )
    assert bootloader.flash()[0x8000 + 4096 : 0x8000 + 6144] == b"\xff" * 2048  # erased only


def test_a_failed_erase_is_a_flash_error(bootloader: EmulatedBootloader, tmp_path: Path) -> None:
    bootloader.inject(erase_fails_at=0x0800_C000)
    device = _device(bootloader)
    with pytest.raises(FlashError) as error:
        dfu.download(device, 0x0800_8000, _file(tmp_path, b"\x02" * 0x5000))
    assert str(error.value) == (
        "dfu-util failed writing at 0x08008000 (exit 74): "
        "dfu-util: ERASE_PAGE not correctly executed"
    )
    start, end = sector_span(3)
    assert bootloader.flash()[start:end] == OLD_FLASH[start:end]
    assert bootloader.events("write") == []


def test_a_device_vanishing_mid_download_is_a_flash_error(
    bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    bootloader.inject(vanish_after_blocks=3)
    device = _device(bootloader)
    with pytest.raises(FlashError) as error:
        dfu.download(device, 0x0800_8000, _file(tmp_path, b"\x02" * 65536))
    assert str(error.value) == (
        "dfu-util failed writing at 0x08008000 (exit 74): dfu-util: Error during download "
        "get_status; the board left USB (unplugged, or reset?)"
    )
    assert not bootloader.attached
    assert len(bootloader.events("write")) == 3


def test_reading_past_the_flash_is_a_flash_error(bootloader: EmulatedBootloader) -> None:
    device = _device(bootloader)
    with pytest.raises(FlashError, match=r"^dfu-util failed reading back 0x0807f000 \(exit"):
        dfu.upload(device, 0x0807_F000, 0x2000)


def test_missing_dfu_util_is_explained(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dfu, "DFU_UTIL", ("/nonexistent/dfu-util",))
    with pytest.raises(FlashError, match="dfu-util is not installed"):
        dfu.list_devices()
