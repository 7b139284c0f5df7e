"""The virtual FC: the patched SITL running with FSP configured, optionally in motion.

`VirtualFcSession` is what `wftool sitl` and the end-to-end tests start: a `VirtualFC`
process in a scratch directory (emulating a `VirtualBoard`), FSP put on UART2 through the CLI
with the same safe workflow a lab uses on hardware (`configure fsp`; and, on request, the MSP
port's baud rate, which counts once its UARTs are paced), and — on request — synthetic IMU
motion fed through SITL's simulator input (UDP 9003), so the stream carries moving values.

With `WFTOOL_SITL_CACHE` naming a directory, a fresh virtual FC whose configuration was made
before (the same binary, the same options) starts from the EEPROM that configuration left,
in one boot instead of `configure fsp`'s three (~6 s); the test suite sets it for its run.

Who flies it is `configure fsp`'s choice: the OBC alone (the MSP receiver, the default
here; it arms by arming requests, the FC holding ARM on AUX1), or a safety pilot
(`pilot=True`): the simulated radio (`radio.SimulatedRadio` on SITL's RC input, `feature
RX_UDP`) is the receiver, ARM on its AUX1, and the OBC overrides the sticks once the pilot
has engaged it with the AUX2 switch (`radio.EngagingPilot`).
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import shutil
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from wftool.fc.cli_session import CliSession
from wftool.fc.fsp_setup import (
    CMD_TIMEOUT_MS_DEFAULT,
    Control,
    ObcOnly,
    SafetyPilot,
    SerialPortConfig,
    aux_ranges,
    fsp_planner,
)
from wftool.fc.modes import MODE_ARM, AuxRange
from wftool.fc.msp import FEATURE_RX_UDP, MspClient
from wftool.fc.params import apply_plan
from wftool.fc.plan import Command, Plan, Planner, set_command
from wftool.fc.versions import BetaflightVersion
from wftool.fsp import DEFAULT_BAUDRATE
from wftool.fsp.schedule import DEFAULT_RATE_HZ, frame_rate_hz
from wftool.sitl.process import (
    DEFAULT_PORT_BASE,
    LOOPBACK,
    SITL_BOARD,
    VirtualBoard,
    VirtualFC,
)
from wftool.sitl.radio import SimulatedRadio

CACHE_ENV = "WFTOOL_SITL_CACHE"
"""A directory of the EEPROMs configured virtual FCs left, by binary and options (unset: none)."""
EEPROM = "eeprom.bin"
"""Where SITL keeps its settings, in its working directory."""
FSP_UART = 2
MSP_UART = 1
"""The SITL's MSP and CLI port (its only serial function by default)."""
GRAVITY = 9.80665
PILOT_ARM = 1
"""The simulated radio's ARM switch: AUX1."""
PILOT_OVERRIDE = 2
"""The simulated radio's override switch: AUX2."""
SWITCH_ON_US = (1700, 2100)


@dataclass(frozen=True)
class Motion:
    """A gentle, smooth flight-like wobble: roll and pitch oscillate, yaw turns slowly."""

    roll_deg: float = 20.0
    pitch_deg: float = 12.0
    roll_hz: float = 0.4
    pitch_hz: float = 0.27
    yaw_deg_per_s: float = 15.0

    def state(self, t: float, timestamp: float) -> bytes:
        """SITL's fdm_packet for motion time `t`: angular rates, specific force, attitude."""
        roll = math.radians(self.roll_deg) * math.sin(2 * math.pi * self.roll_hz * t)
        pitch = math.radians(self.pitch_deg) * math.sin(2 * math.pi * self.pitch_hz * t)
        yaw = math.radians(self.yaw_deg_per_s * t) % (2 * math.pi)
        roll_rate = (
            math.radians(self.roll_deg)
            * 2
            * math.pi
            * self.roll_hz
            * math.cos(2 * math.pi * self.roll_hz * t)
        )
        pitch_rate = (
            math.radians(self.pitch_deg)
            * 2
            * math.pi
            * self.pitch_hz
            * math.cos(2 * math.pi * self.pitch_hz * t)
        )
        yaw_rate = math.radians(self.yaw_deg_per_s)
        # Hovering: the accelerometer feels gravity's reaction, in body axes (NED).
        accel = (
            GRAVITY * math.sin(pitch),
            -GRAVITY * math.sin(roll) * math.cos(pitch),
            -GRAVITY * math.cos(roll) * math.cos(pitch),
        )
        cr, sr = math.cos(roll / 2), math.sin(roll / 2)
        cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
        cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
        quaternion = (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        )
        return struct.pack(
            "<18d", timestamp, roll_rate, pitch_rate, yaw_rate, *accel, *quaternion,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 101325.0,
        )  # fmt: skip


