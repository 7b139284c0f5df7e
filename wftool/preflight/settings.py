"""The board's own settings, read and checked: who flies (its receiver), the command timeout,
the override mask and switch, the failsafe, and where ARM and every other mode sit (spec §5,
§11, §14, §15; what `configure fsp` sets up and refuses). The scenarios then run against
what is read here.

What MSP has is read over MSP; the rest (`fsp_cmd_timeout_ms`, `msp_override_*`, the FSP
port) over the CLI, whose `exit` reboots the FC: `read_settings` waits for it to come back.
"""

from __future__ import annotations

from dataclasses import dataclass

from wftool.errors import CliCommandError
from wftool.fc.board import Board
from wftool.fc.cli_session import CliSession
from wftool.fc.fsp_setup import ARM_AUX, OBC_AUX, SerialPortConfig
from wftool.fc.modes import MODE_ARM, MODE_FAILSAFE, MODE_MSP_OVERRIDE, SWITCH_LOW_US, AuxRange
from wftool.fc.msp import (
    FEATURE_RX_MSP,
    FailsafeConfig,
    FcIdentity,
    MspClient,
    RxConfig,
)
from wftool.fc.versions import version_of
from wftool.preflight.report import Report
from wftool.progress import Log, quiet

CLI_SETTINGS = (
    "fsp_cmd_timeout_ms", "fsp_time_reply", "msp_override_channels_mask",
    "msp_override_failsafe", "failsafe_procedure", "failsafe_recovery_delay",
)  # fmt: skip
"""What preflight reads over the CLI (MSP does not carry them)."""
STICKS = 4
"""Roll, pitch, yaw, throttle: the first functions of the FC's channel map."""


@dataclass(frozen=True)
class BoardSettings:
    """What preflight knows of a board's configuration."""

    identity: FcIdentity
    features: int
    values: dict[str, str | None]
    """`CLI_SETTINGS` as `get` reports them; None: the firmware has no such setting."""
    ranges: list[AuxRange]
    """The mode ranges in use."""
    rcmap: tuple[int, ...]
    """The FC's channel map: the raw channel of roll, pitch, yaw, throttle, AUX1-AUX4."""
    failsafe: FailsafeConfig
    rx: RxConfig
    fsp_ports: tuple[str, ...]
    """The UARTs FSP is on (`serial`)."""

    @property
    def obc_alone(self) -> bool:
        """The MSP receiver is the FC's receiver (feature RX_MSP): the OBC flies alone."""
        return bool(self.features & FEATURE_RX_MSP)

    @property
    def who_flies(self) -> str:
        return "the OBC alone" if self.obc_alone else "a safety pilot"

    def number(self, name: str) -> int | None:
        value = self.values.get(name)
        return int(value) if value is not None and value.lstrip("-").isdigit() else None

    @property
    def timeout_ms(self) -> int | None:
        return self.number("fsp_cmd_timeout_ms")

    @property
    def time_reply(self) -> bool:
        return (self.values.get("fsp_time_reply") or "").upper() == "ON"

    def of_mode(self, mode: int) -> list[AuxRange]:
        return [r for r in self.ranges if r.mode == mode]

    @property
    def override_switch(self) -> AuxRange | None:
        """The MSP OVERRIDE range, when there is exactly one."""
        ranges = self.of_mode(MODE_MSP_OVERRIDE)
        return ranges[0] if len(ranges) == 1 else None

    @property
    def arm_switch(self) -> AuxRange | None:
        """The ARM range, when there is exactly one."""
        ranges = self.of_mode(MODE_ARM)
        return ranges[0] if len(ranges) == 1 else None

    @property
    def sticks_mask(self) -> int:
        """`msp_override_channels_mask` for the sticks under the FC's map."""
        return sum(1 << channel for channel in self.rcmap[:STICKS])

    def raw_channel(self, aux: int) -> int:
        """The raw channel (0-based) of AUX`aux`: through the map for AUX1-AUX4."""
        return self.rcmap[STICKS + aux - 1] if aux <= 4 else STICKS + aux - 1

    def describe(self) -> list[str]:
        """What the report's header says of the configuration."""
        identity = self.identity
        lines = [
            f"firmware: {identity.variant} {identity.version} (git {identity.build.git_revision}"
            f", {identity.board.board_name or identity.board.target_name})",
            f"who flies: {self.who_flies}"
            + ("" if self.obc_alone else f" ({_switch(self.override_switch)})"),
            f"fsp_cmd_timeout_ms {self.values.get('fsp_cmd_timeout_ms')}, FSP on "
            f"{', '.join(self.fsp_ports) or 'no UART'}, the pulse range "
            f"{self.rx.min_us}-{self.rx.max_us} µs",
            f"failsafe: {self.failsafe.procedure_name} at failsafe_delay "
            f"{self.failsafe.delay_ms} ms after RX loss",
        ]
        return lines


def _switch(switch: AuxRange | None) -> str:
    if switch is None:
        return "no single MSP OVERRIDE switch"
    off = "no off position" if switch.off_us is None else f"off at {switch.off_us}"
    return f"MSP OVERRIDE on AUX{switch.aux} {switch.start}-{switch.end}, {off}"


