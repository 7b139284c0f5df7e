"""The umockdev host of the EMULATED bootloader (tests/flash/dfuse_device.py): it puts the
device into a umockdev testbed (sysfs attributes and a /dev/bus/usb node) and answers the
usbfs ioctls that libusb sends on that node, so the unmodified dfu-util and libusb run
against it under `umockdev-wrapper`. Test scaffolding; started by tests/flash/emulator.py.

Runs under the system Python (PyGObject, UMockdev 1.0 typelib), so it uses the standard
library and dfuse_device.py only. Commands come as JSON lines on stdin, one JSON reply a
line on stdout. umockdev answers each ioctl in its worker thread (`UsbfsHandler`).

usbfs as the kernel does it for a full-speed device: control transfers are URBs (SUBMITURB,
then REAPURB/REAPURBNDELAY), each completed at submit and handed back at reap; a stall is
an URB status of -EPIPE; a device that left the bus fails new ioctls with ENODEV and the
URB in flight with -ESHUTDOWN. No driver is bound (GETDRIVER: ENODATA).
"""

from __future__ import annotations

import base64
import errno
import gc
import json
import struct
import sys
import threading
import traceback
from dataclasses import asdict, fields

import gi

gi.require_version("UMockdev", "1.0")
from gi.repository import UMockdev  # noqa: E402

from tests.flash.dfuse_device import (  # noqa: E402
    BCD_DEVICE,
    MANUFACTURER,
    PRODUCT,
    PRODUCT_ID,
    VENDOR_ID,
    Bootloader,
    Faults,
    Gone,
    Stall,
    config_descriptor,
    device_descriptor,
)

BUS = 1
USB_DEVICE_MAJOR = 189
USB_SPEED_FULL = 2
URB_TYPE_CONTROL = 2
URB_SIZE = 56
URB_STATUS, URB_BUFFER, URB_BUFFER_LENGTH, URB_ACTUAL_LENGTH = 4, 16, 24, 28
CAPABILITIES = 0x01 | 0x02 | 0x04 | 0x10
"""ZERO_PACKET, BULK_CONTINUATION, NO_PACKET_SIZE_LIM, REAP_AFTER_DISCONNECT."""


def _ioc(direction: int, number: int, size: int) -> int:
    return (direction << 30) | (size << 16) | (ord("U") << 8) | number


_NONE, _WRITE, _READ = 0, 1, 2
CONTROL = _ioc(_READ | _WRITE, 0, 24)
SETINTERFACE = _ioc(_READ, 4, 8)
SETCONFIGURATION = _ioc(_READ, 5, 4)
GETDRIVER = _ioc(_WRITE, 8, 260)
SUBMITURB = _ioc(_READ, 10, URB_SIZE)
DISCARDURB = _ioc(_NONE, 11, 0)
REAPURB = _ioc(_WRITE, 12, 8)
REAPURBNDELAY = _ioc(_WRITE, 13, 8)
CLAIMINTERFACE = _ioc(_READ, 15, 4)
RELEASEINTERFACE = _ioc(_READ, 16, 4)
CONNECTINFO = _ioc(_WRITE, 17, 8)
RESET = _ioc(_NONE, 20, 0)
CLEAR_HALT = _ioc(_READ, 21, 4)
GET_CAPABILITIES = _ioc(_READ, 26, 4)
DISCONNECT_CLAIM = _ioc(_READ, 27, 264)
GET_SPEED = _ioc(_NONE, 31, 0)


def _read(data: UMockdev.IoctlData) -> bytes:
    return bytes(data.retrieve())


