"""The virtual FC's pilot: a simulated radio on SITL's RC input (UDP, `feature RX_UDP`).

`feature RX_UDP` (Betaflight 2026.6) makes the simulator's RC port (UDP sim base + 4) a
receiver like a board's radio:
each packet (a double timestamp, 16 u16 channels in raw order) is one receiver frame, and
150 ms without one is RX loss. `SimulatedRadio` sends the channels it holds at a radio's
frame rate from a process of its own (as a radio does not stall when the program holding it
does), until stopped or its parent ends; a test or `wftool preflight` moves the sticks and
flips the switches with `set`, and takes the radio away with `transmitting(False)`.
`EngagingPilot` is the pilot `wftool sitl --pilot` flies with: it engages the OBC (spec §15)
whenever the FC reports it ready.

    python -m wftool.sitl.radio PORT RATE_HZ    # the transmitter: state lines on stdin
"""

from __future__ import annotations

import contextlib
import json
import os
import selectors
import socket
import struct
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import IO, Any

from wftool.fsp import Authority, UplinkFlag, UplinkStatus
from wftool.sitl.process import LOOPBACK

RC_CHANNELS = 16
_RC_PACKET = struct.Struct(f"<d{RC_CHANNELS}H")
STDIN = 0
DEFAULT_RATE_HZ = 100.0
"""Frames per second: an SBUS or CRSF radio's order of magnitude."""

RX_LOSS_MS = 150
"""Betaflight's RX loss delay for a receiver that stops (RXLOSS_TRIGGER_INTERVAL)."""
STALL_S = 0.8 * RX_LOSS_MS / 1000
"""A gap this long between two frames the transmitter meant to send in a row (its host
stalled it): the FC may have counted the radio lost. The transmitter reports each one."""
SYNC_S = 1.0
"""How long `SimulatedRadio.stalls_since` waits for the transmitter's next frame; one not
sent by then is a stall going on."""

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
        self._stalls: list[tuple[float, float]] = []
        """(when it ended, how long) of each stall the transmitter reported (`STALL_S`)."""
        self._heard = threading.Condition(self._lock)
        self._syncs = 0
        """Syncs asked of the transmitter, and the newest it answered (`stalls_since`)."""
        self._synced = 0
        self._reports_ended = False

    @property
    def frame_period_s(self) -> float:
        return 1.0 / self._rate_hz

    @property
    def channels(self) -> tuple[int, ...]:
        with self._lock:
            return tuple(self._channels)

    def set(
        self,
        values: Mapping[str, int] | Mapping[int, int] | None = None,
        hold_frames: int = 0,
        **named: int,
    ) -> None:
        """Move sticks and switches by name (`channel_index`): `set(roll=1300, aux2=2000)`,
        or by raw channel (0-based): `set({5: 2000})`. The next frame carries them, and at
        least `hold_frames` frames do before a later `set`'s values go out: a switch turned
        off and at once on again is on the air off, however late the host runs the
        transmitter (which otherwise sends only the newest values)."""
        indices = {channel_index(name): value for name, value in named.items()}
        for key, value in (values or {}).items():
            indices[key if isinstance(key, int) else channel_index(key)] = value
        with self._lock:
            for index, value in indices.items():
                self._channels[index] = value
            self._tell(hold_frames)

    def stalls_since(self, since: float) -> list[float]:
        """The gaps (s) between frames, each `STALL_S` or longer, that ended at or after
        `since` (the host's monotonic clock): the transmitter's host stalled it, and the FC
        may have counted the radio lost. Every gap that ended by the call is in: the
        transmitter reports it once the next frame went out, so this waits for the next
        tick's answer (up to `SYNC_S`: a transmitter silent that long is a stall going on,
        counted as the time waited)."""
        with self._lock:
            going_on = []
            if self._process is not None and not self._reports_ended:
                self._syncs += 1
                wanted = self._syncs
                asked = time.monotonic()
                with contextlib.suppress(OSError):  # one that ended answers with its end
                    self._write({"sync": wanted})
                if not self._heard.wait_for(
                    lambda: self._synced >= wanted or self._reports_ended, SYNC_S
                ):
                    going_on.append(time.monotonic() - asked)
            return [gap for ended, gap in self._stalls if ended >= since] + going_on

    def transmitting(self, on: bool) -> None:
        """Switch the transmitter on or off (off: no frames, the FC's RX loss follows)."""
        with self._lock:
            self._on = on
            self._tell()

    def start(self) -> SimulatedRadio:
        command = [sys.executable, "-m", "wftool.sitl.radio", str(self._port), str(self._rate_hz)]
        with self._lock:
            self._process = subprocess.Popen(  # its own session: a Ctrl-C is for the program
                command,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                start_new_session=True,
            )
            self._tell()
            reports = self._process.stdout
        threading.Thread(target=self._read_stalls, args=(reports,), daemon=True).start()
        return self

    def _read_stalls(self, reports: IO[str] | None) -> None:
        """Take the transmitter's stall reports and sync answers (a JSON line each) until it
        ends."""
        for line in reports or ():
            report = json.loads(line)
            with self._lock:
                if "synced" in report:
                    self._synced = report["synced"]
                else:
                    self._stalls.append((report["ended"], report["gap"]))
                self._heard.notify_all()
        with self._lock:
            self._reports_ended = True
            self._heard.notify_all()

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

    def _tell(self, hold_frames: int = 0) -> None:
        """Hand the state to the transmitter. Called with the lock held."""
        self._write({"channels": self._channels, "on": self._on, "frames": hold_frames})

    def _write(self, message: dict[str, Any]) -> None:
        """A line to the transmitter. Called with the lock held."""
        if self._process is None or self._process.stdin is None:
            return
        self._process.stdin.write(json.dumps(message) + "\n")
        self._process.stdin.flush()


