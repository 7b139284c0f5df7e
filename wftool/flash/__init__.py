"""Flashing Betaflight onto STM32 flight controllers over USB DFU (dfu-util)."""
