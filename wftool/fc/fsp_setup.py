"""`wftool configure fsp`: everything FSP needs (its UART, who flies — a safety pilot by
default, or the OBC alone —, bidirectional DShot, the filter defaults, the rates), planned
from what the FC reports (docs/design.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from wftool.errors import CliCommandError, ParameterError, ProtocolError
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import FEATURE_RX_MSP, RECEIVER_FEATURES
from wftool.fc.params import Command, FeatureChange, Plan, Planner, set_command
from wftool.fsp.schedule import DEFAULT_RATE_HZ

FSP_FUNCTION = 1 << 30
"""FSP's serial function bit on the series for Betaflight 2026.6 (1 << 19 on 2025.12, a bit
2026.6 gives FUNCTION_LIDAR_NL): clear of upstream's sequential allocation."""
MSP_FUNCTION = 1 << 0
RX_SERIAL_FUNCTION = 1 << 6
CMD_TIMEOUT_MS_DEFAULT = 50
CMD_TIMEOUT_MS_RANGE = (10, 150)
"""`fsp_cmd_timeout_ms` (spec §11): the firmware's default and range."""
MAX_INVALID_PULSE_MS = 300
"""Betaflight's stage 1 holds a lost receiver's last values this long (rx.c)."""
ACC_RPM_FILTER_DEFAULTS = {
    "acc_rpm_filter_harmonics": "1",
    "acc_rpm_filter_min_hz": "60",
    "acc_rpm_filter_fade_range_hz": "50",
    "acc_rpm_filter_q": "500",
}
SERIAL_FUNCTION_NAMES = {
    1 << 0: "MSP", 1 << 1: "GPS", 1 << 2: "FRSKY_HUB", 1 << 3: "HOTT", 1 << 4: "LTM",
    1 << 5: "SMARTPORT", 1 << 6: "RX_SERIAL", 1 << 7: "BLACKBOX", 1 << 9: "MAVLINK",
    1 << 10: "ESC_SENSOR", 1 << 11: "SMARTAUDIO", 1 << 12: "IBUS", 1 << 13: "TRAMP",
    1 << 14: "RCDEVICE", 1 << 15: "LIDAR_TF", 1 << 16: "FRSKY_OSD", 1 << 17: "VTX_MSP",
    1 << 18: "GIMBAL", 1 << 19: "LIDAR_NL", 1 << 20: "OSD_CUSTOM_TEXT", FSP_FUNCTION: "FSP",
}  # fmt: skip
"""`serialPortFunction_e` (io/serial.h of Betaflight 2026.6), only to name what FSP replaces."""


@dataclass(frozen=True)
class SerialPortConfig:
    """One line of the CLI `serial` command: port, function bits, four baud rates."""

    port: str
    functions: int
    msp_baud: int
    other_bauds: tuple[int, int, int]
    """GPS, telemetry, blackbox: kept as they are."""

    @classmethod
    def parse(cls, line: str) -> SerialPortConfig:
        """A line of the FC's `serial` output; `ProtocolError` if it is not one."""
        fields = line.split()
        if len(fields) != 7 or fields[0] != "serial" or not all(f.isdigit() for f in fields[2:]):
            raise ProtocolError(
                f"the FC's `serial` output has a line wftool does not know: {line.strip()!r} "
                "(expected `serial PORT FUNCTIONS` and four baud rates)"
            )
        _, port, functions, msp_baud, gps, telemetry, blackbox = fields
        others = (int(gps), int(telemetry), int(blackbox))
        return cls(port.upper(), int(functions), int(msp_baud), others)

    def command(self) -> str:
        bauds = " ".join(str(b) for b in (self.msp_baud, *self.other_bauds))
        return f"serial {self.port} {self.functions} {bauds}"


def function_names(mask: int) -> str:
    return "+".join(
        SERIAL_FUNCTION_NAMES.get(1 << bit, f"bit {bit}") for bit in range(32) if mask >> bit & 1
    )


