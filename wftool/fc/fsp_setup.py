"""`wftool configure fsp`: everything FSP needs (its UART, who flies — a safety pilot by
default, or the OBC alone —, bidirectional DShot, the filter defaults, the rates), planned
from what the FC reports (docs/design.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from wftool.errors import CliCommandError, ParameterError, ProtocolError
from wftool.fc.cli_session import CliSession
from wftool.fc.modes import (
    AUX_CHANNELS,
    MODE_ARM,
    MODE_MSP_OVERRIDE,
    SWITCH_LOW_US,
    AuxRange,
)
from wftool.fc.msp import FEATURE_RX_MSP, RECEIVER_FEATURES
from wftool.fc.plan import Command, FeatureChange, Plan, Planner, set_command
from wftool.fc.versions import VERSIONS, BetaflightVersion
from wftool.fsp.schedule import DEFAULT_RATE_HZ

FSP_BAUD_RATES = tuple(sorted({r for v in VERSIONS for r in v.baud_rates if r <= v.fsp_baud_max}))
"""The rates some Betaflight wftool knows runs an FSP port at (the plan checks the FC's own)."""
MSP_BAUD_DEFAULT = 115200
"""A port's MSP baud when FSP leaves it: Betaflight's default, which any `serial` takes."""
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


PROOF_MS = 500
"""How long an OBC's link must have been live before the pilot can engage it (the
firmware's FSP_AUTHORITY_PROOF_US, spec §15; every uplink status reports it)."""
OBC_AUX = (2, 3)
"""The AUX channels (0 = AUX1) a command carries, aux3 and aux4: the OBC's."""
ARM_AUX = 0
"""AUX1: the ARM switch the FC holds for the OBC alone (spec §14)."""
ARM_RANGE_US = (1700, 2100)
"""ARM's range on AUX1 with the OBC alone: on at the 2000 µs the FC holds for an arming
request, off at its 1000 µs."""


def check_baud(baud: int) -> int:
    """`baud`, if some Betaflight wftool knows runs an FSP port at it (`FSP_BAUD_RATES`);
    else
    `ValueError` saying which rates are."""
    if baud not in FSP_BAUD_RATES:
        listed = ", ".join(str(rate) for rate in FSP_BAUD_RATES)
        raise ValueError(f"the FC takes no baud rate {baud} for a port: one of {listed}")
    return baud


@dataclass(frozen=True)
class SafetyPilot:
    """The board's radio is the receiver; the OBC overrides the sticks while the pilot has
    engaged it with the switch (AUX`switch`) within `on_us` (spec §15). A range that takes
    in the switch's low end (≤ `SWITCH_LOW_US`) has no off position: `ValueError`."""

    switch: int = 2
    on_us: tuple[int, int] = (1700, 2100)

    def __post_init__(self) -> None:
        start, end = self.on_us
        if AuxRange(0, MODE_MSP_OVERRIDE, self.switch - 1, start, end).off_us is None:
            raise ValueError(
                f"the override range {start}-{end} has no off position: a switch's low end "
                f"(up to {SWITCH_LOW_US} µs) lies in it, so the OBC would fly with the switch "
                "off — start it above that, e.g. 1700-2100"
            )


@dataclass(frozen=True)
class ObcOnly:
    """The OBC is the FC's only receiver; `failsafe_procedure` (a `FAILSAFE_PROCEDURES`
    key) is what the FC does when it is gone."""

    failsafe_procedure: str


Control = SafetyPilot | ObcOnly


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


def engagement_outlook(
    pilot: SafetyPilot,
    settings: dict[str, str],
    timeout_ms: int,
    arm: AuxRange | None,
) -> list[str]:
    """Who flies with a safety pilot and how the pilot engages the OBC (spec §15), from the
    FC's settings: one line per step."""
    start, end = pilot.on_us
    switch = f"AUX{pilot.switch}"
    arm_text = arm.describe().split(": ", 1)[1] if arm is not None else "no ARM switch yet"
    return [
        "who flies: the pilot — the board's radio is the receiver; the OBC can only ever "
        "steer roll, pitch, yaw and throttle, and only once the pilot has engaged it:",
        f"  1. the OBC sends fresh commands, every value within the FC's pulse range "
        f"{settings['rx_min_usec']}-{settings['rx_max_usec']} µs, for {PROOF_MS} ms without a "
        "break: its uplink status says READY",
        f"  2. the pilot turns {switch} off and on (into {start}-{end}): ENGAGED, the OBC steers "
        "(on before READY, it engages nothing: off and on again)",
        f"  the sticks are the pilot's again at once, until the pilot engages it again, when the "
        f"OBC sends no fresh command for {timeout_ms} ms (fsp_cmd_timeout_ms), {switch} goes "
        "off, a value outside the pulse range comes, a second program commands, the OBC's "
        "clock steps back, the radio is lost (Betaflight's failsafe, as without FSP) or the "
        "FC disarms",
        f"  ARM ({arm_text}), {switch} and every AUX channel are the pilot's alone",
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

    try:
        check_baud(baud)
    except ValueError as exc:
        raise ParameterError(str(exc)) from None

    def plan(session: CliSession, version: BetaflightVersion) -> Plan:
        commands, notes = _fsp_port(session, version, uart, baud, control)
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
            notes.extend(
                engagement_outlook(control, _settings(session), cmd_timeout_ms, _arm(session))
            )
        else:
            receiver = _obc_only(session, control, cmd_timeout_ms, commands, notes)
        return Plan(commands, receiver, notes)

    return plan


def _fsp_port(
    session: CliSession, version: BetaflightVersion, uart: int, baud: int, control: Control
) -> tuple[list[Command], list[str]]:
    """The `serial` lines that give UART`uart` to FSP alone (FSP's function bit and baud
    rates as VERSION has them), and what they replace."""
    if baud not in version.baud_rates or baud > version.fsp_baud_max:
        rates = ", ".join(str(rate) for rate in version.baud_rates if rate <= version.fsp_baud_max)
        raise ParameterError(
            f"{baud} is not a baud rate of an FSP port on {version.name} ({rates})"
        )
    fsp, msp = version.fsp_function, version.serial_functions["MSP"]
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
        if config.port != target and config.functions & fsp:
            left = replace(config, functions=config.functions & ~fsp, msp_baud=MSP_BAUD_DEFAULT)
            commands.append(Command(left.command()))  # FSP's rate refused without FSP
            notes.append(
                f"FSP moves from {config.port} to {target} ({config.port}'s MSP baud back to "
                f"{MSP_BAUD_DEFAULT})"
            )
    if not any(c.functions & msp for c in ports.values() if c.port != target):
        raise ParameterError(
            f"{target} is the FC's only MSP port; giving it to FSP would lock out MSP and the CLI"
        )
    receiver = version.serial_functions["RX_SERIAL"]
    if isinstance(control, SafetyPilot) and ports[target].functions & receiver:
        raise ParameterError(
            f"{target} carries the receiver (RX_SERIAL), the safety pilot's radio: give FSP "
            "another UART"
        )
    replaced = ports[target].functions & ~fsp
    if replaced:
        notes.append(f"{target}: FSP replaces {version.function_names(replaced)} on this port")
    commands.append(Command(replace(ports[target], functions=fsp, msp_baud=baud).command()))
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
    mask = override_mask(rcmap)
    before = session.get("msp_override_channels_mask").value
    if before != str(mask):
        notes.append(
            f"msp_override_channels_mask {before} → {mask}: the sticks alone (an AUX channel "
            "in it would be the OBC's to move, and no AUX channel is)"
        )
    commands.append(set_command("msp_override_channels_mask", str(mask)))
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
    notes.append(f"MSP OVERRIDE on AUX{pilot.switch} {start}-{end}: the pilot's engagement switch")
    return receiver


def _settings(session: CliSession) -> dict[str, str]:
    names = ("failsafe_delay", "failsafe_landing_time", "failsafe_throttle", "rx_min_usec",
             "rx_max_usec")  # fmt: skip
    return {name: session.get(name).value for name in names}


def _arm(session: CliSession) -> AuxRange | None:
    """The FC's (first) ARM range, if it has one."""
    return next((r for r in aux_ranges(session) if r.usable and r.mode == MODE_ARM), None)


def _obc_only(
    session: CliSession,
    obc: ObcOnly,
    timeout_ms: int,
    commands: list[Command],
    notes: list[str],
) -> FeatureChange:
    """The MSP receiver as the FC's receiver, ARM on AUX1 for the FC to hold (spec §14), the
    failsafe procedure, what loss means. Refused while a mode sits where a command sent by
    accident would switch it (AUX3, AUX4: the OBC's), where nothing drives it (AUX2, AUX5 and
    up: stuck at its boot value), or on AUX1 other than ARM."""
    ranges = aux_ranges(session)
    used = [r for r in ranges if r.usable]
    refused = [
        f"{r.describe()} ({_why_not(r)})"
        for r in used
        if r.channel != ARM_AUX or r.mode != MODE_ARM
    ]
    if refused:
        raise ParameterError(
            "with the OBC alone no mode may sit on a channel it drives or FSP never drives, "
            f"nor anything but ARM on AUX1: {'; '.join(refused)} — remove them first"
        )
    arms = [r for r in used if r.mode == MODE_ARM]
    free = [r for r in ranges if not r.usable]
    if not arms and not free:
        raise ParameterError("every mode range slot (`aux`) is in use: free one for ARM")
    slot = arms[0].slot if arms else free[0].slot
    start, end = ARM_RANGE_US
    commands.append(Command(AuxRange(slot, MODE_ARM, ARM_AUX, start, end).command()))
    for extra in arms[1:]:
        commands.append(Command(AuxRange(extra.slot, 0, 0, 900, 900).command()))
        notes.append(f"{extra.describe()} cleared: ARM is AUX1 {start}-{end}")
    procedure = FAILSAFE_PROCEDURES[obc.failsafe_procedure]
    commands.append(set_command("failsafe_procedure", procedure))
    settings = _settings(session)
    notes.append(
        f"who flies: the OBC alone — its commands are the FC's receiver, every value within "
        f"the FC's pulse range {settings['rx_min_usec']}-{settings['rx_max_usec']} µs; it arms "
        f"and disarms only by an arming request (spec §14): the FC holds ARM on AUX1 "
        f"({start}-{end}), which no command moves"
    )
    notes.extend(failsafe_outlook(settings, timeout_ms, procedure))
    return FeatureChange(enable=FEATURE_RX_MSP, disable=RECEIVER_FEATURES & ~FEATURE_RX_MSP)


def _why_not(mode_range: AuxRange) -> str:
    """Why a mode range cannot stay with the OBC alone."""
    if mode_range.channel in OBC_AUX:
        return "the OBC's channel: a command sent by accident would switch it"
    if mode_range.channel == ARM_AUX:
        return "AUX1 is the ARM switch the FC holds for the OBC"
    return "FSP never drives it: stuck at its boot value"


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
