"""Firmware images: which bytes go where, and which flash sectors writing them erases.

dfu-util's DfuSe download erases every flash page (STM32F7: sector) that a download
touches, and nothing else (`dfuse_dnload_element` in dfuse.c). So writing a hex file
segment by segment leaves untouched sectors alone — in particular Betaflight's config
sector, which the linker keeps out of the image (F72x: sector 1 at 0x08004000). Two
segments sharing a sector must go in one download, or the second erase would wipe the
first; `write_regions` merges them, filling the gap with 0xFF (erased flash).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path

from intelhex import IntelHex, IntelHexError

from wftool.errors import FlashError, UsageError


@dataclass(frozen=True)
class FlashLayout:
    """Sectors of an internal flash, from `base` upwards."""

    base: int
    sector_sizes: tuple[int, ...]

    @classmethod
    def from_dfuse_name(cls, name: str) -> FlashLayout | None:
        """Parse a DfuSe alt-setting name, e.g. `@Internal Flash  /0x08000000/04*016Kg,…`."""
        match = re.search(r"/(0x[0-9A-Fa-f]+)/((?:\d+\*\d+[ KM]?[a-g],?)+)", name)
        if not match:
            return None
        sizes: list[int] = []
        for count, size, unit in re.findall(r"(\d+)\*(\d+)([ KM]?)[a-g]", match[2]):
            scale = {"K": 1024, "M": 1024 * 1024}.get(unit, 1)
            sizes += [int(size) * scale] * int(count)
        return cls(int(match[1], 16), tuple(sizes))

    @property
    def end(self) -> int:
        return self.base + sum(self.sector_sizes)

    def sector_start(self, index: int) -> int:
        return self.base + sum(self.sector_sizes[:index])

    def sector_of(self, address: int) -> int:
        if not self.base <= address < self.end:
            raise FlashError(f"address 0x{address:08x} is outside the flash")
        offset = address - self.base
        for index, size in enumerate(self.sector_sizes):
            if offset < size:
                return index
            offset -= size
        raise AssertionError("unreachable: address checked against end")

    def sectors(self, start: int, end: int) -> range:
        """Sector indices covering [start, end)."""
        return range(self.sector_of(start), self.sector_of(end - 1) + 1)


STM32F72X = FlashLayout(0x0800_0000, (16 << 10,) * 4 + (64 << 10,) + (128 << 10,) * 3)
"""STM32F722/F732: 512 KiB."""


@dataclass(frozen=True)
class McuFlash:
    """What wftool must know about an MCU target to flash it without losing the config."""

    layout: FlashLayout
    config_address: int
    """Start of the sector holding Betaflight's EEPROM emulation (linker script)."""
    ram: tuple[int, int]
    """[start, end] of the RAM an initial stack pointer may point into (end included: the
    stack grows down from it)."""

    @property
    def config_sector(self) -> int:
        return self.layout.sector_of(self.config_address)


MCU_FLASH = {"STM32F722": McuFlash(STM32F72X, 0x0800_4000, (0x2000_0000, 0x2004_0000))}
"""Keyed by the part; Betaflight's target names for it (which differ between versions) are
`wftool.fc.versions.mcu_part`'s."""


@dataclass(frozen=True)
class WriteRegion:
    """One contiguous download."""

    address: int
    data: bytes

    @property
    def end(self) -> int:
        return self.address + len(self.data)


def load_image(path: Path, base: int = STM32F72X.base) -> IntelHex:
    """A .hex file, or a raw .bin placed at `base`."""
    image = IntelHex()
    try:
        if path.suffix.lower() == ".bin":
            image.loadbin(str(path), offset=base)
        else:
            image.loadhex(str(path))
    except (OSError, IntelHexError) as exc:
        raise UsageError(f"cannot read firmware {path}: {exc}") from exc
    if not image.segments():
        raise UsageError(f"firmware {path} is empty")
    return image


def write_regions(image: IntelHex, layout: FlashLayout) -> list[WriteRegion]:
    """The downloads that write `image`, merged so that no two share a sector."""
    spans: list[list[int]] = []
    for start, end in sorted(image.segments()):
        first_sector = layout.sectors(start, end)[0]  # raises if the segment leaves the flash
        if spans and first_sector <= layout.sector_of(spans[-1][1] - 1):
            spans[-1][1] = end
        else:
            spans.append([start, end])
    return [
        WriteRegion(start, bytes(image.tobinarray(start=start, size=end - start)))
        for start, end in spans
    ]


def erased_sectors(regions: list[WriteRegion], layout: FlashLayout) -> set[int]:
    """Sectors the downloads erase (DfuSe erases every sector a download touches)."""
    return {index for region in regions for index in layout.sectors(region.address, region.end)}


def vector_table_problem(image: IntelHex, address: int, mcu: McuFlash) -> str | None:
    """Why the core would not start from a vector table at `address` of `image` (None: it
    would). A Cortex-M loads its stack pointer and reset handler from there, and the STM32
    bootloader jumps there when it leaves (ST AN3156)."""
    stack, reset = struct.unpack("<II", bytes(image.tobinarray(start=address, size=8)))
    if not (mcu.ram[0] < stack <= mcu.ram[1] and stack % 4 == 0):
        return f"0x{stack:08x} at 0x{address:08x} is not an initial stack pointer in RAM"
    handler = reset & ~1
    if not (reset & 1 and any(start <= handler < end for start, end in image.segments())):
        return f"its reset handler 0x{reset:08x} is not Thumb code in the image"
    return None


def contains_string(image: IntelHex, text: str, *, whole: bool = True) -> bool:
    """Whether the image holds C string `text` (or, with `whole=False`, one starting with it)."""
    if not text.isascii():
        return False  # an FC's string with bytes MSP decoding replaced: no image holds it
    needle = b"\0" + text.encode("ascii") + (b"\0" if whole else b"")
    return any(
        needle in bytes(image.tobinarray(start=start, size=end - start))
        for start, end in image.segments()
    )