AUX_CHANNELS = 14
"""Betaflight's AUX channels (MAX_AUX_CHANNEL_COUNT: 18 channels, 4 of them sticks)."""
MODE_ARM = 0
MODE_MSP_OVERRIDE = 50
MODE_NAMES = {
    0: "ARM", 1: "ANGLE", 2: "HORIZON", 3: "ALTHOLD", 5: "HEADFREE", 6: "PASSTHRU",
    13: "BEEPER", 19: "OSD DISABLE", 26: "BLACKBOX", 27: "FAILSAFE", 28: "AIR MODE",
    35: "FLIP OVER AFTER CRASH", 36: "PREARM", 39: "VTX PIT MODE", 46: "GPS RESCUE",
    50: "MSP OVERRIDE", 53: "LAUNCH CONTROL",
}  # fmt: skip
"""Permanent mode ids (msp_box.c) of the `aux` command, for messages."""
STICK_FUNCTIONS = 4
"""rcmap's first four entries: roll, pitch, yaw, throttle."""
FAILSAFE_PROCEDURES = {"drop": "DROP", "land": "AUTO-LAND", "gps-rescue": "GPS-RESCUE"}
"""`--failsafe-procedure` → Betaflight's `failsafe_procedure`."""
PROCEDURE_OUTCOMES = {
    "DROP": "DROP: the motors stop and the FC disarms — the aircraft falls",
    "AUTO-LAND": (
        "AUTO-LAND: sticks level, throttle at failsafe_throttle ({failsafe_throttle}) for "
        "failsafe_landing_time ({failsafe_landing_time} s), then the FC disarms"
    ),
    "GPS-RESCUE": "GPS-RESCUE: the FC flies home and lands (needs a GPS fix and the rescue set-up)",
}


@dataclass(frozen=True)
class SafetyPilot:
    """The board's radio is the receiver; the OBC overrides the sticks while the pilot's
    switch (AUX`switch`) is within `on_us`."""

    switch: int = 2
    on_us: tuple[int, int] = (1700, 2100)


@dataclass(frozen=True)
class ObcOnly:
    """The OBC is the FC's only receiver; `failsafe_procedure` (a `FAILSAFE_PROCEDURES`
    key) is what the FC does when it is gone."""

    failsafe_procedure: str


Control = SafetyPilot | ObcOnly


@dataclass(frozen=True)
class AuxRange:
    """One line of the CLI `aux` command: a mode on an AUX channel within a range."""

    slot: int
    mode: int
    """The mode's permanent id (`MODE_NAMES`)."""
    channel: int
    """0 = AUX1."""
    start: int
    end: int
    logic: int = 0
    linked: int = 0

    @classmethod
    def parse(cls, line: str) -> AuxRange:
        return cls(*(int(field) for field in line.split()[1:8]))

    @property
    def usable(self) -> bool:
        """Betaflight's IS_RANGE_USABLE: an empty range is an unused slot."""
        return self.start < self.end

    def command(self) -> str:
        fields = (self.slot, self.mode, self.channel, self.start, self.end, self.logic)
        return "aux " + " ".join(str(f) for f in (*fields, self.linked))

    def describe(self) -> str:
        name = MODE_NAMES.get(self.mode, f"mode {self.mode}")
        return f"aux {self.slot}: {name} on AUX{self.channel + 1} {self.start}-{self.end}"


def aux_ranges(session: CliSession) -> list[AuxRange]:
    """Every slot of the FC's mode ranges, used or not."""
    return [
        AuxRange.parse(line) for line in session.run("aux").splitlines() if line.startswith("aux ")
    ]


def channel_map(session: CliSession) -> list[int]:
    """The FC's rcmap: for roll, pitch, yaw, throttle, AUX1-4 the raw channel (0-based)."""
    letters = "AERT1234"
    line = next((line for line in session.run("map").splitlines() if line.startswith("map ")), "")
    order = line.split()[1] if len(line.split()) > 1 else ""
    if sorted(order) != sorted(letters):
        raise ParameterError(f"cannot read the FC's channel map from `map` ({line or 'nothing'})")
    return [order.index(letter) for letter in letters]


def enabled_features(session: CliSession) -> set[str]:
    """The names the FC lists as enabled in `feature`."""
    for line in session.run("feature").splitlines():
        heading, _, names = line.partition(":")
        if heading.strip() == "Enabled":
            return {name.upper() for name in names.split()}
    return set()


def failsafe_outlook(settings: dict[str, str], timeout_ms: int, procedure: str) -> list[str]:
    """What an FC flown by the OBC alone does when the OBC is gone, from its settings (spec
    §11): one line per stage, with its time after the OBC's last fresh command."""
    delay_ms = int(settings["failsafe_delay"]) * 100
    outcome = PROCEDURE_OUTCOMES[procedure].format(**settings)
    hold_ms = max(timeout_ms, MAX_INVALID_PULSE_MS)
    return [
        "with the OBC alone, when it is gone (crashed, hung, stopped, repeating itself, "
        "sending garbage) — times after its last fresh command:",
        f"  {timeout_ms} ms: RXLOSS (fsp_cmd_timeout_ms); Betaflight's failsafe stage 1 holds "
        "the last command",
        f"  {hold_ms} ms: sticks centred, throttle at rx_min_usec ({settings['rx_min_usec']})",
        f"  {delay_ms} ms: stage 2 (failsafe_delay): {outcome}",
        "  no human can take over; fresh commands end stage 1, but not stage 2",
    ]


