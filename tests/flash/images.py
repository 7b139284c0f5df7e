"""Firmware images and flash contents for the flash tests."""

from __future__ import annotations

import hashlib
import struct
from pathlib import Path

from intelhex import IntelHex

from wftool.fc.msp import BuildInfo
from wftool.flash.image import STM32F72X

FLASH_BASE = STM32F72X.base
FLASH_SIZE = STM32F72X.end - STM32F72X.base
CONFIG_SECTOR = 1
VECTORS = struct.pack("<II", 0x2001_0000, 0x0800_8101)
"""A vector table as Betaflight's F7 images start: stack at the top of DTCM, reset handler
(Thumb) in the firmware part at 0x08008000."""


def _noise(label: bytes, size: int) -> bytes:
    """SIZE pseudo-random bytes: no run of 0xFF, unlike anything written or erased."""
    out = bytearray()
    counter = 0
    while len(out) < size:
        out += hashlib.sha256(label + counter.to_bytes(4, "little")).digest()
        counter += 1
    return bytes(out[:size]).replace(b"\xff", b"\xfe")


def _old_flash() -> bytes:
    flash = bytearray(_noise(b"the previous firmware", FLASH_SIZE))
    flash[:8] = VECTORS
    start, end = sector_span(CONFIG_SECTOR)
    flash[start:end] = _noise(b"the configuration", end - start)
    return bytes(flash)


def sector_span(index: int) -> tuple[int, int]:
    """[start, end) of sector INDEX as offsets into the flash."""
    start = STM32F72X.sector_start(index) - FLASH_BASE
    return start, start + STM32F72X.sector_sizes[index]


OLD_FLASH = _old_flash()
"""What the board's flash held before a test: a previous firmware and a configuration."""


def sector(flash: bytes, index: int) -> bytes:
    start, end = sector_span(index)
    return flash[start:end]


def firmware_hex(path: Path, build: BuildInfo, *strings: str, vectors: bytes = VECTORS) -> Path:
    """A Betaflight-shaped image: vector table at 0x08000000 (sector 0), firmware at
    0x08008000 (sector 2, past the config sector) holding BUILD's identity and STRINGS."""
    image = IntelHex()
    image.puts(FLASH_BASE, vectors + bytes(range(256)) * 2)
    names = (build.date, build.time, build.git_revision + "f2", *strings)
    firmware = b"\0" + b"\0".join(name.encode() for name in names) + b"\0"
    image.puts(FLASH_BASE + 0x8000, firmware + bytes(range(251, 0, -1)) * 24)
    image.write_hex_file(str(path))
    return path


def image_bytes(path: Path) -> list[tuple[int, bytes]]:
    """The (address, data) segments of a hex file."""
    image = IntelHex(str(path))
    return [
        (start, bytes(image.tobinarray(start=start, size=end - start)))
        for start, end in image.segments()
    ]