def read_settings(board: Board, log: Log = quiet) -> BoardSettings:
    """The board's settings, over MSP and then the CLI; the FC reboots when the CLI is left
    (it must not be armed: Betaflight opens no CLI then)."""
    with MspClient.open(board.url) as msp:
        identity = msp.identify()
        fsp = version_of(identity).fsp_function  # an FC wftool does not know: refused here
        features = msp.features()
        ranges = [r for r in msp.mode_ranges() if r.usable]
        rcmap = tuple(msp.request(64))
        failsafe = msp.failsafe_config()
        rx = msp.rx_config()
    log("reading the settings over the CLI (the FC reboots when it is left)")
    session = CliSession.open(board.url)
    try:
        values: dict[str, str | None] = {}
        for name in CLI_SETTINGS:
            try:
                values[name] = session.get(name).value
            except CliCommandError:
                values[name] = None
        lines = filter(str.strip, session.run("serial").splitlines())
        ports = tuple(
            config.port for config in map(SerialPortConfig.parse, lines) if config.functions & fsp
        )
    finally:
        if session.exit():
            board.wait_back()
    return BoardSettings(identity, features, values, ranges, rcmap, failsafe, rx, ports)


def check_settings(settings: BoardSettings, limit_ms: float) -> Report:
    """A line per setting that decides whether control changes hands only on purpose."""
    report = Report()
    timeout = settings.timeout_ms
    report.check(
        "fsp_cmd_timeout_ms",
        timeout is not None and timeout <= limit_ms,
        "no such setting (not the patched firmware?)" if timeout is None else f"{timeout} ms",
        f"≤ {limit_ms:g} ms",
    )
    report.check(
        "FSP on a UART (serial)",
        bool(settings.fsp_ports),
        ", ".join(settings.fsp_ports) or "none",
        "one",
    )
    if settings.obc_alone:
        _obc_alone(settings, report)
    else:
        _safety_pilot(settings, report)
    _failsafe(settings, report)
    return report


def _safety_pilot(settings: BoardSettings, report: Report) -> None:
    mask = settings.number("msp_override_channels_mask")
    sticks = settings.sticks_mask
    report.check(
        "msp_override_channels_mask: the sticks only",
        mask is not None and mask != 0 and mask & ~sticks == 0,
        "no such setting" if mask is None else _channels(mask),
        _channels(sticks),
    )
    failsafe = settings.values.get("msp_override_failsafe")
    report.check(
        "msp_override_failsafe OFF (the OBC never keeps a lost radio link alive)",
        (failsafe or "").upper() == "OFF",
        failsafe or "no such setting",
        "OFF",
    )
    overrides = settings.of_mode(MODE_MSP_OVERRIDE)
    switch = settings.override_switch
    if switch is None:
        measured = "none" if not overrides else "; ".join(r.describe() for r in overrides)
        report.check("MSP OVERRIDE on one switch", False, measured, "one range")
    else:
        report.check(
            "the override switch has an off position",
            switch.off_us is not None,
            _switch(switch),
            f"its low end (≤ {SWITCH_LOW_US} µs) left out",
        )
        arms = [r for r in settings.of_mode(MODE_ARM) if r.channel == switch.channel]
        report.check(
            "the override switch is not the ARM switch",
            not arms,
            "; ".join(r.describe() for r in arms) or f"AUX{switch.aux}: MSP OVERRIDE only",
            "a channel of its own",
        )
    driven = mask or 0
    on_obc = [
        r
        for r in settings.ranges
        if r.mode in (MODE_ARM, MODE_FAILSAFE) and driven >> settings.raw_channel(r.aux) & 1
    ]
    report.check(
        "ARM and FAILSAFE off the channels the OBC overrides",
        not on_obc,
        "; ".join(r.describe() for r in on_obc) or "yes",
        "yes",
    )


def _obc_alone(settings: BoardSettings, report: Report) -> None:
    arms = settings.of_mode(MODE_ARM)
    elsewhere = [r for r in arms if r.channel != ARM_AUX]
    report.check(
        f"ARM on AUX{ARM_AUX + 1} only, the switch the FC holds (arming requests)",
        bool(arms) and not elsewhere,
        "; ".join(r.describe() for r in elsewhere) or ("no ARM range" if not arms else "yes"),
        f"AUX{ARM_AUX + 1}",
    )
    on_obc = [r for r in settings.ranges if r.mode != MODE_ARM and r.channel in OBC_AUX]
    report.check(
        "no mode on AUX3/AUX4 (the OBC's: a command sent by accident would switch it)",
        not on_obc,
        "; ".join(r.describe() for r in on_obc) or "none",
        "none",
    )
    never = [r for r in settings.ranges if r.mode != MODE_ARM and r.channel not in OBC_AUX]
    report.check(
        "no mode on AUX1/AUX2/AUX5+ (FSP never drives them: it would be stuck)",
        not never,
        "; ".join(r.describe() for r in never) or "none",
        "none",
    )


def _failsafe(settings: BoardSettings, report: Report) -> None:
    config = settings.failsafe
    procedure = config.procedure_name
    known = procedure in ("DROP", "AUTO-LAND", "GPS-RESCUE")
    report.check(
        "failsafe_procedure (stage 2 when the receiver is lost)",
        known,
        f"{procedure} after failsafe_delay {config.delay_ms} ms",
        "DROP, AUTO-LAND or GPS-RESCUE",
    )


def _channels(mask: int) -> str:
    """A raw channel mask as channel numbers (1-based)."""
    channels = [str(bit + 1) for bit in range(mask.bit_length()) if mask >> bit & 1]
    return f"{mask} (channels {', '.join(channels)})" if channels else "0 (none)"
