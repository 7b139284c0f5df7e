"""An EMULATED STM32F722 ROM bootloader in DFU mode (DfuSe 1.1a): the device the flash tests
give the real dfu-util and libusb, through umockdev (tests/flash/usbfs_host.py).

Standard library only: the umockdev host runs it under the system Python.

Modelled, after ST's AN3156 (the DfuSe protocol of the STM32 bootloader) and AN2606:
- USB identity: 0483:df11, bcdDevice 22.00, "STMicroelectronics" / "STM32  BOOTLOADER",
  one configuration with interface 0 in four alternate settings (internal flash, option
  bytes, OTP, device feature) named by DfuSe memory strings, and the DFU functional
  descriptor (bmAttributes 0x0B: download, upload, will detach, manifestation
  intolerant; wDetachTimeOut 255 ms; wTransferSize 2048; bcdDFUVersion 1.1a). The layout
  is that of `lsusb -v` dumps of STM32F4/F7 ROM bootloaders (bcdUSB 2.00 here; an old F4
  ROM says 1.00); the alternate settings' strings are those of an STM32F72x board's
  `dfu-util -l` (alt 0 says `01*64Kg`, not `01*064Kg` as the F4 does). Written from
  published dumps: not read off an F722 here.
- Flash: 512 KiB at 0x08000000 in the F72x sectors (4 x 16, 1 x 64, 3 x 128 KiB). Erasing
  sets a sector to 0xFF; programming can only clear bits (new = old AND data: the F7 flash
  controller does not refuse a write over unerased flash, so a missing erase shows as
  wrong data, found only by reading back).
- DFU requests on interface 0: DNLOAD, UPLOAD, GETSTATUS, CLRSTATUS, GETSTATE, ABORT
  (DETACH stalls), in the DFU 1.1 state machine; a request a state does not allow stalls
  and puts the device in dfuERROR (errSTALLEDPKT).
- DfuSe commands (DNLOAD block 0): Set Address Pointer (0x21), Erase page/sector (0x41 +
  address) and mass erase (0x41 alone), Read Unprotect (0x92: wipes the flash, sets read
  protection to level 0, resets the device); UPLOAD block 0 lists them (Get Commands).
  Data blocks n >= 2 go to / come from address pointer + (n - 2) * wTransferSize.
- Timing of the protocol as the ROM does it: the GETSTATUS after a DNLOAD answers
  dfuDNBUSY with a poll timeout and only then does the work; the next GETSTATUS gives
  the result (dfuDNLOAD-IDLE, or dfuERROR with a status). Poll timeouts are the modelled
  durations of erasing and programming (typical STM32F7 datasheet figures, x32) times
  `time_scale` (0 in tests: no waiting); a GETSTATUS that comes before the work is done is
  answered when it is done (the device NAKs meanwhile).
- Leave (AN3156, AN2662 "Leave DFU"): a zero-length DNLOAD, then GETSTATUS answers
  dfuMANIFEST; the bootloader leaves the bus and jumps to the address pointer if the word
  there is a stack pointer in SRAM ("executable code"), else it resets and, BOOT0 being
  low, the chip boots from flash at 0x08000000. Either way the firmware runs only if the
  vector table it starts from has a stack pointer in SRAM and a Thumb reset handler in
  flash; otherwise it faults and the board stays dark until power-cycled (`Leave`).
- Read protection level 1 (`read_protected`): every DfuSe command but Read Unprotect
  stalls, and so does UPLOAD.
- Faults (`Faults`): an erase or a write that fails (dfuERROR, errERASE / errWRITE), a
  write that silently stores wrong data, the device vanishing after N data blocks, and a
  reset before the leave request's status is answered. A device that never appears is
  one never attached (emulator.py).

Not modelled: USB bus timing (control transfers complete at once); option bytes and OTP
beyond their listing (they read back fixed contents, writes are refused with errTARGET);
write protection (nWRP), PCROP, dual bank/boot, the ITCM flash alias; the bootloader's
other interfaces (USART, CAN, ...); the exact poll timeouts the ROM reports; DFU_DETACH.
"""

from __future__ import annotations

import struct
import threading
import time
from dataclasses import dataclass, field
from enum import IntEnum

VENDOR_ID = 0x0483
PRODUCT_ID = 0xDF11
BCD_DEVICE = 0x2200
MANUFACTURER = "STMicroelectronics"
PRODUCT = "STM32  BOOTLOADER"
SERIAL = "STM32FxSTM32"
"""What many STM32F4/F7 ROM bootloaders report as their serial number (some report a
number derived from the chip's unique ID instead; pass `serial=`)."""
TRANSFER_SIZE = 2048