def fsp_planner(
    uart: int,
    baud: int,
    rate_hz: int = DEFAULT_RATE_HZ,
    time_reply: bool | None = None,
    serial_update_rate_hz: int | None = None,
    *,
    control: Control = SafetyPilot(),
    cmd_timeout_ms: int = CMD_TIMEOUT_MS_DEFAULT,
    radio_feature: int | None = None,
) -> Planner:
    """A planner (see `wftool.fc.params.apply_plan`) for FSP on UART`uart` at `baud`, flown
    as `control` says; `time_reply` sets `fsp_time_reply` (None: leave it);
    `serial_update_rate_hz` None sets the highest the FC allows; `radio_feature` makes that
    receiver feature the FC's radio first (the virtual FC's `FEATURE_RX_UDP`)."""

    def plan(session: CliSession) -> Plan:
        commands, notes = _fsp_port(session, uart, baud, control)
        try:
            session.get("dshot_bidir")
            commands.append(set_command("dshot_bidir", "ON"))
        except CliCommandError:
            notes.append(
                "this firmware has no dshot_bidir (no DShot telemetry, e.g. SITL): left out; "
                "the RPM filters get no motor RPM"
            )
        commands += [set_command(name, value) for name, value in ACC_RPM_FILTER_DEFAULTS.items()]
        commands.append(set_command("fsp_rate_hz", str(rate_hz)))
        commands.append(set_command("fsp_cmd_timeout_ms", str(cmd_timeout_ms)))
        if time_reply is not None:
            commands.append(set_command("fsp_time_reply", "ON" if time_reply else "OFF"))
        if serial_update_rate_hz is not None:
            commands.append(set_command("serial_update_rate_hz", str(serial_update_rate_hz)))
        elif update_rate := session.get("serial_update_rate_hz").int_range:
            commands.append(set_command("serial_update_rate_hz", str(update_rate[1])))
        if isinstance(control, SafetyPilot):
            receiver = _safety_pilot(session, control, radio_feature, commands, notes)
        else:
            receiver = _obc_only(session, control, cmd_timeout_ms, commands, notes)
        return Plan(commands, receiver, notes)

    return plan


def _fsp_port(
    session: CliSession, uart: int, baud: int, control: Control
) -> tuple[list[Command], list[str]]:
    """The `serial` lines that give UART`uart` to FSP alone, and what they replace."""
    ports = {
        config.port: config
        for config in map(
            SerialPortConfig.parse, filter(str.strip, session.run("serial").splitlines())
        )
    }
    target = f"UART{uart}"
    if target not in ports:
        raise ParameterError(f"the FC has no {target} (it has {', '.join(ports)})")
    commands: list[Command] = []
    notes: list[str] = []
    for config in ports.values():
        if config.port != target and config.functions & FSP_FUNCTION:
            commands.append(
                Command(replace(config, functions=config.functions & ~FSP_FUNCTION).command())
            )
            notes.append(f"FSP moves from {config.port} to {target}")
    if not any(c.functions & MSP_FUNCTION for c in ports.values() if c.port != target):
        raise ParameterError(
            f"{target} is the FC's only MSP port; giving it to FSP would lock out MSP and the CLI"
        )
    if isinstance(control, SafetyPilot) and ports[target].functions & RX_SERIAL_FUNCTION:
        raise ParameterError(
            f"{target} carries the receiver (RX_SERIAL), the safety pilot's radio: give FSP "
            "another UART"
        )
    replaced = ports[target].functions & ~FSP_FUNCTION
    if replaced:
        notes.append(f"{target}: FSP replaces {function_names(replaced)} on this port")
    commands.append(
        Command(replace(ports[target], functions=FSP_FUNCTION, msp_baud=baud).command())
    )
    return commands, notes


