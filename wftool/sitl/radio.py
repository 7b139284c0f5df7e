"""The virtual FC's pilot: a simulated radio on SITL's RC input (UDP, `feature RX_UDP`).

Patch 0017 makes the simulator's RC port (UDP sim base + 4) a receiver like a board's radio:
each packet (a double timestamp, 16 u16 channels in raw order) is one receiver frame, and
150 ms without one is RX loss. `SimulatedRadio` sends the channels it holds at a radio's
frame rate from a daemon thread; a test or `wftool preflight` moves the sticks and flips the
switches with `set`, and takes the radio away with `transmitting(False)`.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Mapping

from wftool.sitl.process import LOOPBACK

RC_CHANNELS = 16
_RC_PACKET = struct.Struct(f"<d{RC_CHANNELS}H")
DEFAULT_RATE_HZ = 100.0
"""Frames per second: an SBUS or CRSF radio's order of magnitude."""

CHANNEL_NAMES = ("roll", "pitch", "throttle", "yaw")
"""Raw channels 1-4 under Betaflight's default map AETR1234; then AUX1, AUX2, ..."""
LOW, MID, HIGH = 1000, 1500, 2000


def channel_index(name: str) -> int:
    """The raw channel (0-based) of "roll", "pitch", "throttle", "yaw" (AETR1234) or "auxN"."""
    lowered = name.lower()
    if lowered in CHANNEL_NAMES:
        return CHANNEL_NAMES.index(lowered)
    if lowered.startswith("aux") and lowered[3:].isdigit():
        index = 3 + int(lowered[3:])
        if 4 <= index < RC_CHANNELS:
            return index
    raise ValueError(f"no radio channel {name!r} (roll, pitch, throttle, yaw, aux1-aux12)")


def neutral_channels() -> list[int]:
    """Sticks centred, throttle low, every switch low (off)."""
    channels = [LOW] * RC_CHANNELS
    channels[channel_index("roll")] = channels[channel_index("pitch")] = MID
    channels[channel_index("yaw")] = MID
    return channels


class SimulatedRadio:
    """Sends RC frames to a virtual FC's RC input until stopped. Thread-safe setters."""

    def __init__(self, port: int, rate_hz: float = DEFAULT_RATE_HZ) -> None:
        """`port`: SITL's RC input (`VirtualFC.sim_rc_port`)."""
        self._port = port
        self._period = 1.0 / rate_hz
        self._lock = threading.Lock()
        self._channels = neutral_channels()
        self._on = threading.Event()
        self._on.set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sitl-radio", daemon=True)
        self.frames_sent = 0

    @property
    def frame_period_s(self) -> float:
        return self._period

    @property
    def channels(self) -> tuple[int, ...]:
        with self._lock:
            return tuple(self._channels)

    def set(self, values: Mapping[str, int] | None = None, **named: int) -> None:
        """Move sticks and switches by name (`channel_index`): `set(roll=1300, aux2=2000)`.
        The next frame carries them."""
        changes = {**(values or {}), **named}
        indices = {channel_index(name): value for name, value in changes.items()}
        with self._lock:
            for index, value in indices.items():
                self._channels[index] = value

    def transmitting(self, on: bool) -> None:
        """Switch the transmitter on or off (off: no frames, the FC's RX loss follows)."""
        if on:
            self._on.set()
        else:
            self._on.clear()

    def start(self) -> SimulatedRadio:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def __enter__(self) -> SimulatedRadio:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _run(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            start = next_send = time.monotonic()
            while not self._stop.is_set():
                if self._on.is_set():
                    with self._lock:
                        packet = _RC_PACKET.pack(time.monotonic() - start, *self._channels)
                    sock.sendto(packet, (LOOPBACK, self._port))
                    self.frames_sent += 1
                next_send += self._period
                delay = next_send - time.monotonic()
                if delay < -self._period:  # the host stalled: no burst of stale frames
                    next_send = time.monotonic()
                self._stop.wait(max(0.0, delay))


class SimulatedPilot:
    """`wftool preflight`'s pilot on the virtual FC (`verify.preflight.Pilot`): moves the
    switches of a `SimulatedRadio` itself, sticks centred and throttle low."""

    simulated = True

    def __init__(self, radio: SimulatedRadio, override_switch: int = 2, arm_switch: int = 1):
        self.radio = radio
        self._override = f"aux{override_switch}"
        self._arm = f"aux{arm_switch}"

    def hold(self, *, override: bool | None = None, armed: bool | None = None) -> None:
        changes = {}
        if override is not None:
            changes[self._override] = HIGH if override else LOW
        if armed is not None:
            changes[self._arm] = HIGH if armed else LOW
        self.radio.set(changes)
        time.sleep(2 * self.radio.frame_period_s)  # the next frame carries it

    def transmitter(self, on: bool) -> bool:
        self.radio.transmitting(on)
        return True
