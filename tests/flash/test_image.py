"""Splitting firmware into downloads and working out which sectors they erase."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from intelhex import IntelHex

from wftool.errors import FlashError, UsageError
from wftool.flash.image import (
    MCU_FLASH,
    STM32F72X,
    FlashLayout,
    contains_string,
    erased_sectors,
    load_image,
    vector_table_problem,
    write_regions,
)

F722 = MCU_FLASH["STM32F722"]


def test_f722_bootloader_layout_string_matches_the_table() -> None:
    # alt 0 of an STM32F72x ROM bootloader as `dfu-util -l` prints it, and the F4's spelling
    for name in (
        "@Internal Flash  /0x08000000/04*016Kg,01*64Kg,03*128Kg",
        "@Internal Flash  /0x08000000/04*016Kg,01*064Kg,03*128Kg",
    ):
        assert FlashLayout.from_dfuse_name(name) == STM32F72X
    assert STM32F72X.end == 0x0808_0000
    assert FlashLayout.from_dfuse_name("@Option Bytes  /0x1FFF0000/01*032 e") == FlashLayout(
        0x1FFF_0000, (32,)
    )
    assert FlashLayout.from_dfuse_name("no layout here") is None


def test_config_sector_is_sector_1() -> None:
    assert F722.config_sector == 1
    assert STM32F72X.sector_start(1) == 0x0800_4000


def test_built_hex_skips_the_config_sector(built_hex: Path) -> None:
    image = load_image(built_hex)
    regions = write_regions(image, STM32F72X)
    assert [r.address for r in regions] == [0x0800_0000, 0x0800_8000]
    assert sum(len(r.data) for r in regions) == sum(end - start for start, end in image.segments())
    erased = erased_sectors(regions, STM32F72X)
    assert F722.config_sector not in erased
    assert 0 in erased and 2 in erased
    assert contains_string(image, "STM32F722")
    assert not contains_string(image, "STM32F72")  # whole strings only
    assert contains_string(image, "STM32F72", whole=False)
    assert not contains_string(image, "STM32F72\ufffd")  # a name MSP decoding replaced


def test_a_bin_of_the_same_build_covers_the_config_sector(built_hex: Path, tmp_path: Path) -> None:
    # A .bin is the image from 0x08000000 with the gap filled: it must go over sector 1.
    image = load_image(built_hex)
    binary = tmp_path / "fw.bin"
    image.tobinfile(str(binary), start=STM32F72X.base)
    regions = write_regions(load_image(binary), STM32F72X)
    assert len(regions) == 1
    assert F722.config_sector in erased_sectors(regions, STM32F72X)


def test_segments_sharing_a_sector_become_one_download() -> None:
    image = IntelHex()
    image.puts(0x0800_0000, b"\x01" * 16)
    image.puts(0x0800_0100, b"\x02" * 16)  # same 16K sector: must not be erased twice
    image.puts(0x0801_0000, b"\x03" * 16)  # sector 4
    regions = write_regions(image, STM32F72X)
    assert [(r.address, len(r.data)) for r in regions] == [(0x0800_0000, 0x110), (0x0801_0000, 16)]
    assert regions[0].data[16:0x100] == b"\xff" * (0x100 - 16)  # gap = erased flash
    assert erased_sectors(regions, STM32F72X) == {0, 4}


def test_a_segment_spanning_sectors_erases_each_of_them() -> None:
    image = IntelHex()
    image.puts(0x0800_3FF0, b"\x00" * 0x20)  # crosses from sector 0 into sector 1
    assert erased_sectors(write_regions(image, STM32F72X), STM32F72X) == {0, 1}


def test_data_outside_the_flash_is_refused() -> None:
    image = IntelHex()
    image.puts(0x0808_0000, b"\x00")
    with pytest.raises(FlashError, match="outside the flash"):
        write_regions(image, STM32F72X)


def test_unreadable_firmware_is_a_usage_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.hex"
    bad.write_text(":zz\n")
    with pytest.raises(UsageError, match=f"cannot read firmware {bad}"):
        load_image(bad)


def test_a_betaflight_image_starts_with_a_vector_table(built_hex: Path) -> None:
    assert vector_table_problem(load_image(built_hex), STM32F72X.base, F722) is None


@pytest.mark.parametrize(
    ("vectors", "problem"),
    [
        ((0x2001_0000, 0x0800_0101), None),
        ((0x2004_0000, 0x0800_0101), None),  # the stack may start at the top of RAM
        ((0x2004_0004, 0x0800_0101), "0x20040004 at 0x08000000 is not an initial stack pointer"),
        ((0xFFFF_FFFF, 0xFFFF_FFFF), "0xffffffff at 0x08000000 is not an initial stack pointer"),
        ((0x2001_0000, 0x0800_0100), "its reset handler 0x08000100 is not Thumb code"),
        ((0x2001_0000, 0x0801_0001), "its reset handler 0x08010001 is not Thumb code"),
    ],
)
def test_vector_table_problems(vectors: tuple[int, int], problem: str | None) -> None:
    image = IntelHex()
    image.puts(0x0800_0000, struct.pack("<II", *vectors) + bytes(0x200))
    found = vector_table_problem(image, 0x0800_0000, F722)
    assert found == problem if problem is None else (found or "").startswith(problem)
