"""`wftool preflight`: does the board fail safe when the OBC dies, stalls, repeats itself or lies?

Run on the board itself (props off) or on the virtual FC. wftool plays the OBC on the FSP port
(`Obc`: fresh commands, then silence, a closed port, the last packet repeated byte for byte,
garbage, or older packets replayed) and reads what the FC makes of it over MSP (`FcWatcher`:
MSP_RC and MSP_STATUS_EX in turn, every ~2 ms): the sticks, RXLOSS (arming disable flag
RX_FAILSAFE), failsafe stage 2 (the FAILSAFE mode), MSP OVERRIDE and arming. The pilot is a
`Pilot`: the virtual FC's simulated radio, moved by wftool, or a human at the transmitter,
asked to flip switches.

What it checks depends on who flies (spec §5, §11; `configure fsp`):

- safety pilot (the radio is the receiver): with the override switch on before any fresh
  command nothing moves; fresh commands fly the sticks and nothing else; after each failure
  the pilot's stick values are back within the limit and stay, the FC still armed, no RXLOSS;
  the switch off gives the sticks back; without the pilot's radio the FC fails safe even
  while the OBC sends (virtual FC only).
- OBC alone (the MSP receiver): fresh commands fly the FC; after each failure RXLOSS comes
  within the limit; armed (`arm`), failsafe stage 2 follows at `failsafe_delay`.

Every timing is from the write of the last fresh command to the MSP reply that shows the
change (an upper bound: the FC changed before the reply arrived).
"""

from __future__ import annotations

import os
import random
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from wftool.errors import PortError, ProtocolError
from wftool.fc.msp import FEATURE_RX_MSP, MspClient
from wftool.fc.versions import version_of
from wftool.fsp.decoder import StateDecoder
from wftool.fsp.encoder import CommandSender
from wftool.fsp.packets import UplinkFlag, UplinkStatus
from wftool.fsp.reader import DEFAULT_BAUDRATE
from wftool.fsp.twoway import RoundTrip
from wftool.link.transport import Port, open_port, read_within, selectable_fd
from wftool.progress import Log, quiet

MSP_MODE_RANGES = 34
MSP_FEATURE_CONFIG = 36
MSP_FAILSAFE_CONFIG = 75
MSP_RC = 105
MSP_BOXIDS = 119
MSP_STATUS_EX = 150
BOX_ARM = 0
BOX_FAILSAFE = 27
BOX_MSP_OVERRIDE = 50
STICKS = 4
"""MSP_RC's first channels: roll, pitch, yaw, throttle."""
FAILSAFE_LANDING = 2
"""Betaflight's failsafe phases from here on are stage 2 (`FAILSAFE_PHASES`)."""
RX_LOSS_MS = 150
"""Betaflight's RX loss delay for a receiver that stops (RXLOSS_TRIGGER_INTERVAL)."""

LIMIT_MS = 100.0
"""The pilot's sticks back, or RXLOSS, within this long after the OBC's last fresh command."""
COMMAND_RATE_HZ = 100.0
HOLD_S = 0.5
"""How long the FC must stay safe while a failure goes on."""
TAKEOVER_S = 0.4
"""Fresh commands before each failure, so the OBC is in control when it fails."""
WAIT_S = 5.0
"""How long preflight waits for what it asked of the FC before it says "never" (timings are
judged against their limits, not this)."""
LINK_UP_S = 10.0
"""An OBC-alone FC needs `failsafe_recovery_delay` of commands before the link counts as up
(a wait, not a limit: a virtual FC on a busy host runs slow)."""
TOLERANCE_US = 10
"""A stick within this of the pilot's value is the pilot's (a real radio's values jitter)."""

FAILURES = {
    "stopped": "OBC stopped (port open)",
    "closed": "OBC killed (port closed)",
    "garbage": "OBC sends garbage",
    "replay": "OBC replays old packets",
    "stuck": "OBC stuck (repeats its last packet)",
}
"""The failures the OBC plays, by name: what `Obc.behave` takes besides "fresh"."""


@dataclass(frozen=True)
class Line:
    """One line of the report: a check, what was measured, its limit, whether it passed."""

    name: str
    measured: str
    limit: str
    passed: bool


