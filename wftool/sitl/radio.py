"""The virtual FC's pilot: a simulated radio on SITL's RC input (UDP, `feature RX_UDP`).

`feature RX_UDP` (Betaflight 2026.6) makes the simulator's RC port (UDP sim base + 4) a
receiver like a board's radio:
each packet (a double timestamp, 16 u16 channels in raw order) is one receiver frame, and
150 ms without one is RX loss. `SimulatedRadio` sends the channels it holds at a radio's
frame rate from a process of its own (as a radio does not stall when the program holding it
does), until stopped or its parent ends; a test or `wftool preflight` moves the sticks and
flips the switches with `set`, and takes the radio away with `transmitting(False)`.

    python -m wftool.sitl.radio PORT RATE_HZ    # the transmitter: state lines on stdin
"""

from __future__ import annotations

import json
import os
import selectors
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Mapping

from wftool.sitl.process import LOOPBACK

RC_CHANNELS = 16
_RC_PACKET = struct.Struct(f"<d{RC_CHANNELS}H")
STDIN = 0
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
        self._rate_hz = rate_hz
        self._lock = threading.Lock()
        self._channels = neutral_channels()
        self._on = True
        self._process: subprocess.Popen[str] | None = None

    @property
    def frame_period_s(self) -> float:
        return 1.0 / self._rate_hz

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
            self._tell()

    def transmitting(self, on: bool) -> None:
        """Switch the transmitter on or off (off: no frames, the FC's RX loss follows)."""
        with self._lock:
            self._on = on
            self._tell()

    def start(self) -> SimulatedRadio:
        command = [sys.executable, "-m", "wftool.sitl.radio", str(self._port), str(self._rate_hz)]
        with self._lock:
            self._process = subprocess.Popen(  # its own session: a Ctrl-C is for the program
                command, stdin=subprocess.PIPE, text=True, start_new_session=True
            )
            self._tell()
        return self

    def stop(self) -> None:
        with self._lock:
            process, self._process = self._process, None
        if process is None:
            return
        assert process.stdin is not None
        try:
            process.stdin.close()  # the transmitter ends at the end of its input
            process.wait(2.0)
        except (OSError, subprocess.TimeoutExpired):
            process.kill()
            process.wait()

    def __enter__(self) -> SimulatedRadio:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _tell(self) -> None:
        """Hand the state to the transmitter. Called with the lock held."""
        if self._process is None or self._process.stdin is None:
            return
        state = json.dumps({"channels": self._channels, "on": self._on})
        self._process.stdin.write(state + "\n")
        self._process.stdin.flush()


def transmit(port: int, rate_hz: float) -> None:
    """The transmitter: a frame every 1/`rate_hz` s with the latest state read from stdin (a
    JSON line {"channels", "on"}), until stdin ends (stopped, or its parent gone)."""
    period = 1.0 / rate_hz
    channels, on = neutral_channels(), True
    pending = b""
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock,
        selectors.DefaultSelector() as sel,
    ):
        sel.register(STDIN, selectors.EVENT_READ)
        start = next_send = time.monotonic()
        while True:
            if sel.select(max(0.0, next_send - time.monotonic())):
                chunk = os.read(STDIN, 65536)  # unbuffered: a selector sees what is left
                if not chunk:
                    return
                *lines, pending = (pending + chunk).split(b"\n")
                if lines:
                    state = json.loads(lines[-1])
                    channels, on = state["channels"], state["on"]
                continue
            if on:
                sock.sendto(_RC_PACKET.pack(time.monotonic() - start, *channels), (LOOPBACK, port))
            next_send += period
            if next_send < time.monotonic() - period:  # the host stalled: no burst of stale frames
                next_send = time.monotonic()


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


if __name__ == "__main__":
    transmit(int(sys.argv[1]), float(sys.argv[2]))