def transmit(port: int, rate_hz: float) -> None:
    """The transmitter: a frame every 1/`rate_hz` s with the latest state read from stdin (a
    JSON line {"channels", "on", "frames"}), until stdin ends (stopped, or its parent gone);
    a state to hold for `frames` frames goes out in that many before the states after it.
    On stdout, a JSON line for each stall once the frame that ended it went out, and after
    the tick that follows a {"sync": n} line, {"synced": n}."""
    period = 1.0 / rate_hz
    channels, on = neutral_channels(), True
    states: deque[dict[str, Any]] = deque()
    held = 0
    pending = b""
    last_sent: float | None = None
    sync: int | None = None
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
                for line in lines:
                    message = json.loads(line)
                    if "sync" in message:
                        sync = message["sync"]
                    else:
                        states.append(message)
                continue
            while held == 0 and states:  # the newest state, or the first one to hold
                state = states.popleft()
                channels, on, held = state["channels"], state["on"], state["frames"]
            held = max(0, held - 1)
            if on:
                sent = time.monotonic()
                sock.sendto(_RC_PACKET.pack(sent - start, *channels), (LOOPBACK, port))
                if last_sent is not None and sent - last_sent >= STALL_S:
                    print(json.dumps({"ended": sent, "gap": sent - last_sent}), flush=True)
            last_sent = sent if on else None  # off is no stall: the radio taken away
            if sync is not None:  # after the stall this frame ended, if it did
                print(json.dumps({"synced": sync}), flush=True)
                sync = None
            next_send += period
            if next_send < time.monotonic() - period:  # the host stalled: no burst of stale frames
                next_send = time.monotonic()


class EngagingPilot:
    """A safety pilot who lets the OBC fly: whenever the FC's uplink status says the OBC is
    ready (spec §15) with the override switch (AUX`override_switch`, a `SimulatedRadio`'s) off,
    turns it on — the engagement only a pilot can make; ready with the switch on, turns it off
    first, and on once the FC shows it off. Says so through `say`, and when the OBC loses the
    sticks. `observe` takes each status as it comes (the live loop's reads) and never blocks.

    The pilot goes by the switch as the FC shows it (the status's `override` flag), never by
    how long ago it moved it: a loaded host reads statuses late and runs the transmitter late,
    and a switch turned on before the FC read it off is no turn at all."""

    OFF_FRAMES = 3
    """Radio frames the switch is off at least: the FC's RX task must read it off before on."""

    def __init__(
        self,
        radio: SimulatedRadio,
        override_switch: int = 2,
        say: Callable[[str], object] = lambda text: None,
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        self.radio = radio
        self._switch = f"aux{override_switch}"
        self._say = say
        self._now = now
        self._off_at: float | None = None
        """When the switch went off to be turned on (None: not waiting for the FC to see it)."""
        self._authority: Authority | None = None
        self.engagements = 0

    def observe(self, status: UplinkStatus | None) -> None:
        """The FC's newest uplink status (its `arrival_time` on the clock of `now`)."""
        if status is None or status.authority is None:
            return
        if status.authority is not self._authority:
            self._tell(status)
            self._authority = status.authority
        shown_on = status.has(UplinkFlag.OVERRIDE)
        if self._off_at is not None:
            if not shown_on and (status.arrival_time is None or status.arrival_time > self._off_at):
                self._switch_on()
            return
        if status.authority is not Authority.READY:
            return
        if not shown_on and self.radio.channels[channel_index(self._switch)] != LOW:
            return  # on, and the FC has not read it yet
        self._say(f"pilot: the OBC is ready; override switch {self._switch.upper()} off …")
        if shown_on:  # on before the OBC was ready, or a turn the FC refused (exit not_ready)
            self.radio.set({self._switch: LOW}, hold_frames=self.OFF_FRAMES)
            self._off_at = self._now()
        else:
            self._switch_on()

    def engage(self) -> None:
        """Turn the switch off and on now: for a pilot who sees the OBC is ready where wftool
        cannot (the user's OBC reads the stream). The radio sends `OFF_FRAMES` frames of the
        switch off between; that the FC read them only its status can tell (`observe`)."""
        self.radio.set({self._switch: LOW}, hold_frames=self.OFF_FRAMES)
        self._switch_on()

    def _switch_on(self) -> None:
        self.radio.set({self._switch: HIGH})
        self._off_at = None
        self.engagements += 1
        self._say(f"pilot: override switch {self._switch.upper()} on: engaging the OBC")

    def _tell(self, status: UplinkStatus) -> None:
        authority = status.authority
        if authority is Authority.ENGAGED:
            self._say("pilot: the OBC is engaged: it steers the sticks")
        elif self._authority is Authority.ENGAGED:
            why = status.exit.name.lower().replace("_", " ") if status.exit is not None else "?"
            self._say(f"pilot: the OBC lost the sticks ({why}): the pilot flies")


if __name__ == "__main__":
    transmit(int(sys.argv[1]), float(sys.argv[2]))