@dataclass
class PreflightReport:
    mode: str
    """"safety pilot" or "OBC alone"."""
    lines: list[Line] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(line.passed for line in self.lines)

    @property
    def failed(self) -> list[Line]:
        return [line for line in self.lines if not line.passed]

    def add(self, name: str, measured: str, limit: str, passed: bool) -> Line:
        line = Line(name, measured, limit, passed)
        self.lines.append(line)
        return line

    def timing(self, name: str, ms: float | None, limit_ms: float) -> Line:
        """A line for a time that must not exceed `limit_ms` (None: it never happened)."""
        measured = "never" if ms is None else f"{ms:.1f} ms"
        return self.add(name, measured, f"≤ {limit_ms:.0f} ms", ms is not None and ms <= limit_ms)


# -- the FC, over MSP ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Snapshot:
    """What the FC reported by one MSP reply (and the latest of the other kind before it)."""

    t: float
    """Host `time.monotonic()` when the reply arrived."""
    rc: tuple[int, ...]
    """MSP_RC: rcData in Betaflight's order (roll, pitch, yaw, throttle, AUX1, ...)."""
    armed: bool
    override: bool
    failsafe: bool
    """Failsafe stage 2 (the FAILSAFE mode)."""
    rx_loss: bool
    """RXLOSS: the arming disable flag RX_FAILSAFE."""
    arming_flags: int
    """Betaflight's arming disable flags (`armingDisableFlags_e`)."""
    arming_blockers: int
    """The arming disable flags but the ARM switch's own (which only says the switch was on
    while the others held)."""

    @property
    def can_arm(self) -> bool:
        """Nothing but the ARM switch itself keeps the FC from arming."""
        return self.arming_blockers == 0


def parse_status_ex(payload: bytes) -> tuple[int, int, int]:
    """MSP_STATUS_EX → (the active-box bits, in MSP_BOXIDS order; the arming disable flags;
    how many such flags the firmware has)."""
    if len(payload) < 16:
        raise ProtocolError(f"MSP_STATUS_EX of {len(payload)} bytes")
    (boxes,) = struct.unpack_from("<I", payload, 6)
    extra = payload[15]
    boxes |= int.from_bytes(payload[16 : 16 + extra], "little") << 32
    if len(payload) < 21 + extra:
        raise ProtocolError(f"MSP_STATUS_EX of {len(payload)} bytes")
    count = payload[16 + extra]
    (arming,) = struct.unpack_from("<I", payload, 17 + extra)
    return boxes, arming, count


@dataclass(frozen=True)
class ModeRange:
    mode: int
    """Permanent mode id."""
    channel: int
    """0 = AUX1."""
    start: int
    end: int


def parse_mode_ranges(payload: bytes) -> list[ModeRange]:
    """MSP_MODE_RANGES: the usable ones (start < end), values in µs."""
    ranges = []
    for offset in range(0, len(payload) - 3, 4):
        mode, channel, start, end = payload[offset : offset + 4]
        if start < end:
            ranges.append(ModeRange(mode, channel, 900 + 25 * start, 900 + 25 * end))
    return ranges