FLASH_BASE = 0x0800_0000
FLASH_SECTORS = (16 << 10,) * 4 + (64 << 10,) + (128 << 10,) * 3
FLASH_SIZE = sum(FLASH_SECTORS)
SRAM = (0x2000_0000, 0x2004_0000)
"""DTCM + SRAM1 + SRAM2 of the F722: where an initial stack pointer may point (inclusive
of the end: stacks grow down from it)."""

ALT_NAMES = (
    "@Internal Flash  /0x08000000/04*016Kg,01*64Kg,03*128Kg",
    "@Option Bytes  /0x1FFF0000/01*048 e",
    "@OTP Memory /0x1FF07800/01*528e",
    "@Device Feature/0xFFFF0000/01*004 e",
)
OPTION_BYTES = 0x1FFF_0000
OTP = 0x1FF0_7800
DEVICE_FEATURE = 0xFFFF_0000

# Typical STM32F7 flash timings at x32 parallelism (datasheet figures), in seconds.
ERASE_S = {16 << 10: 0.25, 64 << 10: 0.5, 128 << 10: 1.0}
MASS_ERASE_S = 4.0
PROGRAM_WORD_S = 16e-6

GET_COMMANDS, SET_ADDRESS, ERASE, READ_UNPROTECT = 0x00, 0x21, 0x41, 0x92

# USB standard requests
GET_STATUS, GET_DESCRIPTOR, GET_CONFIGURATION, SET_CONFIGURATION = 0x00, 0x06, 0x08, 0x09
DT_DEVICE, DT_CONFIG, DT_STRING = 1, 2, 3
# DFU class requests
DFU_DETACH, DFU_DNLOAD, DFU_UPLOAD, DFU_GETSTATUS, DFU_CLRSTATUS, DFU_GETSTATE, DFU_ABORT = range(7)


class State(IntEnum):
    appIDLE = 0
    appDETACH = 1
    dfuIDLE = 2
    dfuDNLOAD_SYNC = 3
    dfuDNBUSY = 4
    dfuDNLOAD_IDLE = 5
    dfuMANIFEST_SYNC = 6
    dfuMANIFEST = 7
    dfuMANIFEST_WAIT_RESET = 8
    dfuUPLOAD_IDLE = 9
    dfuERROR = 10


class Status(IntEnum):
    OK = 0x00
    errTARGET = 0x01
    errFILE = 0x02
    errWRITE = 0x03
    errERASE = 0x04
    errCHECK_ERASED = 0x05
    errPROG = 0x06
    errVERIFY = 0x07
    errADDRESS = 0x08
    errNOTDONE = 0x09
    errFIRMWARE = 0x0A
    errVENDOR = 0x0B
    errUSBR = 0x0C
    errPOR = 0x0D
    errUNKNOWN = 0x0E
    errSTALLEDPKT = 0x0F


class Stall(Exception):
    """The device stalls the control request (the host sees EPIPE)."""


class Gone(Exception):
    """The device is no longer on the bus (the host sees ENODEV)."""


def device_descriptor() -> bytes:
    return struct.pack(
        "<BBHBBBBHHHBBBB", 18, DT_DEVICE, 0x0200, 0, 0, 0, 64,
        VENDOR_ID, PRODUCT_ID, BCD_DEVICE, 1, 2, 3, 1,
    )  # fmt: skip


def config_descriptor() -> bytes:
    interfaces = b"".join(
        struct.pack("<BBBBBBBBB", 9, 4, 0, alt, 0, 0xFE, 0x01, 0x02, 4 + alt)
        for alt in range(len(ALT_NAMES))
    )
    functional = struct.pack("<BBBHHH", 9, 0x21, 0x0B, 255, TRANSFER_SIZE, 0x011A)
    total = 9 + len(interfaces) + len(functional)
    header = struct.pack("<BBHBBBBB", 9, DT_CONFIG, total, 1, 1, 0, 0xC0, 50)
    return header + interfaces + functional


def string_descriptor(text: str) -> bytes:
    encoded = text.encode("utf-16-le")
    return bytes([2 + len(encoded), DT_STRING]) + encoded