class MotionFeeder:
    """Sends `Motion` states to SITL from a daemon thread until stopped.

    SITL rescales its own clock by simulator time over real time whenever a state packet's
    timestamp is less than 20 ms after the previous one, so send jitter would make the FC
    clock run fast or slow. The packets' simulator timestamps therefore advance by exactly
    `SIM_STEP_S` each, which SITL never uses for rescaling: its clock stays real time.
    """

    SIM_STEP_S = 0.025

    def __init__(self, motion: Motion, port: int, rate_hz: float = 1.0 / SIM_STEP_S) -> None:
        """`port`: SITL's simulator input, one `fdm_packet` (18 doubles) per UDP datagram."""
        self._motion = motion
        self._port = port
        self._period = 1.0 / rate_hz
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sitl-motion", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            start = time.monotonic()
            next_send = start
            sent = 0
            while not self._stop.is_set():
                state = self._motion.state(time.monotonic() - start, sent * self.SIM_STEP_S)
                sock.sendto(state, (LOOPBACK, self._port))
                sent += 1
                next_send += self._period
                self._stop.wait(max(0.0, next_send - time.monotonic()))


def with_msp_baud(planner: Planner, baud: int) -> Planner:
    """`planner`, and the MSP port's baud rate set to `baud` as well."""

    def plan(session: CliSession, version: BetaflightVersion) -> Plan:
        planned = planner(session, version)
        lines = filter(str.strip, session.run("serial").splitlines())
        for config in map(SerialPortConfig.parse, lines):
            if config.port == f"UART{MSP_UART}" and config.msp_baud != baud:
                planned.commands.append(Command(replace(config, msp_baud=baud).command()))
        return planned

    return plan


