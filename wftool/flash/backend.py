"""The flash backend: one small base class, one subclass per tool (as Zephyr's west runners).

The flasher owns the flow (identify, back up, reboot to the bootloader, write, read back,
leave, confirm); a backend only finds the board in its bootloader and moves bytes.
`wftool.flash.dfu` is the one so far (dfu-util, the STM32 ROM bootloader).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Protocol

from wftool.flash.image import FlashLayout

Progress = Callable[[str, int, int], None]
"""Called with the phase (e.g. "Erase", "Download"), percent done and bytes done."""


class Device(Protocol):
    """A board in its bootloader, as a backend found it."""

    @property
    def name(self) -> str: ...

    @property
    def layout(self) -> FlashLayout | None:
        """The flash layout the bootloader reports, None if it reports none."""


class FlashBackend(ABC):
    """Writes, reads back and starts images in a board's flash through one tool."""

    @abstractmethod
    def wait_for_device(self, timeout: float) -> Device:
        """The board in its bootloader, once it shows up (`FlashError` after `timeout` s)."""

    @abstractmethod
    def write(
        self,
        device: Device,
        address: int,
        data: bytes,
        *,
        mass_erase: bool = False,
        progress: Progress | None = None,
    ) -> None:
        """Write `data` at `address`, erasing what it covers (`mass_erase`: the whole flash
        first)."""

    @abstractmethod
    def read(
        self, device: Device, address: int, length: int, *, progress: Progress | None = None
    ) -> bytes:
        """The `length` bytes at `address`, read back from the board."""

    @abstractmethod
    def leave(self, device: Device, address: int) -> str | None:
        """Leave the bootloader and start the image whose vector table is at `address`.
        Returns a remark for the log (something the tool said that is not a failure)."""
