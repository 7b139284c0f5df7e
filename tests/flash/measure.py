"""How long the dfu-util part of `wftool flash` takes for an image, on the emulated STM32F722
bootloader: write (erase + download), read back, leave. Test scaffolding, run by hand:

    .venv/bin/python -m tests.flash.measure build/speedybeef7v3/*.hex

Two runs: with the emulation's flash timing off (what dfu-util, libusb and the protocol
cost here) and on (the STM32F7 datasheet's typical erase and programming times, which
the bootloader reports as poll timeouts). USB bus time is not modelled: a full-speed board
adds the transfer time of the bytes (control transfers of 64-byte packets).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from tests.flash.emulator import EmulatedBootloader, unavailable
from wftool.flash import dfu
from wftool.flash.image import STM32F72X, erased_sectors, load_image, write_regions


def measure(image_path: Path, time_scale: float) -> dict[str, float]:
    regions = write_regions(load_image(image_path), STM32F72X)
    with (
        tempfile.TemporaryDirectory() as scratch,
        EmulatedBootloader(Path(scratch) / "host.log") as bootloader,
    ):
        bootloader.configure(time_scale=time_scale)
        dfu.DFU_UTIL = bootloader.dfu_util
        bootloader.attach()
        device = dfu.wait_for_device(5)
        times = {"write": time.monotonic()}
        for region in regions:
            path = Path(scratch) / "region.bin"
            path.write_bytes(region.data)
            dfu.download(device, region.address, path)
        times["read back"] = time.monotonic()
        for region in regions:
            assert dfu.upload(device, region.address, len(region.data)) == region.data
        times["leave"] = time.monotonic()
        dfu.leave(device, regions[0].address)
        times["end"] = time.monotonic()
    stamps = list(times.values())
    return {name: end - start for name, start, end in zip(times, stamps, stamps[1:])}


def main(image: str) -> None:
    if reason := unavailable():
        sys.exit(f"measure: {reason}")
    path = Path(image)
    regions = write_regions(load_image(path), STM32F72X)
    size = sum(len(region.data) for region in regions)
    sectors = sorted(erased_sectors(regions, STM32F72X))
    print(f"{path.name}: {size} bytes in {len(regions)} regions, sectors {sectors}")
    for label, scale in (("flash timing off", 0.0), ("F7 flash timing", 1.0)):
        phases = measure(path, scale)
        table = ", ".join(f"{name} {seconds:.2f} s" for name, seconds in phases.items())
        print(f"{label:>17}: {sum(phases.values()):.2f} s ({table})")


if __name__ == "__main__":
    main(sys.argv[1])