class VirtualFcSession:
    """The patched SITL with FSP on UART2; a context manager that never leaves a process."""

    def __init__(
        self,
        binary: Path,
        workdir: Path,
        *,
        baud: int = DEFAULT_BAUDRATE,
        rate_hz: int = DEFAULT_RATE_HZ,
        motion: Motion | None = None,
        port_base: int | None = DEFAULT_PORT_BASE,
        time_reply: bool = False,
        serial_update_rate_hz: int | None = None,
        board: VirtualBoard = SITL_BOARD,
        msp_baud: int | None = None,
        pilot: bool = False,
        cmd_timeout_ms: int = CMD_TIMEOUT_MS_DEFAULT,
        failsafe_procedure: str = "drop",
        arm_switch: int | None = None,
        control: Control | None = None,
        configuration: Planner | None = None,
        fsp_uart: int = FSP_UART,
        idle_timeout_s: int | None = None,
    ) -> None:
        """`time_reply`: the FC answers each command with a time reply (spec §10);
        `port_base=None`: any free ports (see `VirtualFC`); `serial_update_rate_hz` None:
        the highest the FC allows (as `configure fsp`); `msp_baud` None: the MSP port's as
        it is (115200). `pilot`: a safety pilot's simulated radio is the receiver (`radio`),
        else the OBC flies alone with `failsafe_procedure` (and arms by arming requests:
        `configure fsp` puts ARM on AUX1, which the FC holds). `arm_switch`: with a pilot,
        ARM on that AUX channel of the radio (default AUX1). `control`: who flies as
        `configure fsp` is told (default: from `pilot`, the switch AUX2 at 1700-2100).
        `configuration`: a planner that configures the FC instead of `configure fsp` (a
        user's backup), with FSP on UART`fsp_uart`. `idle_timeout_s`: `VirtualFC`'s."""
        if control is not None:
            pilot = isinstance(control, SafetyPilot)
        if arm_switch is not None and not pilot:
            raise ValueError("the OBC alone arms by arming requests: ARM is AUX1, the FC's")
        self.fc = VirtualFC(
            binary, workdir, port_base=port_base, board=board, idle_timeout_s=idle_timeout_s
        )
        self.msp_baud = msp_baud
        self.workdir = workdir
        self._baud = baud
        self.rate_hz = rate_hz
        self.time_reply = time_reply
        self.serial_update_rate_hz = serial_update_rate_hz
        self.pilot = pilot
        self.cmd_timeout_ms = cmd_timeout_ms
        self.failsafe_procedure = failsafe_procedure
        self.arm_switch = (arm_switch or PILOT_ARM) if pilot else None
        self.control = control
        self.configuration = configuration
        self.fsp_uart = fsp_uart
        self._motion = motion
        self._feeder: MotionFeeder | None = None
        self.radio: SimulatedRadio | None = None
        """The safety pilot's radio (with `pilot`): sticks centred, throttle low, switches
        off until told otherwise."""

    @property
    def expected_rate_hz(self) -> float:
        """The frame rate this FC streams: its `fsp_rate_hz` and PID looptime (over MSP)."""
        with MspClient.open(self.msp_url) as msp:
            return frame_rate_hz(self.rate_hz, msp.pid_looptime_us())

    @property
    def msp_url(self) -> str:
        return self.fc.url

    @property
    def fsp_url(self) -> str:
        return self.fc.uart_url(self.fsp_uart)

    def planner(self) -> Planner:
        """`configure fsp` as this virtual FC is flown, plus what a simulator without an
        airframe needs (`_virtual_airframe`); or the `configuration` given."""
        if self.configuration is not None:
            return self.configuration
        control: Control = ObcOnly(self.failsafe_procedure)
        if self.control is not None:
            control = self.control
        elif self.pilot:
            control = SafetyPilot(PILOT_OVERRIDE, SWITCH_ON_US)
        planner = fsp_planner(
            self.fsp_uart,
            self._baud,
            self.rate_hz,
            self.time_reply,
            self.serial_update_rate_hz,
            control=control,
            cmd_timeout_ms=self.cmd_timeout_ms,
            radio_feature=FEATURE_RX_UDP if self.pilot else None,
        )
        if self.msp_baud is not None:
            planner = with_msp_baud(planner, self.msp_baud)
        return _virtual_airframe(planner, self.arm_switch)

    def start(self) -> VirtualFcSession:
        eeprom = self.workdir / EEPROM
        cached = None if eeprom.exists() else self._cached()
        configured = False
        if cached is not None and cached.is_file():
            self.workdir.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(cached, eeprom)
            configured = True
        self.fc.start()
        try:
            if self.pilot:
                self.radio = SimulatedRadio(self.fc.sim_rc_port).start()
            if not configured:
                apply_plan(self.fc, self.planner(), self.workdir / "backups")
                if cached is not None:  # made from a blank EEPROM: what the next one gets
                    partial = cached.with_name(f"{cached.name}.{os.getpid()}")
                    shutil.copyfile(eeprom, partial)
                    partial.replace(cached)
            if self._motion is not None:  # the ports are known once the FC runs
                self._feeder = MotionFeeder(self._motion, self.fc.sim_state_port)
                self._feeder.start()
        except BaseException:
            self.stop()
            raise
        return self

    def _cached(self) -> Path | None:
        """Where the EEPROM of this configuration, made from a blank one, is cached (it may
        not be yet); None without a cache, or for a `configuration` of the caller's."""
        root = os.environ.get(CACHE_ENV)
        if not root or self.configuration is not None:
            return None
        binary = self.fc.binary.stat()
        key = hashlib.sha256(_digest(self.fc.binary, binary.st_mtime_ns, binary.st_size))
        options = (
            self.fsp_uart, self._baud, self.rate_hz, self.time_reply, self.serial_update_rate_hz,
            self.pilot, self.cmd_timeout_ms, self.failsafe_procedure, self.arm_switch,
            self.control, self.msp_baud, self.fc.board,
        )  # fmt: skip
        key.update(repr(options).encode())
        return Path(root) / f"{key.hexdigest()[:32]}.{EEPROM}"

    def set_msp_baud(self, baud: int) -> None:
        """Give the MSP port another baud rate, saved: the FC restarts with it."""
        apply_plan(
            self.fc,
            with_msp_baud(lambda _session, _version: Plan([]), baud),
            self.workdir / "backups",
        )
        self.msp_baud = baud

    def serve(
        self,
        on_reset: Callable[[], None] | None = None,
        alongside: Callable[[threading.Event], object] | None = None,
    ) -> None:
        """Keep the FC up until interrupted: a reset (CLI save, reboot) ends the SITL
        process, so start it again, as a board's reset circuit would.

        `alongside(stop)` runs in a thread of its own meanwhile (say, reading the FSP
        stream), until `stop` is set when serving ends; if it ends first, serving ends
        too, and what it raised is raised here.
        """
        stop = threading.Event()
        failure: list[BaseException] = []

        def run(work: Callable[[threading.Event], object]) -> None:
            try:
                work(stop)
            except BaseException as exc:
                failure.append(exc)
            finally:
                stop.set()

        thread = None
        if alongside is not None:
            thread = threading.Thread(
                target=run, args=(alongside,), name="wftool-serve-alongside", daemon=True
            )
            thread.start()
        try:
            while not stop.wait(0.2):
                if not self.fc.running:
                    if on_reset is not None:
                        on_reset()
                    self.fc.wait_back()  # a crash is raised, not started again
        finally:
            stop.set()
            if thread is not None:
                thread.join()
        if failure:
            raise failure[0]

    def stop(self) -> None:
        if self._feeder is not None:
            self._feeder.stop()
            self._feeder = None
        if self.radio is not None:
            self.radio.stop()
            self.radio = None
        self.fc.stop()

    def __enter__(self) -> VirtualFcSession:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()