class FcWatcher:
    """MSP_RC and MSP_STATUS_EX in turn, from a thread, as fast as the FC answers; every
    reply kept as a `Snapshot`."""

    def __init__(self, msp: MspClient) -> None:
        self._msp = msp
        self._msp_lock = threading.Lock()
        self.version = version_of(msp.identify())
        """The FC's Betaflight: where its arming disable flags are."""
        boxes = list(msp.request(MSP_BOXIDS))
        self._bit = {
            box: boxes.index(box)
            for box in (BOX_ARM, BOX_FAILSAFE, BOX_MSP_OVERRIDE)
            if box in boxes
        }
        self.has_override = BOX_MSP_OVERRIDE in self._bit
        self.snapshots: list[Snapshot] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="preflight-msp", daemon=True)

    def start(self) -> FcWatcher:
        self._thread.start()
        self.wait(lambda s: True, time.monotonic(), 2.0)
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        rc: tuple[int, ...] = ()
        boxes = arming = 0
        try:
            while not self._stop.is_set():
                payload = self.request(MSP_RC)
                rc = struct.unpack(f"<{len(payload) // 2}H", payload)
                self._record(rc, boxes, arming)
                boxes, arming, count = parse_status_ex(self.request(MSP_STATUS_EX))
                if count != len(self.version.arming_disable_flags):
                    raise ProtocolError(
                        f"the FC has {count} arming disable flags, "
                        f"{self.version.name} {len(self.version.arming_disable_flags)}"
                    )
                self._record(rc, boxes, arming)
        except BaseException as exc:  # reported by the next wait
            self._error = exc

    def request(self, cmd: int) -> bytes:
        """One MSP exchange, between the watcher's own."""
        with self._msp_lock:
            return self._msp.request(cmd, timeout=WAIT_S)

    def _record(self, rc: tuple[int, ...], boxes: int, arming: int) -> None:
        if not rc:
            return

        def on(box: int) -> bool:
            return box in self._bit and bool(boxes >> self._bit[box] & 1)

        snapshot = Snapshot(
            time.monotonic(), rc, on(BOX_ARM), on(BOX_MSP_OVERRIDE), on(BOX_FAILSAFE),
            bool(arming & self.version.rx_failsafe_flag), arming,
            arming & ~self.version.arm_switch_flag,
        )  # fmt: skip
        with self._lock:
            self.snapshots.append(snapshot)

    def latest(self) -> Snapshot:
        self.wait(lambda s: True, time.monotonic(), 2.0)
        with self._lock:
            return self.snapshots[-1]

    def since(self, t: float) -> list[Snapshot]:
        with self._lock:
            return [s for s in self.snapshots if s.t > t]

    def wait(
        self, predicate: Callable[[Snapshot], bool], since: float, timeout: float
    ) -> Snapshot | None:
        """The first snapshot after `since` for which `predicate` holds, waiting up to
        `timeout` seconds from now; None if none came."""
        deadline = time.monotonic() + timeout
        seen = 0
        while True:
            if self._error is not None:
                raise ProtocolError(f"reading the FC over MSP: {self._error}")
            with self._lock:
                fresh = self.snapshots[seen:]
                seen = len(self.snapshots)
            for snapshot in fresh:
                if snapshot.t > since and predicate(snapshot):
                    return snapshot
            if time.monotonic() > deadline:
                return None
            time.sleep(0.001)


# -- the OBC, on the FSP port ----------------------------------------------------------------------