@dataclass
class Faults:
    """Faults to inject (each fires every time its condition holds, until changed)."""

    erase_fails_at: int | None = None
    """A page erase covering this address fails: dfuERROR, errERASE (flash unchanged)."""
    mass_erase_fails: bool = False
    write_fails_at: int | None = None
    """The data block covering this address fails: dfuERROR, errWRITE (nothing stored)."""
    corrupt_write_at: int | None = None
    """The data block covering this address is stored with this byte's lowest set bit
    cleared (a weak cell), and reported as written: a silent corruption."""
    vanish_after_blocks: int | None = None
    """The device drops off the bus once this many data blocks were written."""
    reset_before_leave_status: bool = False
    """On leave, the device resets before answering the GETSTATUS (some STM32 ROMs do)."""


@dataclass(frozen=True)
class Leave:
    """How the bootloader left: where it was told to go, where the chip started, and
    whether firmware runs."""

    address: int
    """The address pointer at the leave request."""
    jumped: bool
    """It jumped there (else it reset and booted from flash)."""
    vector_table: int
    """Where the firmware's vector table was taken from."""
    runs: bool
    """That vector table starts firmware (SP in SRAM, Thumb reset handler in flash)."""


@dataclass
class _Memory:
    base: int
    data: bytearray
    sectors: tuple[int, ...] | None
    """Sector sizes of an erasable memory (None: not erasable)."""
    writable: bool

    @property
    def end(self) -> int:
        return self.base + len(self.data)

    def sector_span(self, address: int) -> tuple[int, int] | None:
        """[start, end) of the sector holding `address`."""
        if self.sectors is None:
            return None
        start = self.base
        for size in self.sectors:
            if start <= address < start + size:
                return start, start + size
            start += size
        return None


@dataclass
class _Pending:
    """A DNLOAD waiting for its GETSTATUS."""

    kind: str
    address: int = 0
    data: bytes = b""


