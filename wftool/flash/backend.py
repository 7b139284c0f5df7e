"""The flash backend: one small base class, one subclass per tool (as Zephyr's west runners).

The flasher owns the flow (identify, back up, reboot to the bootloader, confirm); a
backend only finds the board in its bootloader and writes regions. `wftool.flash.dfu`
is the one so far (dfu-util, the STM32 ROM bootloader).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path
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
    """Writes images into a board's flash through one tool."""

    @abstractmethod
    def wait_for_device(self, timeout: float) -> Device:
        """The board in its bootloader, once it shows up (`FlashError` after `timeout` s)."""

    @abstractmethod
    def write(
        self,
        device: Device,
        address: int,
        image_file: Path,
        *,
        leave: bool,
        mass_erase: bool = False,
        progress: Progress | None = None,
    ) -> str | None:
        """Write `image_file` at `address`; `leave` then starts the firmware. Returns a
        remark for the log (something the tool said that is not a failure), or None."""