class Obc:
    """wftool as the OBC: sends commands at `rate_hz` and plays the failures of `FAILURES`;
    reads the stream alongside: the FC's uplink statuses (E3), its time replies (E2, if it
    sends them) and the frames' sticks, each with its FC time — how long the firmware took,
    whatever the host's scheduling (`fc_elapsed_us`)."""

    def __init__(
        self,
        url: str,
        baudrate: int = DEFAULT_BAUDRATE,
        rate_hz: float = COMMAND_RATE_HZ,
        *,
        closing: Callable[[Callable[[], None]], object] | None = None,
    ):
        """`closing(close)` closes the port when the OBC is killed (default: `close()`); the
        virtual FC's waits until SITL has let go of the connection (`VirtualFC.close_client`),
        so the new one is not dropped."""
        self.url = url
        self._closing = closing
        self.baudrate = baudrate
        self._period = 1.0 / rate_hz
        self.decoder = StateDecoder(time_replies=True)
        matcher = self.decoder.round_trips
        assert matcher is not None
        matcher.on_round_trip = self._answered
        self._sender = CommandSender(round_trips=matcher)
        self._taken: dict[float, int] = {}
        """OBC send time of a command → FC time (µs) it was taken, by its time reply."""
        self.frames: list[tuple[int, tuple[int, ...]]] = []
        """(FC time in µs, sticks roll, pitch, yaw, throttle) of every frame read."""
        self.statuses: list[UplinkStatus] = []
        """Every uplink status read, placed on the FC clock (`sent_us`) where it could be."""
        self.last_fresh_sent = 0.0
        """The OBC time stamped on the last fresh command."""
        self._port: Port | None = None
        self._fd: int | None = None
        self._lock = threading.Lock()
        self._mode = "stopped"
        self._rc: tuple[int, ...] = (1500, 1500, 1500, 1000, 1000, 1000)
        self._sent: list[bytes] = []
        self.last_fresh_t = 0.0
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._random = random.Random(os.urandom(8))
        self._thread = threading.Thread(target=self._run, name="preflight-obc", daemon=True)

    @property
    def status(self) -> UplinkStatus | None:
        """The FC's newest uplink status (E3)."""
        return self.decoder.uplink_status

    def start(self) -> Obc:
        self._open()
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._close()

    def _open(self) -> None:
        port = open_port(self.url, self.baudrate, timeout=0)
        self._port, self._fd = port, selectable_fd(port)
        self.decoder.resync()

    def _close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def behave(self, mode: str, rc: Sequence[int] | None = None) -> float:
        """Send fresh commands carrying `rc` ("fresh"), or play a failure (`FAILURES`) from now
        on; the host time the last fresh command was written.

        "closed" is the OBC killed: it stops sending, its port closes (once the FC answered
        the last command, if it answers: 20 ms at most) and a new connection (another OBC
        program, say) stays silent — the FC sees silence either way, and the uplink statuses
        that come then say when it stopped taking commands (`fc_timed_out_us`)."""
        if mode != "fresh" and mode not in FAILURES:
            raise ValueError(f"no OBC behaviour {mode!r}")
        with self._lock:
            if rc is not None:
                self._rc = tuple(rc)
            self._mode = mode
            last = self.last_fresh_t
            if self._port is None:
                self._open()
        if mode == "closed":
            deadline = time.monotonic() + 0.02
            while self.fc_taken_us() is None and time.monotonic() < deadline:
                time.sleep(0.001)
            with self._lock:
                if self._closing is None:
                    self._close()
                else:
                    self._closing(self._close)
                self._open()
        return last

    def send_one(self, rc: Sequence[int]) -> None:
        """One command, alone (the FC takes no command from one packet: spec §11)."""
        with self._lock:
            self._mode = "stopped"
            self._write(self._sender.encode(rc))

    def _write(self, data: bytes) -> None:
        assert self._port is not None
        self._port.write(data)

    def _run(self) -> None:
        next_t = time.monotonic()
        try:
            while not self._stop.is_set():
                with self._lock:
                    self._tick()
                next_t += self._period
                while (left := next_t - time.monotonic()) > 0 and not self._stop.is_set():
                    self._read(min(left, 0.005))
        except BaseException as exc:
            self._error = exc

    def _read(self, timeout: float) -> None:
        with self._lock:
            port = self._port
            if port is not None:
                data = read_within(port, self._fd, 0)
                if data:
                    before = self.decoder.stats.uplink_statuses
                    for packet in self.decoder.feed(data, time.monotonic()):
                        self.frames += [(f.time_us or 0, f.rc[:STICKS]) for f in packet.frames]
                    if self.decoder.stats.uplink_statuses != before and self.status is not None:
                        self.statuses.append(self.status)
        time.sleep(timeout)

    def _answered(self, trip: RoundTrip) -> None:
        self._taken[trip.obc_sent] = trip.fc_received_us

    def fc_taken_us(self) -> int | None:
        """FC time (µs, the stream's) the last fresh command was taken; None if the FC did
        not answer it (`fsp_time_reply` OFF)."""
        with self._lock:
            return self._taken.get(self.last_fresh_sent)

    def wait_fc_elapsed_us(
        self,
        timeout: float = WAIT_S,
        *,
        timed_out: bool = False,
        sticks: Callable[[tuple[int, ...]], bool] | None = None,
        status: Callable[[UplinkStatus], bool] | None = None,
    ) -> int | None:
        """FC microseconds from the last fresh command (its time reply) to what `sticks` or
        `status` asks (`fc_elapsed_us`), or to the FC's timeout (`timed_out`), once the
        stream has brought it; None if it did not within `timeout` seconds."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            taken = self.fc_taken_us()
            if taken is not None:
                if timed_out:
                    us = self.fc_timed_out_us(taken)
                else:
                    us = self.fc_elapsed_us(taken, sticks, status)
                if us is not None:
                    return us
            time.sleep(0.01)
        return None

    def fc_timed_out_us(self, since_us: int) -> int | None:
        """FC microseconds from `since_us` to the timeout an uplink status reports after it;
        None if none was read (yet)."""
        with self._lock:
            times = [
                s.timed_out_at_us for s in self.statuses
                if s.timed_out_at_us is not None and s.timed_out_at_us > since_us
            ]  # fmt: skip
        return times[0] - since_us if times else None

    def fc_elapsed_us(
        self,
        since_us: int,
        sticks: Callable[[tuple[int, ...]], bool] | None = None,
        status: Callable[[UplinkStatus], bool] | None = None,
    ) -> int | None:
        """FC microseconds from `since_us` to the first frame whose sticks satisfy `sticks`,
        or the first status for which `status` holds; None if none was read (yet)."""
        with self._lock:
            if sticks is not None:
                times = [t for t, rc in self.frames if t > since_us and sticks(rc)]
            else:
                assert status is not None
                times = [
                    s.sent_us for s in self.statuses
                    if s.sent_us is not None and s.sent_us > since_us and status(s)
                ]  # fmt: skip
        return times[0] - since_us if times else None

    def _tick(self) -> None:
        mode = self._mode
        if mode == "fresh":
            sent = time.monotonic()
            packet = self._sender.encode(self._rc, sent)
            self._write(packet)
            self.last_fresh_sent, self.last_fresh_t = sent, time.monotonic()
            self._sent = [*self._sent[-49:], packet]
        elif mode == "stuck" and self._sent:
            self._write(self._sent[-1])
        elif mode == "replay" and self._sent:
            self._write(self._random.choice(self._sent[:-1] or self._sent))
        elif mode == "garbage":
            junk = bytearray(self._random.randbytes(30))
            junk[self._random.randrange(8, 30)] = 0  # chunks of any length, most not 25
            self._write(bytes(junk))

    def check(self) -> None:
        if self._error is not None:
            raise PortError(f"{self.url}: {self._error}")


# -- the pilot -----------------------------------------------------------------------------------


class Pilot(Protocol):
    """Whoever holds the board's radio: the override switch, the ARM switch, the transmitter."""

    simulated: bool

    def hold(self, *, override: bool | None = None, armed: bool | None = None) -> None:
        """Put the switches there and keep the sticks still (returns once they are)."""

    def transmitter(self, on: bool) -> bool:
        """Switch the transmitter on or off; False if this pilot cannot."""


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
        return False


