"""Whoever holds the board's radio during preflight: a person at the transmitter, asked to flip
switches; the virtual FC's simulated radio, moved by wftool; or nobody (the OBC alone).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

from wftool.fc.modes import SWITCH_ENDS_US, AuxRange
from wftool.preflight.settings import BoardSettings
from wftool.sitl.radio import SimulatedRadio

LOW_US, MID_US = 1000, 1500


class Pilot(Protocol):
    """The override switch, the ARM switch and the transmitter of the board's radio."""

    simulated: bool
    """wftool moves the switches itself (and knows when): timings start at its move."""

    def hold(self, *, override: bool | None = None, armed: bool | None = None) -> None:
        """Put the switches there, sticks centred and still, throttle low (returns once the
        radio sends it)."""

    def transmitter(self, on: bool) -> bool:
        """Switch the transmitter on or off; False if this pilot cannot."""

    def stalls_since(self, since: float) -> list[float]:
        """Gaps (s) between the radio's frames since host time `since` long enough for the FC
        to count the radio lost though nobody took it away (a simulated radio's host
        stalled); none for a real radio, which wftool does not run."""


class HumanPilot:
    """A person at the transmitter, asked through `ask` (which returns when they are done)."""

    simulated = False

    def __init__(self, ask: Callable[[str], object]) -> None:
        self._ask = ask

    def hold(self, *, override: bool | None = None, armed: bool | None = None) -> None:
        wanted = []
        if armed is not None:
            wanted.append("ARM (props off!)" if armed else "disarm")
        if override is not None:
            wanted.append(f"override switch {'ON' if override else 'OFF'}")
        self._ask(", ".join(wanted) + "; sticks centred and still, throttle low")

    def transmitter(self, on: bool) -> bool:
        self._ask("transmitter ON" if on else "transmitter OFF (props off!)")
        return True

    def stalls_since(self, since: float) -> list[float]:
        return []


class NoPilot:
    """The OBC alone: nobody holds a radio."""

    simulated = True

    def hold(self, *, override: bool | None = None, armed: bool | None = None) -> None:
        pass

    def transmitter(self, on: bool) -> bool:
        return False

    def stalls_since(self, since: float) -> list[float]:
        return []


class RadioPilot:
    """The virtual FC's pilot: flips the switches of its simulated radio, where the FC's own
    mode ranges put them on (the middle of the range) and off (`AuxRange.off_us`), on the
    raw channels its map gives them; sticks centred, throttle low."""

    simulated = True

    def __init__(self, radio: SimulatedRadio, settings: BoardSettings) -> None:
        self.radio = radio
        self._settings = settings
        roll, pitch, yaw, throttle = settings.rcmap[:4]
        radio.set({roll: MID_US, pitch: MID_US, yaw: MID_US, throttle: LOW_US})

    def hold(self, *, override: bool | None = None, armed: bool | None = None) -> None:
        settings = self._settings
        changes = {}
        for wanted, switch in (
            (override, settings.override_switch),
            (armed, settings.arm_switch),
        ):
            if wanted is not None and switch is not None:
                changes[settings.raw_channel(switch.aux)] = switch_position(switch, wanted)
        self.radio.set(changes)
        time.sleep(2 * self.radio.frame_period_s)  # the next frame carries it

    def transmitter(self, on: bool) -> bool:
        self.radio.transmitting(on)
        return True

    def stalls_since(self, since: float) -> list[float]:
        return self.radio.stalls_since(since)


def switch_position(switch: AuxRange, on: bool) -> int:
    """Where a switch of range `switch` is on, or off (the switch end furthest from the
    range, for a range with no off position)."""
    if on:
        return switch.on_us
    if switch.off_us is not None:
        return switch.off_us
    low, high = SWITCH_ENDS_US
    return low if abs(low - switch.on_us) >= abs(high - switch.on_us) else high