@functools.lru_cache(maxsize=8)
def _digest(binary: Path, mtime_ns: int, size: int) -> bytes:
    """The SHA-256 of `binary` as it is (its time and size in the key: read once each)."""
    return hashlib.sha256(binary.read_bytes()).digest()


def _virtual_airframe(planner: Planner, arm_switch: int | None) -> Planner:
    """`planner`, then ARM on AUX`arm_switch` (its on position) in a slot of its own, and
    runaway takeoff prevention off: the virtual FC's gyro is the synthetic motion, which no
    motor moves, so any stick held off centre while armed winds the PID sum up until
    Betaflight disarms ("runaway takeoff") within ~0.1 s."""

    def plan(session: CliSession, version: BetaflightVersion) -> Plan:
        base = planner(session, version)
        base.commands.append(set_command("runaway_takeoff_prevention", "OFF"))
        if arm_switch is None:
            return base
        ranges = aux_ranges(session)
        taken = {int(command.text.split()[1]) for command in base.commands if command.verb == "aux"}
        arms = [r.slot for r in ranges if r.usable and r.mode == MODE_ARM]
        free = [r.slot for r in ranges if not r.usable and r.slot not in taken]
        slot = (arms or free)[0]
        start, end = SWITCH_ON_US
        arm = AuxRange(slot, MODE_ARM, arm_switch - 1, start, end)
        base.commands.append(Command(arm.command()))
        return base

    return plan