class NoPilot:
    """The OBC alone: nobody holds a radio."""

    simulated = True

    def hold(self, *, override: bool | None = None, armed: bool | None = None) -> None:
        pass

    def transmitter(self, on: bool) -> bool:
        return False


# -- the checks ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Setup:
    """What preflight needs to know about the FC, read over MSP and from the uplink status."""

    obc_alone: bool
    timeout_ms: int | None
    """`fsp_cmd_timeout_ms` as the uplink status says (None: the firmware sends none)."""
    failsafe_delay_ms: int
    arm_range: ModeRange | None


def offset_rc(pilot_rc: Sequence[int]) -> tuple[int, int, int, int]:
    """Stick values the OBC commands: far from the pilot's (300 µs, throttle 150 µs above)."""
    roll, pitch, yaw, throttle = pilot_rc[:STICKS]
    away = [v - 300 if v > 1500 else v + 300 for v in (roll, pitch, yaw)]
    return (away[0], away[1], away[2], min(throttle + 150, 2000))


def ms_after(snapshot: Snapshot | None, t0: float) -> float | None:
    """Milliseconds from `t0` to `snapshot` (None: it never came)."""
    return None if snapshot is None else 1e3 * (snapshot.t - t0)


def near(values: Sequence[int], wanted: Sequence[int], tolerance: int = TOLERANCE_US) -> bool:
    return all(abs(a - b) <= tolerance for a, b in zip(values, wanted, strict=True))


