"""A STAND-IN for dfu-util 0.11 talking to an STM32F722 ROM bootloader. Not the real thing.

There is no USB device on the test machine, so tests put this script first on PATH as
`dfu-util`. It reproduces dfu-util 0.11's output (strings taken from the real binary) and
exit codes (74 = EX_IOERR), and emulates the flash the way DfuSe downloads work: every
sector a download touches is erased first (dfuse.c), or everything with `:mass-erase`.

Behaviour comes from $DFU_STANDIN_STATE/config.json:
  appear_after_lists  the device is listed from the Nth `dfu-util -l` on (default 1)
  fail_at_percent     a download fails at this percentage with a write error (default none)
  leave_status_error  `:leave` ends in the get_status error real bootloaders cause (default true)
and it records every call in calls.jsonl and the flash contents in flash.bin.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

STATE = Path(os.environ["DFU_STANDIN_STATE"])
CONFIG = json.loads((STATE / "config.json").read_text())
BASE = 0x0800_0000
SECTORS = [16 << 10] * 4 + [64 << 10] + [128 << 10] * 3
SERIAL = "3276365D3231"
ALTS = [
    "@Internal Flash  /0x08000000/04*016Kg,01*064Kg,03*128Kg",
    "@Option Bytes  /0x1FFF0000/01*032 e",
    "@OTP Memory /0x1FF0F000/01*0001Ke",
    "@Device Feature/0xFFFF0000/01*004 e",
]
HEADER = """dfu-util 0.11

Copyright 2005-2009 Weston Schmidt, Harald Welte and OpenMoko Inc.
Copyright 2010-2021 Tormod Volden and Stefan Schmidt
This program is Free Software and has ABSOLUTELY NO WARRANTY
Please report bugs to http://sourceforge.net/p/dfu-util/tickets/
"""
EX_IOERR = 74


def out(text: str) -> None:
    sys.stdout.write(text)
    sys.stdout.flush()


def fail(message: str) -> None:
    sys.stdout.flush()
    sys.stderr.write(f"dfu-util: {message}\n")
    sys.exit(EX_IOERR)


def progress(description: str, done: int, total: int) -> None:
    width = 25
    filled = width * done // total
    out(f"\r{description}\t[{'=' * filled}{' ' * (width - filled)}] {100 * done // total:3d}% "
        f"{done:12d} bytes")  # fmt: skip
    if filled == width:
        out(f"\n{description} done.\n")


def device_present() -> bool:
    lists = int((STATE / "lists").read_text()) if (STATE / "lists").exists() else 0
    return lists >= CONFIG.get("appear_after_lists", 1)


def list_devices() -> None:
    count = int((STATE / "lists").read_text()) + 1 if (STATE / "lists").exists() else 1
    (STATE / "lists").write_text(str(count))
    out(HEADER + "\n")
    if device_present():
        for alt in reversed(range(len(ALTS))):
            out(f'Found DFU: [0483:df11] ver=2200, devnum=12, cfg=1, intf=0, path="1-1", '
                f'alt={alt}, name="{ALTS[alt]}", serial="{SERIAL}"\n')  # fmt: skip


def sector_span(address: int) -> tuple[int, int]:
    start = BASE
    for size in SECTORS:
        if start <= address < start + size:
            return start, start + size
        start += size
    fail(f"Page at 0x{address:08x} is not writeable")
    raise AssertionError


def download(options: str, image_path: str) -> None:
    out(HEADER + "\n")
    if not device_present():
        fail("No DFU capable USB device available")
    address_text, *modifiers = options.split(":")
    address = int(address_text, 0)
    data = Path(image_path).read_bytes()
    sys.stderr.write("dfu-util: Warning: Invalid DFU suffix signature\n")
    sys.stderr.write("dfu-util: A valid DFU suffix will be required in a future dfu-util release\n")
    out("Opening DFU capable USB device...\nDevice ID 0483:df11\nDevice DFU version 011a\n"
        "Claiming USB DFU Interface...\nSetting Alternate Interface #0 ...\n"
        "Determining device status...\n"
        "DFU state(2) = dfuIDLE, status(0) = No error condition is present\n"
        "DFU mode device DFU version 011a\nDevice returned transfer size 2048\n"
        'DfuSe interface name: "Internal Flash  "\n')  # fmt: skip
    flash = bytearray((STATE / "flash.bin").read_bytes())
    if "mass-erase" in modifiers:
        if "force" not in modifiers:
            fail("The mass erase command can only be used with force")
        out("Performing mass erase, this can take a moment\n")
        flash[:] = b"\xff" * len(flash)
    out(f"Downloading element to address = 0x{address:08x}, size = {len(data)}\n")
    if "mass-erase" not in modifiers:
        erase = address
        while erase < address + len(data):
            start, end = sector_span(erase)
            flash[start - BASE : end - BASE] = b"\xff" * (end - start)
            erase = end
        progress("Erase   ", len(data), len(data))
    fail_at = CONFIG.get("fail_at_percent")
    for done in range(0, len(data), 2048):
        chunk = data[done : done + 2048]
        if fail_at is not None and 100 * done // len(data) >= fail_at:
            out(" failed!\nstate(10) = dfuERROR, status(3) = Device is unable to write memory\n")
            (STATE / "flash.bin").write_bytes(flash)
            fail(f"Failed to write whole chunk: -1 of {len(chunk)} bytes")
        flash[address - BASE + done : address - BASE + done + len(chunk)] = chunk
        progress("Download", done, len(data))
    progress("Download", len(data), len(data))
    (STATE / "flash.bin").write_bytes(flash)
    out("File downloaded successfully\n")
    if "leave" in modifiers:
        out("Submitting leave request...\n")
        if CONFIG.get("leave_status_error", True):
            fail("Error during download get_status")
        out("Transitioning to dfuMANIFEST state\n")


def main(argv: list[str]) -> None:
    with (STATE / "calls.jsonl").open("a") as calls:
        calls.write(json.dumps(argv) + "\n")
    if argv in (["-V"], ["--version"]):
        out(HEADER)
    elif argv == ["-l"]:
        list_devices()
    elif "-D" in argv and "-s" in argv:
        download(argv[argv.index("-s") + 1], argv[argv.index("-D") + 1])
    else:
        fail(f"stand-in does not know {argv}")


if __name__ == "__main__":
    main(sys.argv[1:])