class UsbfsHandler(UMockdev.IoctlBase):
    """Answers the usbfs ioctls of one attached device from `host.device`."""

    def __init__(self, host: Host, devnum: int) -> None:
        super().__init__()
        self.host = host
        self.devnum = devnum
        self.reapable: dict[UMockdev.IoctlClient, list[UMockdev.IoctlData]] = {}
        """Completed URBs by client (the key keeps PyGObject's wrapper, and so its identity)."""
        self.unknown: set[int] = set()

    def do_client_vanished(self, client: UMockdev.IoctlClient) -> None:
        self.reapable.pop(client, None)

    def do_handle_ioctl(self, client: UMockdev.IoctlClient) -> bool:
        try:
            result, error = self._ioctl(client)
        except Exception:
            traceback.print_exc(file=sys.stderr)
            result, error = -1, errno.EIO
        client.complete(result, error)
        return True

    def _ioctl(self, client: UMockdev.IoctlClient) -> tuple[int, int]:
        request = client.get_request()
        arg = client.get_arg()
        device = self.host.device
        queue = self.reapable.setdefault(client, [])
        if request in (REAPURB, REAPURBNDELAY):
            if not queue:
                return -1, (errno.ENODEV if self.host.gone(self) else errno.EAGAIN)
            slot = arg.resolve(0, 8)
            slot.set_ptr(0, queue.pop(0))
            return 0, 0
        if self.host.gone(self):
            return -1, errno.ENODEV
        if request == SUBMITURB:
            urb = arg.resolve(0, URB_SIZE)
            kind, _endpoint, _status, _flags, _buffer, length = struct.unpack(
                "<BBxxiI4xQi", _read(urb)[:28]
            )
            if kind != URB_TYPE_CONTROL or length < 8:
                return -1, errno.EINVAL
            buffer = urb.resolve(URB_BUFFER, length)
            setup = _read(buffer)[:8]
            status, reply = self._transfer(_read(buffer))
            if reply and setup[0] & 0x80:
                buffer.update(8, reply)
            urb.update(URB_STATUS, struct.pack("<i", status))
            urb.update(URB_ACTUAL_LENGTH, struct.pack("<i", len(reply) if status == 0 else 0))
            queue.append(urb)
            return 0, 0
        if request == CONTROL:
            transfer = arg.resolve(0, 24)
            setup = _read(transfer)[:8]
            length = struct.unpack("<H", setup[6:8])[0]
            buffer = transfer.resolve(16, length) if length else None
            status, reply = self._transfer(setup + (_read(buffer) if buffer else b""))
            if status:
                return -1, -status
            if reply and buffer is not None and setup[0] & 0x80:
                buffer.update(0, reply)
            return len(reply) if setup[0] & 0x80 else length, 0
        if request == GET_CAPABILITIES:
            arg.resolve(0, 4).update(0, struct.pack("<I", CAPABILITIES))
            return 0, 0
        if request == GET_SPEED:
            return USB_SPEED_FULL, 0
        if request == CONNECTINFO:
            arg.resolve(0, 8).update(0, struct.pack("<IB3x", self.devnum, 0))
            return 0, 0
        if request == GETDRIVER:
            return -1, errno.ENODATA
        if request in (CLAIMINTERFACE, RELEASEINTERFACE, DISCONNECT_CLAIM):
            interface = struct.unpack("<I", _read(arg.resolve(0, 4))[:4])[0]
            return (0, 0) if interface == 0 else (-1, errno.ENOENT)
        if request == SETINTERFACE:
            interface, alt = struct.unpack("<II", _read(arg.resolve(0, 8)))
            try:
                device.set_alt(alt)
            except Stall:
                return -1, errno.EINVAL
            except Gone:
                return -1, errno.ENODEV
            return (0, 0) if interface == 0 else (-1, errno.EINVAL)
        if request == SETCONFIGURATION:
            value = struct.unpack("<i", _read(arg.resolve(0, 4)))[0]
            return (0, 0) if value in (1, -1) else (-1, errno.EINVAL)
        if request in (RESET, CLEAR_HALT):
            return 0, 0
        if request == DISCARDURB:
            return -1, errno.EINVAL
        if request not in self.unknown:
            self.unknown.add(request)
            print(f"usbfs_host: ioctl 0x{request:08x} not emulated", file=sys.stderr)
        return -1, errno.ENOTTY

    def _transfer(self, packet: bytes) -> tuple[int, bytes]:
        """(URB status, data moved) of one control transfer: the SETUP packet and OUT data."""
        setup = packet[:8]
        length = struct.unpack("<H", setup[6:8])[0]
        try:
            if setup[0] & 0x80:
                return 0, self.host.device.control(setup)[:length]
            self.host.device.control(setup, packet[8 : 8 + length])
            return 0, packet[8 : 8 + length]
        except Stall:
            return -errno.EPIPE, b""
        except Gone:
            return -errno.ESHUTDOWN, b""
        finally:
            self.host.after_transfer(self)


