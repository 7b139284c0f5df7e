"""Flashing Betaflight onto STM32 flight controllers: `flasher` runs the flow over a flash
backend (`backend.FlashBackend`; `dfu` is dfu-util over USB DFU), `image` knows the flash."""