class Preflight:
    """One run of the checks; `run()` returns the report."""

    def __init__(
        self,
        msp: MspClient,
        fsp_url: str,
        pilot: Pilot,
        *,
        baudrate: int = DEFAULT_BAUDRATE,
        limit_ms: float = LIMIT_MS,
        arm: bool = False,
        log: Log = quiet,
        closing: Callable[[Callable[[], None]], object] | None = None,
    ) -> None:
        """`closing`: how the OBC's port closes when it is killed (see `Obc`)."""
        self.msp = msp
        self.pilot = pilot
        self.limit_ms = limit_ms
        self.arm = arm
        self.log = log
        self.obc = Obc(fsp_url, baudrate, closing=closing)
        self.watcher = FcWatcher(msp)
        self.report = PreflightReport("?")

    def run(self) -> PreflightReport:
        self.obc.start()
        self.watcher.start()
        try:
            setup = self._setup()
            if setup is None:
                return self.report
            if setup.obc_alone:
                self._obc_alone(setup)
            else:
                self._safety_pilot(setup)
        finally:
            self.obc.behave("stopped")
            self.watcher.stop()
            self.obc.stop()
        return self.report

    # -- what the FC is -----------------------------------------------------------------------

    def _setup(self) -> Setup | None:
        (features,) = struct.unpack("<I", self.watcher.request(MSP_FEATURE_CONFIG)[:4])
        obc_alone = bool(features & FEATURE_RX_MSP)
        self.report.mode = "OBC alone" if obc_alone else "safety pilot"
        receiver = "the MSP receiver (the OBC alone)" if obc_alone else "its radio (a safety pilot)"
        self.log(f"the FC's receiver: {receiver}")
        failsafe = self.watcher.request(MSP_FAILSAFE_CONFIG)
        ranges = parse_mode_ranges(self.watcher.request(MSP_MODE_RANGES))
        arm_range = next((r for r in ranges if r.mode == BOX_ARM), None)
        if not obc_alone and not self.watcher.has_override:
            self.report.add(
                "MSP OVERRIDE set up (msp_override_channels_mask, a switch)", "no", "yes", False
            )
            return None
        # a lone command: the FC answers with an uplink status, and takes no control
        self.obc.send_one((1500, 1500, 1500, 1000, 1000, 1000))
        status = self._wait_status(1.0)
        if status is None:  # measured all the same: what does this firmware do?
            name = "uplink status (E3): the firmware judges commands fresh or stale"
            self.report.add(name, "none in 1 s", "present", False)
            timeout_ms = None
        else:
            timeout_ms = status.timeout_ms
            limit = f"≤ {self.limit_ms:.0f} ms"
            self.report.add(
                "fsp_cmd_timeout_ms", f"{timeout_ms} ms", limit, timeout_ms <= self.limit_ms
            )
        time.sleep(((timeout_ms or 150) + 50) / 1000)  # any earlier sequence has timed out
        return Setup(obc_alone, timeout_ms, failsafe[0] * 100, arm_range)

    def _elapsed(
        self, t0: float, seen: Snapshot | None, failure: str, **what: Any
    ) -> tuple[float | None, str]:
        """How long after the last fresh command the FC did what MSP showed in `seen`: by the
        FC clock (its time reply and the stream: `Obc.fc_elapsed_us`) where it answers
        commands (`fsp_time_reply`), else from the host's write to the MSP reply. While the
        port was closed the stream cannot show it: then the FC's timeout, as the uplink status
        reports it (the change itself comes at once, or with the radio's next frame)."""
        if seen is None:
            return None, "never"
        closed = failure == "closed"
        us = self.obc.wait_fc_elapsed_us(timed_out=closed, **what)
        if us is not None:
            return us / 1000, "FC clock: its timeout" if closed else "FC clock"
        return ms_after(seen, t0), "host clock"

    def _wait_status(self, timeout: float) -> UplinkStatus | None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.obc.check()
            if self.obc.status is not None:
                return self.obc.status
            time.sleep(0.01)
        return None

    # -- a safety pilot ------------------------------------------------------------------------

    def _safety_pilot(self, setup: Setup) -> None:
        report = self.report
        self.pilot.hold(override=False, armed=False)
        if self.arm:
            self._pilot_arms()
        armed = self.watcher.latest().armed
        # override on while the OBC is silent (a lone packet arrived at setup): nothing moves
        self.pilot.hold(override=True)
        on = self.watcher.wait(lambda s: s.override, time.monotonic() - 0.01, 5.0)
        if on is None:
            report.add("override switch on (MSP OVERRIDE mode)", "off", "on", False)
            return
        pilot_rc = self.watcher.latest().rc
        self.obc.send_one(self._obc_rc(pilot_rc))
        moved = self._largest_move(pilot_rc, 0.5)
        report.add(
            "override on, no fresh command yet: the sticks stay the pilot's",
            f"moved {moved} µs", f"≤ {TOLERANCE_US} µs", moved <= TOLERANCE_US,
        )  # fmt: skip
        sticks = pilot_rc[:STICKS]
        for name, description in FAILURES.items():
            if not self._take_over(pilot_rc, f"{description}: "):
                return
            t0 = self.obc.behave(name)
            back = self.watcher.wait(lambda s: near(s.rc[:STICKS], sticks), t0, WAIT_S)
            ms, clock = self._elapsed(t0, back, name, sticks=lambda rc: near(rc, sticks))
            report.timing(f"{description}: pilot's sticks back ({clock})", ms, self.limit_ms)
            if back is not None:
                self._stays_with_pilot(description, pilot_rc, back.t, armed)
            self.obc.behave("stopped")
        # the switch off gives the sticks back at once
        self.pilot.hold(override=True)
        if self._take_over(pilot_rc, "override switch off: "):
            t0 = time.monotonic()
            self.pilot.hold(override=False)
            back = self.watcher.wait(lambda s: near(s.rc[:STICKS], pilot_rc[:STICKS]), t0, 10.0)
            name = "override switch off while the OBC sends: the pilot's sticks back"
            if self.pilot.simulated:
                report.timing(name, None if back is None else 1e3 * (back.t - t0), self.limit_ms)
            else:
                report.add(name, "yes" if back else "no", "yes", back is not None)
            self.obc.behave("stopped")
        self._radio_lost(setup)

    def _pilot_arms(self) -> None:
        ready = self.watcher.wait(lambda s: s.can_arm, time.monotonic(), 15.0)
        if ready is None:
            flags = self.watcher.version.arming_flag_names(self.watcher.latest().arming_flags)
            self.report.add("the pilot arms", f"arming disabled ({flags})", "armed", False)
            return
        self.pilot.hold(armed=True)
        armed = self.watcher.wait(lambda s: s.armed, time.monotonic() - 0.01, 10.0)
        self.report.add(
            "the pilot arms", "armed" if armed else "not armed", "armed", armed is not None
        )

    def _obc_rc(self, pilot_rc: Sequence[int]) -> tuple[int, ...]:
        """The OBC's command: sticks away from the pilot's, aux3/aux4 away from the pilot's
        AUX3/AUX4 (the OBC must not move them)."""
        aux = (
            [2000 if v < 1500 else 1000 for v in pilot_rc[6:8]]
            if len(pilot_rc) >= 8
            else [1000, 1000]
        )
        return (*offset_rc(pilot_rc), *aux)

    def _largest_move(self, pilot_rc: Sequence[int], seconds: float) -> int:
        start = time.monotonic()
        time.sleep(seconds)
        return max(
            (
                max(abs(a - b) for a, b in zip(s.rc[:8], pilot_rc[:8]))
                for s in self.watcher.since(start)
            ),
            default=0,
        )

    def _take_over(self, pilot_rc: Sequence[int], what: str) -> bool:
        """Fresh commands until the OBC flies the sticks (and only them); False (with a failed
        line) if it does not."""
        command = self._obc_rc(pilot_rc)
        t0 = time.monotonic()
        self.obc.behave("fresh", command)
        wanted = (command[0], command[1], command[2], command[3])
        taken = self.watcher.wait(lambda s: near(s.rc[:STICKS], wanted), t0, WAIT_S)
        if taken is None:
            latest = self.watcher.latest()
            self.report.add(
                f"{what}fresh commands fly the sticks",
                f"sticks {latest.rc[:STICKS]}",
                f"{wanted}",
                False,
            )
            self.obc.behave("stopped")
            return False
        time.sleep(TAKEOVER_S)
        aux = self.watcher.latest().rc[4:8]
        if not near(aux, pilot_rc[4:8]):
            self.report.add(
                f"{what}ARM, the switch and AUX channels stay the pilot's",
                f"AUX1-4 {aux}",
                f"{tuple(pilot_rc[4:8])}",
                False,
            )
        return True

    def _stays_with_pilot(
        self, description: str, pilot_rc: Sequence[int], since: float, armed: bool
    ) -> None:
        time.sleep(HOLD_S)
        after = self.watcher.since(since)
        moved = max(
            (max(abs(a - b) for a, b in zip(s.rc[:STICKS], pilot_rc[:STICKS])) for s in after),
            default=0,
        )
        lost = any(s.rx_loss or s.failsafe for s in after)
        disarmed = armed and any(not s.armed for s in after)
        problems = []
        if moved > TOLERANCE_US:
            problems.append(f"sticks moved {moved} µs")
        if lost:
            problems.append("RXLOSS/failsafe")
        if disarmed:
            problems.append("disarmed")
        name = f"{description}: {HOLD_S:.1f} s on, pilot flies" + (", armed" if armed else "")
        self.report.add(name, "; ".join(problems) or "yes", "yes", not problems)

    def _radio_lost(self, setup: Setup) -> None:
        """Without the pilot's radio the FC fails safe, fresh commands or not."""
        if not self.pilot.transmitter(True):
            self.report.add(
                "pilot's radio lost while the OBC flies: RXLOSS",
                "not checked (needs the virtual FC's radio)",
                "—",
                True,
            )
            return
        self.pilot.hold(override=True)
        pilot_rc = self.watcher.latest().rc
        if not self._take_over(pilot_rc, "pilot's radio lost: "):
            return
        t0 = time.monotonic()
        self.pilot.transmitter(False)
        lost = self.watcher.wait(lambda s: s.rx_loss, t0, WAIT_S)
        name = "pilot's radio lost while the OBC flies: RXLOSS"
        self.report.timing(name, ms_after(lost, t0), RX_LOSS_MS + self.limit_ms)
        self.pilot.transmitter(True)
        self.obc.behave("stopped")
        self.watcher.wait(lambda s: not s.rx_loss, time.monotonic(), 5.0)

    # -- the OBC alone -------------------------------------------------------------------------

    def _obc_alone(self, setup: Setup) -> None:
        report = self.report
        aux = (1000, 1000)
        if self.arm:
            arm = setup.arm_range
            if arm is None or arm.channel not in (2, 3):
                report.add(
                    "ARM on AUX3/AUX4, the OBC's channels (--arm)",
                    "no" if arm is None else f"AUX{arm.channel + 1}",
                    "AUX3 or AUX4",
                    False,
                )
                return
        rc = (1400, 1600, 1450, 1000, *aux)  # throttle low: arming needs it
        failures = list(FAILURES)
        for index, name in enumerate(failures):
            description = FAILURES[name]
            self.obc.behave("fresh", rc)
            up = self.watcher.wait(
                lambda s: not s.rx_loss and near(s.rc[:STICKS], rc[:STICKS]),
                time.monotonic(),
                LINK_UP_S,
            )
            if up is None:
                report.add(f"{description}: fresh commands fly the FC, link up", "no", "yes", False)
                self.obc.behave("stopped")
                return
            last = index == len(failures) - 1
            if self.arm and last:
                self.watcher.wait(lambda s: s.can_arm, time.monotonic(), 15.0)
                armed_rc = (*rc[:4], *self._arm_aux(setup.arm_range, True))
                self.obc.behave("fresh", armed_rc)
                armed = self.watcher.wait(lambda s: s.armed, time.monotonic(), WAIT_S)
                report.add(
                    "the OBC arms (--arm)", "armed" if armed else "not armed", "armed", bool(armed)
                )
                if armed is None:
                    self.obc.behave("stopped")
                    return
                time.sleep(TAKEOVER_S)
            time.sleep(TAKEOVER_S)
            t0 = self.obc.behave(name)
            lost = self.watcher.wait(lambda s: s.rx_loss, t0, WAIT_S)
            ms, clock = self._elapsed(t0, lost, name, status=lambda s: s.has(UplinkFlag.RX_LOSS))
            report.timing(f"{description}: RXLOSS ({clock})", ms, self.limit_ms)
            if self.arm and last:
                stage2 = self.watcher.wait(
                    lambda s: s.failsafe or not s.armed, t0, setup.failsafe_delay_ms / 1e3 + 2.0
                )
                ms, clock = self._elapsed(
                    t0,
                    stage2,
                    name,
                    status=lambda s: (
                        not s.has(UplinkFlag.ARMED) or s.failsafe_phase >= FAILSAFE_LANDING
                    ),
                )
                delay = setup.failsafe_delay_ms
                name = f"{description}: failsafe stage 2 ({clock}; failsafe_delay {delay} ms)"
                report.timing(name, ms, delay + self.limit_ms)
            else:
                time.sleep(HOLD_S)
                still = self.watcher.latest()
                report.add(
                    f"{description}: still RXLOSS after {HOLD_S:.1f} s",
                    "yes" if still.rx_loss else "no",
                    "yes",
                    still.rx_loss,
                )
            self.obc.behave("stopped")
        if not self.arm:
            report.add(
                "failsafe stage 2 (--arm: the OBC arms, props off)",
                "not checked: Betaflight enters stage 2 only armed",
                "—",
                True,
            )

    @staticmethod
    def _arm_aux(arm: ModeRange | None, on: bool) -> tuple[int, int]:
        aux = [1000, 1000]
        if arm is not None and on:
            aux[arm.channel - 2] = (arm.start + arm.end) // 2
        return aux[0], aux[1]