class Host:
    """The testbed, the device in it (when attached) and the command loop."""

    def __init__(self) -> None:
        self.testbed = UMockdev.Testbed.new()
        self.device = Bootloader()
        self.lock = threading.RLock()
        self.handler: UsbfsHandler | None = None
        self.syspath: str | None = None
        self.devnode: str | None = None
        self.devnum = 1
        self.attaches = 0
        self._add_root_hub()

    def _add_root_hub(self) -> None:
        descriptors = struct.pack(
            "<BBHBBBBHHHBBBB", 18, 1, 0x0200, 9, 0, 1, 64, 0x1D6B, 0x0002, 0x0606, 3, 2, 1, 1
        ) + bytes.fromhex("09021900010100e0000904000001090000000705810304000c")
        self._add(
            "usb1", "0000:00:00.0", 1, descriptors,
            {"idVendor": "1d6b", "idProduct": "0002", "bcdDevice": "0606", "speed": "480",
             "bConfigurationValue": "1", "maxchild": "2", "product": "emulated root hub"},
        )  # fmt: skip

    def _add(
        self, name: str, parent: str, devnum: int, descriptors: bytes, attributes: dict[str, str]
    ) -> str:
        devnode = f"bus/usb/{BUS:03d}/{devnum:03d}"
        minor = (BUS - 1) * 128 + devnum - 1
        vendor, product = attributes["idVendor"], attributes["idProduct"]
        version = attributes["bcdDevice"]
        lines = [
            f"P: /devices/{parent}/{name}",
            f"N: {devnode}",
            f"E: DEVNAME=/dev/{devnode}",
            "E: DEVTYPE=usb_device",
            "E: DRIVER=usb",
            f"E: PRODUCT={int(vendor, 16):x}/{int(product, 16):x}/{int(version, 16):x}",
            "E: TYPE=0/0/0",
            f"E: BUSNUM={BUS:03d}",
            f"E: DEVNUM={devnum:03d}",
            f"E: MAJOR={USB_DEVICE_MAJOR}",
            f"E: MINOR={minor}",
            "E: SUBSYSTEM=usb",
            f"A: busnum={BUS}",
            f"A: devnum={devnum}",
            f"A: dev={USB_DEVICE_MAJOR}:{minor}",
            *(f"A: {key}={value}" for key, value in attributes.items()),
            f"H: descriptors={descriptors.hex().upper()}",
        ]
        self.testbed.add_from_string("\n".join(lines) + "\n")
        syspath = f"/sys/devices/{parent}/{name}"
        return syspath

    # --- the device on the bus -------------------------------------------------------------

    def attach(self) -> dict[str, object]:
        """The bootloader starts (a reset into system memory): volatile state anew, flash kept."""
        with self.lock:
            if self.syspath:
                raise ValueError("the device is attached already")
            old = self.device
            self.device = Bootloader(
                serial=old.serial,
                time_scale=old.time_scale,
                faults=old.faults,
                read_protected=old.read_protected,
                flash=old.flash,
                events=old.events,
            )
            self.devnum += 1
            self.attaches += 1
            attributes = {
                "idVendor": f"{VENDOR_ID:04x}", "idProduct": f"{PRODUCT_ID:04x}",
                "bcdDevice": f"{BCD_DEVICE:04x}", "speed": "12", "bConfigurationValue": "1",
                "bNumConfigurations": "1", "bNumInterfaces": " 1", "bMaxPacketSize0": "64",
                "version": " 2.00", "manufacturer": MANUFACTURER, "product": PRODUCT,
                "serial": self.device.serial, "devpath": "1", "maxchild": "0",
                "removable": "removable", "authorized": "1",
            }  # fmt: skip
            descriptors = device_descriptor() + config_descriptor()
            self.syspath = self._add(
                "1-1", "0000:00:00.0/usb1", self.devnum, descriptors, attributes
            )
            self.devnode = f"/dev/bus/usb/{BUS:03d}/{self.devnum:03d}"
            self.handler = UsbfsHandler(self, self.devnum)
            self.testbed.attach_ioctl(self.devnode, self.handler)
            self.device.events.append(("attached", self.devnum))
            return {"devnode": self.devnode}

    def detach(self) -> dict[str, object]:
        """The device leaves the bus (unplugged, reset, or jumped to the firmware)."""
        with self.lock:
            if self.syspath is None:
                return {"detached": False}
            self.testbed.remove_device(self.syspath)
            assert self.devnode is not None
            self.testbed.detach_ioctl(self.devnode)
            self.syspath = self.devnode = None
            self.handler = None
            self.device.gone = True
            self.device.events.append(("detached",))
            return {"detached": True}

    def gone(self, handler: UsbfsHandler) -> bool:
        return handler is not self.handler or self.device.gone

    def after_transfer(self, handler: UsbfsHandler) -> None:
        """A device that left the bus during a transfer is taken out of the testbed."""
        if handler is self.handler and self.device.gone:
            self.detach()

    # --- commands ----------------------------------------------------------------------------

    def command(self, request: dict[str, object]) -> dict[str, object]:
        op = request.pop("op")
        with self.lock, self.device.lock:
            device = self.device
            if op == "root":
                return {"root": self.testbed.get_root_dir()}
            if op == "attach":
                return self.attach()
            if op == "detach":
                return self.detach()
            if op == "configure":
                for key in ("serial", "time_scale", "read_protected"):
                    if key in request:
                        setattr(device, key, request[key])
                return {}
            if op == "faults":
                names = {f.name for f in fields(Faults)}
                if unknown := set(request) - names:
                    raise ValueError(f"unknown faults {sorted(unknown)}")
                device.faults = Faults(**request)  # type: ignore[arg-type]
                return {}
            if op == "load":
                data = base64.b64decode(str(request["flash"]))
                device.flash[:] = data
                return {}
            if op == "flash":
                return {"flash": base64.b64encode(bytes(device.flash)).decode()}
            if op == "status":
                return {
                    "attached": self.syspath is not None,
                    "attaches": self.attaches,
                    "left": asdict(device.left) if device.left else None,
                    "state": device.state.name,
                    "events": [list(event) for event in device.events],
                }
        raise ValueError(f"unknown command {op!r}")


def main() -> None:
    host = Host()
    root = host.testbed.get_root_dir()
    try:
        print(json.dumps({"root": root}), flush=True)
        for line in sys.stdin:
            try:
                reply = host.command(json.loads(line))
            except Exception as exc:
                reply = {"error": f"{type(exc).__name__}: {exc}"}
            print(json.dumps(reply), flush=True)
        host.detach()
    finally:
        # the testbed removes its root as it goes (once removed, its finalizer ends the process
        # with a fatal GLib error, SIGTRAP); the emulator removes what a killed host left
        del host
        gc.collect()


if __name__ == "__main__":
    main()