def _safety_pilot(
    session: CliSession,
    pilot: SafetyPilot,
    radio_feature: int | None,
    commands: list[Command],
    notes: list[str],
) -> FeatureChange | None:
    """MSP OVERRIDE of the sticks on the pilot's switch; the receiver change, if any."""
    switch = pilot.switch - 1
    if not 0 <= switch < AUX_CHANNELS:
        raise ParameterError(f"there is no AUX{pilot.switch} (AUX1-AUX{AUX_CHANNELS})")
    receiver = None
    if radio_feature is not None:
        receiver = FeatureChange(enable=radio_feature, disable=RECEIVER_FEATURES & ~radio_feature)
    elif "RX_MSP" in enabled_features(session):
        raise ParameterError(
            "the FC's receiver is the MSP receiver (feature RX_MSP): a safety pilot needs the "
            "board's radio as its receiver — set it up first, or choose --obc-only"
        )
    rcmap = channel_map(session)
    sticks = rcmap[:STICK_FUNCTIONS]
    if sorted(sticks) != list(range(STICK_FUNCTIONS)):
        raise ParameterError(
            "the FC's map puts the sticks outside channels 1-4; MSP OVERRIDE's switch checks "
            "assume them there (use e.g. map AETR1234 or TAER1234)"
        )
    commands.append(set_command("msp_override_channels_mask", str(override_mask(rcmap))))
    commands.append(set_command("msp_override_failsafe", "OFF"))
    ranges = aux_ranges(session)
    used = [r for r in ranges if r.usable]
    if arm := [r for r in used if r.mode == MODE_ARM and r.channel == switch]:
        raise ParameterError(
            f"AUX{pilot.switch} carries ARM ({arm[0].describe()}): the override switch needs "
            "a channel of its own"
        )
    overrides = [r for r in ranges if r.mode == MODE_MSP_OVERRIDE and r.usable]
    free = [r for r in ranges if not r.usable]
    if overrides:
        slot = overrides[0].slot
    elif free:
        slot = free[0].slot
    else:
        raise ParameterError("every mode range slot (`aux`) is in use: free one for MSP OVERRIDE")
    start, end = pilot.on_us
    override = AuxRange(slot, MODE_MSP_OVERRIDE, switch, start, end)
    commands.append(Command(override.command()))
    for extra in overrides[1:]:
        commands.append(Command(AuxRange(extra.slot, 0, 0, 900, 900).command()))
        notes.append(f"{extra.describe()} cleared: the override switch is AUX{pilot.switch}")
    others = [r for r in used if r.channel == switch and r.mode != MODE_MSP_OVERRIDE]
    if others:
        listed = "; ".join(r.describe() for r in others)
        notes.append(f"AUX{pilot.switch} also switches: {listed}")
    if not any(r.mode == MODE_ARM for r in used):
        notes.append("no ARM switch is set up (`aux`): the pilot cannot arm")
    notes.append(
        f"MSP OVERRIDE on AUX{pilot.switch} {start}-{end}: the OBC's fresh commands fly roll, "
        "pitch, yaw and throttle while it is on; ARM and every AUX channel stay the pilot's"
    )
    return receiver


def _obc_only(
    session: CliSession,
    obc: ObcOnly,
    timeout_ms: int,
    commands: list[Command],
    notes: list[str],
) -> FeatureChange:
    """The MSP receiver as the FC's receiver, the failsafe procedure, what loss means."""
    stuck = [r for r in aux_ranges(session) if r.usable and r.channel in (0, 1)]
    if stuck:
        listed = "; ".join(r.describe() for r in stuck)
        raise ParameterError(
            f"FSP never drives AUX1/AUX2, so with the OBC alone these modes would be stuck: "
            f"{listed} — move them to AUX3/AUX4 (the OBC's) or remove them"
        )
    procedure = FAILSAFE_PROCEDURES[obc.failsafe_procedure]
    commands.append(set_command("failsafe_procedure", procedure))
    names = ("failsafe_delay", "failsafe_landing_time", "failsafe_throttle", "rx_min_usec")
    settings = {name: session.get(name).value for name in names}
    notes.extend(failsafe_outlook(settings, timeout_ms, procedure))
    return FeatureChange(enable=FEATURE_RX_MSP, disable=RECEIVER_FEATURES & ~FEATURE_RX_MSP)


def parse_channel(name: str) -> int:
    """ "AUX2" → 2."""
    upper = name.strip().upper()
    if upper.startswith("AUX") and upper[3:].isdigit() and 1 <= int(upper[3:]) <= AUX_CHANNELS:
        return int(upper[3:])
    raise ValueError(f"expected AUX1-AUX{AUX_CHANNELS}, got {name!r}")


def parse_range(text: str) -> tuple[int, int]:
    """ "1700-2100" → (1700, 2100): a mode range in µs, 900-2100 in steps of 25."""
    low, dash, high = text.partition("-")
    if not dash or not low.strip().isdigit() or not high.strip().isdigit():
        raise ValueError(f"expected START-END in µs, e.g. 1700-2100, got {text!r}")
    start, end = int(low), int(high)
    if not 900 <= start < end <= 2100 or start % 25 or end % 25:
        raise ValueError(f"{text}: a mode range runs 900-2100 in steps of 25, start < end")
    return start, end


def override_mask(rcmap: Sequence[int]) -> int:
    """`msp_override_channels_mask` for the sticks under `rcmap`."""
    return sum(1 << channel for channel in rcmap[:STICK_FUNCTIONS])