@dataclass
class Bootloader:
    """The bootloader: USB control requests in (`control`), flash and events out.

    Thread-safe: usbfs_host.py calls `control` from umockdev's worker thread while the
    test side reads the flash.
    """

    serial: str = SERIAL
    time_scale: float = 0.0
    """Poll timeouts and busy times are the modelled durations times this (0: none)."""
    faults: Faults = field(default_factory=Faults)
    read_protected: bool = False
    flash: bytearray = field(default_factory=lambda: bytearray(b"\xff" * FLASH_SIZE))
    events: list[tuple[object, ...]] = field(default_factory=list)
    """What the bootloader did: ("erase", sector start), ("mass_erase",), ("write", address,
    length), ("upload", address, length), ("error", status name), ("leave", Leave)..."""
    left: Leave | None = None
    gone: bool = False
    """Off the bus: vanished (fault), reset after Read Unprotect, or left."""

    def __post_init__(self) -> None:
        self.lock = threading.RLock()
        self.alt = 0
        self.state = State.dfuIDLE
        self.status = Status.OK
        self.pointer = FLASH_BASE
        self._pending: _Pending | None = None
        self._result = Status.OK
        self._busy_until = 0.0
        self._blocks_written = 0
        self._memories = [
            _Memory(FLASH_BASE, self.flash, FLASH_SECTORS, True),
            _Memory(OPTION_BYTES, bytearray(b"\xaa\xaa" + b"\xff" * 46), None, False),
            _Memory(OTP, bytearray(b"\xff" * 528), None, False),
            _Memory(DEVICE_FEATURE, bytearray(4), None, False),
        ]
        self.strings = [MANUFACTURER, PRODUCT, self.serial, *ALT_NAMES]

    # --- USB -------------------------------------------------------------------------------

    def set_alt(self, alt: int) -> None:
        with self.lock:
            self._check_present()
            if not 0 <= alt < len(ALT_NAMES):
                raise Stall(f"no alternate setting {alt}")
            self.alt = alt

    def control(self, setup: bytes, data: bytes = b"") -> bytes:
        """One control transfer: the 8-byte SETUP packet and, for OUT, its data; returns
        the IN data. Raises Stall (EPIPE) or Gone (ENODEV)."""
        request_type, request, value, index, length = struct.unpack("<BBHHH", setup)
        with self.lock:
            self._check_present()
            kind = (request_type >> 5) & 3
            if kind == 0:
                return self._standard(request_type, request, value, index, length)[:length]
            if kind == 1 and (request_type & 0x1F) == 1 and index == 0:
                return self._dfu(request, value, length, data)
            raise Stall(f"unsupported request type 0x{request_type:02x}")

    def _check_present(self) -> None:
        if self.gone:
            raise Gone("the device left the bus")

    def _standard(
        self, request_type: int, request: int, value: int, index: int, length: int
    ) -> bytes:
        if request == GET_DESCRIPTOR and request_type == 0x80:
            kind, number = value >> 8, value & 0xFF
            if kind == DT_DEVICE:
                return device_descriptor()
            if kind == DT_CONFIG and number == 0:
                return config_descriptor()
            if kind == DT_STRING:
                if number == 0:
                    return bytes([4, DT_STRING]) + struct.pack("<H", 0x0409)
                if 1 <= number <= len(self.strings):
                    return string_descriptor(self.strings[number - 1])
            raise Stall(f"no descriptor 0x{value:04x}")
        if request == GET_STATUS:
            return b"\x01\x00" if request_type == 0x80 else b"\x00\x00"  # self-powered
        if request == GET_CONFIGURATION:
            return b"\x01"
        if request == SET_CONFIGURATION and value == 1:
            return b""
        raise Stall(f"standard request 0x{request:02x} not supported")

    # --- DFU -------------------------------------------------------------------------------

    def _dfu(self, request: int, block: int, length: int, data: bytes) -> bytes:
        if request == DFU_GETSTATUS:
            return self._get_status()
        if request == DFU_GETSTATE:
            return bytes([self.state])
        if request == DFU_CLRSTATUS and self.state == State.dfuERROR:
            self.state, self.status = State.dfuIDLE, Status.OK
            return b""
        if request == DFU_ABORT and self.state in (
            State.dfuIDLE, State.dfuDNLOAD_IDLE, State.dfuUPLOAD_IDLE
        ):  # fmt: skip
            self.state = State.dfuIDLE
            return b""
        if request == DFU_DNLOAD and self.state in (State.dfuIDLE, State.dfuDNLOAD_IDLE):
            return self._download(block, data)
        if request == DFU_UPLOAD and self.state in (State.dfuIDLE, State.dfuUPLOAD_IDLE):
            return self._upload(block, length)
        return self._stall_error(f"DFU request {request} in state {self.state.name}")

    def _stall_error(self, why: str) -> bytes:
        self.state, self.status = State.dfuERROR, Status.errSTALLEDPKT
        self.events.append(("stall", why))
        raise Stall(why)

    def _download(self, block: int, data: bytes) -> bytes:
        if not data:
            self._pending = _Pending("leave", self.pointer)
            self.state = State.dfuMANIFEST_SYNC
            return b""
        if self.read_protected and not (block == 0 and data[:1] == bytes([READ_UNPROTECT])):
            raise Stall("read protection is active")
        if block == 0:
            command = data[0]
            if command in (SET_ADDRESS, ERASE) and len(data) == 5:
                address = struct.unpack("<I", data[1:5])[0]
                kind = "set_address" if command == SET_ADDRESS else "erase"
                self._pending = _Pending(kind, address)
            elif command == ERASE and len(data) == 1:
                self._pending = _Pending("mass_erase")
            elif command == READ_UNPROTECT and len(data) == 1:
                self._pending = _Pending("read_unprotect")
            else:
                return self._stall_error(f"unknown DfuSe command {data.hex()}")
        elif block >= 2:
            address = self.pointer + (block - 2) * TRANSFER_SIZE
            self._pending = _Pending("write", address, bytes(data))
        else:
            return self._stall_error("DNLOAD block 1")
        self.state = State.dfuDNLOAD_SYNC
        return b""

    def _upload(self, block: int, length: int) -> bytes:
        if self.read_protected:
            raise Stall("read protection is active")
        self.state = State.dfuUPLOAD_IDLE
        if block == 0:
            return bytes([GET_COMMANDS, SET_ADDRESS, ERASE, READ_UNPROTECT])[:length]
        if block == 1:
            return self._stall_error("UPLOAD block 1")
        address = self.pointer + (block - 2) * TRANSFER_SIZE
        memory = self._memory_for(address)
        if memory is None or address + length > memory.end:
            self.status = Status.errADDRESS
            return self._stall_error(f"UPLOAD of {length} bytes at 0x{address:08x}")
        self.events.append(("upload", address, length))
        offset = address - memory.base
        return bytes(memory.data[offset : offset + length])

    def _get_status(self) -> bytes:
        poll_s = 0.0
        if self.state == State.dfuDNLOAD_SYNC:
            assert self._pending is not None
            pending, self._pending = self._pending, None
            self._result, busy_s = self._execute(pending)
            poll_s = busy_s * self.time_scale
            self._busy_until = time.monotonic() + poll_s
            self.state = State.dfuDNBUSY
        elif self.state == State.dfuDNBUSY:
            wait = self._busy_until - time.monotonic()
            if wait > 0:
                time.sleep(wait)  # the device NAKs until the work is done
            if self._result == Status.OK:
                self.state = State.dfuDNLOAD_IDLE
            else:
                self.state, self.status = State.dfuERROR, self._result
                self.events.append(("error", self._result.name))
            if self.gone:  # vanished while busy (fault) or reset (read unprotect)
                raise Gone("the device left the bus")
        elif self.state == State.dfuMANIFEST_SYNC:
            assert self._pending is not None
            self._leave(self._pending.address)
            self._pending = None
            if self.faults.reset_before_leave_status:
                raise Gone("the device reset before answering")
            self.state = State.dfuMANIFEST
        poll_ms = min(int(poll_s * 1000 + 0.999), 0xFFFFFF)
        return struct.pack("<BI", self.status, poll_ms)[:4] + bytes([self.state, 0])

    def _execute(self, pending: _Pending) -> tuple[Status, float]:
        """Do a DfuSe command or write a block: (result, modelled duration in s)."""
        faults = self.faults
        if pending.kind == "set_address":
            if self._memory_for(pending.address) is None:
                return Status.errTARGET, 0.0
            self.pointer = pending.address
            return Status.OK, 0.0
        if pending.kind == "erase":
            span = self._memories[0].sector_span(pending.address) if self.alt == 0 else None
            if span is None:
                return Status.errTARGET, 0.0
            start, end = span
            if faults.erase_fails_at is not None and start <= faults.erase_fails_at < end:
                return Status.errERASE, ERASE_S[end - start]
            self.flash[start - FLASH_BASE : end - FLASH_BASE] = b"\xff" * (end - start)
            self.events.append(("erase", start))
            return Status.OK, ERASE_S[end - start]
        if pending.kind == "mass_erase":
            if self.alt != 0:
                return Status.errTARGET, 0.0
            if faults.mass_erase_fails:
                return Status.errERASE, MASS_ERASE_S
            self.flash[:] = b"\xff" * FLASH_SIZE
            self.events.append(("mass_erase",))
            return Status.OK, MASS_ERASE_S
        if pending.kind == "read_unprotect":
            self.flash[:] = b"\xff" * FLASH_SIZE
            self.read_protected = False
            self.events.append(("read_unprotect",))
            self.gone = True  # it resets once done
            return Status.OK, MASS_ERASE_S
        assert pending.kind == "write"
        return self._write(pending.address, pending.data)

    def _write(self, address: int, data: bytes) -> tuple[Status, float]:
        faults = self.faults
        memory = self._memory_for(address)
        end = address + len(data)
        if memory is None or end > memory.end or not memory.writable:
            return Status.errTARGET, 0.0
        busy_s = len(data) / 4 * PROGRAM_WORD_S
        if faults.write_fails_at is not None and address <= faults.write_fails_at < end:
            return Status.errWRITE, busy_s
        stored = bytearray(data)
        if faults.corrupt_write_at is not None and address <= faults.corrupt_write_at < end:
            byte = stored[faults.corrupt_write_at - address]
            stored[faults.corrupt_write_at - address] = byte & (byte - 1) if byte else 0
        offset = address - memory.base
        old = memory.data[offset : offset + len(data)]
        memory.data[offset : offset + len(data)] = bytes(a & b for a, b in zip(old, stored))
        self.events.append(("write", address, len(data)))
        self._blocks_written += 1
        if faults.vanish_after_blocks is not None and (
            self._blocks_written >= faults.vanish_after_blocks
        ):
            self.gone = True
            self.events.append(("vanished", address + len(data)))
        return Status.OK, busy_s

    def _memory_for(self, address: int) -> _Memory | None:
        memory = self._memories[self.alt]
        return memory if memory.base <= address < memory.end else None

    def _leave(self, address: int) -> None:
        jumped = self._vector_table(address)[0]
        start = address if jumped else FLASH_BASE
        runs = all(self._vector_table(start))
        self.left = Leave(address, jumped, start, runs)
        self.events.append(("leave", address, jumped, runs))
        self.gone = True

    def _vector_table(self, address: int) -> tuple[bool, bool]:
        """Whether the vector table at `address` has (a stack pointer in SRAM, a Thumb reset
        handler in flash)."""
        offset = address - FLASH_BASE
        if not 0 <= offset <= FLASH_SIZE - 8:
            return False, False
        stack, reset = struct.unpack("<II", self.flash[offset : offset + 8])
        return (
            SRAM[0] < stack <= SRAM[1] and stack % 4 == 0,
            reset & 1 == 1 and FLASH_BASE <= reset - 1 < FLASH_BASE + FLASH_SIZE,
        )
