"""The emulated STM32F722 bootloader behaves as AN3156 says the ROM does (the flash tests
are only as good as it is)."""

from __future__ import annotations

import struct

import pytest

from tests.flash.dfuse_device import (
    ALT_NAMES,
    FLASH_BASE,
    FLASH_SIZE,
    Bootloader,
    Faults,
    Gone,
    Stall,
    State,
    Status,
    config_descriptor,
    device_descriptor,
)
from wftool.flash.image import STM32F72X, FlashLayout

OUT, IN = 0x21, 0xA1  # class request to interface 0, host to device / device to host
DNLOAD, UPLOAD, GETSTATUS, CLRSTATUS, ABORT = 1, 2, 3, 4, 6


def _request(device: Bootloader, request_type: int, request: int, value: int = 0,
             data: bytes = b"", length: int = 0) -> bytes:  # fmt: skip
    size = len(data) if request_type == OUT else length
    return device.control(struct.pack("<BBHHH", request_type, request, value, 0, size), data)


def _status(device: Bootloader) -> tuple[Status, int, State]:
    reply = _request(device, IN, GETSTATUS, length=6)
    poll_ms = int.from_bytes(reply[1:4], "little")
    return Status(reply[0]), poll_ms, State(reply[4])


def _command(device: Bootloader, *payload: int, address: int | None = None) -> None:
    data = bytes(payload) + (struct.pack("<I", address) if address is not None else b"")
    _request(device, OUT, DNLOAD, 0, data)


def test_descriptors_are_those_of_the_rom_bootloader() -> None:
    device = device_descriptor()
    assert struct.unpack("<HHH", device[8:14]) == (0x0483, 0xDF11, 0x2200)
    config = config_descriptor()
    assert struct.unpack("<H", config[2:4])[0] == len(config) == 9 + 4 * 9 + 9
    functional = config[-9:]
    assert functional[1] == 0x21 and functional[2] == 0x0B  # download, upload, will detach
    assert struct.unpack("<HHH", functional[3:9]) == (255, 2048, 0x011A)
    assert FlashLayout.from_dfuse_name(ALT_NAMES[0]) == STM32F72X


def test_a_command_is_busy_first_and_done_only_after_the_status_request() -> None:
    device = Bootloader(flash=bytearray(b"\0" * FLASH_SIZE), time_scale=1.0)
    _command(device, 0x41, address=0x0800_4000)
    assert device.state == State.dfuDNLOAD_SYNC
    assert device.flash[0x4000] == 0  # nothing erased before the status request
    status, poll_ms, state = _status(device)
    assert (status, state, poll_ms) == (Status.OK, State.dfuDNBUSY, 250)  # a 16K sector
    assert _status(device)[2] == State.dfuDNLOAD_IDLE
    assert device.flash[0x4000:0x8000] == b"\xff" * 0x4000
    assert device.flash[0x3FFF] == 0 and device.flash[0x8000] == 0
    assert device.events[-1] == ("erase", 0x0800_4000)


def test_programming_only_clears_bits() -> None:
    device = Bootloader()
    device.flash[0:4] = b"\x0f\xf0\xff\x00"
    _command(device, 0x21, address=FLASH_BASE)
    _status(device), _status(device)
    _request(device, OUT, DNLOAD, 2, b"\xff\xff\x3c\xff")
    assert _status(device)[2] == State.dfuDNBUSY
    assert _status(device)[2] == State.dfuDNLOAD_IDLE
    assert device.flash[0:4] == b"\x0f\xf0\x3c\x00"  # an unerased word keeps its zeros


def test_blocks_are_placed_by_number_and_read_back() -> None:
    device = Bootloader()
    _command(device, 0x21, address=0x0800_8000)
    _status(device), _status(device)
    _request(device, OUT, DNLOAD, 3, b"\x11" * 2048)  # block 3: pointer + 2048
    _status(device), _status(device)
    _request(device, OUT, ABORT)
    assert _request(device, IN, UPLOAD, 3, length=16) == b"\x11" * 16
    assert _request(device, IN, UPLOAD, 0, length=4) == b"\x00\x21\x41\x92"  # Get Commands
    assert device.flash[0x8800:0x9000] == b"\x11" * 2048


def test_a_request_the_state_does_not_allow_stalls_into_dfu_error() -> None:
    device = Bootloader()
    _command(device, 0x21, address=FLASH_BASE)
    with pytest.raises(Stall):
        _request(device, IN, UPLOAD, 2, length=16)  # DNLOAD-SYNC: not now
    assert _status(device)[::2] == (Status.errSTALLEDPKT, State.dfuERROR)
    _request(device, OUT, CLRSTATUS)
    assert _status(device)[::2] == (Status.OK, State.dfuIDLE)


def test_faults_end_in_dfu_error_or_leave_the_bus() -> None:
    device = Bootloader(faults=Faults(write_fails_at=0x0800_8010, vanish_after_blocks=1))
    _command(device, 0x21, address=0x0800_8000)
    _status(device), _status(device)
    _request(device, OUT, DNLOAD, 2, b"\0" * 2048)
    _status(device)
    assert _status(device)[::2] == (Status.errWRITE, State.dfuERROR)
    assert device.flash[0x8000:0x8800] == b"\xff" * 2048
    device = Bootloader(faults=Faults(vanish_after_blocks=1))
    _request(device, OUT, DNLOAD, 2, b"\0" * 2048)
    _status(device)
    with pytest.raises(Gone):
        _status(device)


def test_leaving_jumps_to_a_vector_table_or_resets_into_the_flash() -> None:
    device = Bootloader()
    device.flash[0:8] = struct.pack("<II", 0x2001_0000, 0x0800_8101)
    _command(device, 0x21, address=0x0800_8000)  # no vector table there
    _status(device), _status(device)
    _request(device, OUT, DNLOAD, 2)
    assert _status(device)[2] == State.dfuMANIFEST
    assert device.left is not None
    assert (device.left.jumped, device.left.vector_table, device.left.runs) == (
        False, FLASH_BASE, True
    )  # fmt: skip
    with pytest.raises(Gone):
        _status(device)


def test_read_protection_blocks_all_but_read_unprotect() -> None:
    device = Bootloader(read_protected=True)
    with pytest.raises(Stall):
        _command(device, 0x21, address=FLASH_BASE)
    with pytest.raises(Stall):
        _request(device, IN, UPLOAD, 2, length=16)
    device.flash[0] = 0
    _command(device, 0x92)
    assert _status(device)[2] == State.dfuDNBUSY
    assert not device.read_protected and device.flash == b"\xff" * FLASH_SIZE
    with pytest.raises(Gone):  # it resets
        _status(device)
