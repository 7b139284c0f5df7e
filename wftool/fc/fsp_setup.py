"""`wftool configure fsp`: everything FSP needs (its UART, the MSP receiver, bidirectional
DShot, the filter defaults, the rates), planned from what the FC reports (docs/design.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from wftool.errors import CliCommandError, ParameterError, ProtocolError
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import FEATURE_RX_MSP, RECEIVER_FEATURES
from wftool.fc.params import Command, FeatureChange, Plan, Planner, set_command
from wftool.fsp.schedule import DEFAULT_RATE_HZ

FSP_FUNCTION = 1 << 19
MSP_FUNCTION = 1 << 0
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
    1 << 18: "GIMBAL", FSP_FUNCTION: "FSP",
}  # fmt: skip
"""`serialPortFunction_e` (io/serial.h), only to name what FSP replaces."""


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


def fsp_planner(
    uart: int,
    baud: int,
    rate_hz: int = DEFAULT_RATE_HZ,
    time_reply: bool | None = None,
    serial_update_rate_hz: int | None = None,
) -> Planner:
    """A planner (see `wftool.fc.params.apply_plan`) for FSP on UART`uart` at `baud`;
    `time_reply` sets `fsp_time_reply` (None: leave it); `serial_update_rate_hz` None sets
    the highest the FC allows."""

    def plan(session: CliSession) -> Plan:
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
                f"{target} is the FC's only MSP port; giving it to FSP would lock out MSP and "
                "the CLI"
            )
        replaced = ports[target].functions & ~FSP_FUNCTION
        if replaced:
            notes.append(f"{target}: FSP replaces {function_names(replaced)} on this port")
        commands.append(
            Command(replace(ports[target], functions=FSP_FUNCTION, msp_baud=baud).command())
        )
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
        if time_reply is not None:
            commands.append(set_command("fsp_time_reply", "ON" if time_reply else "OFF"))
        if serial_update_rate_hz is not None:
            commands.append(set_command("serial_update_rate_hz", str(serial_update_rate_hz)))
        elif update_rate := session.get("serial_update_rate_hz").int_range:
            commands.append(set_command("serial_update_rate_hz", str(update_rate[1])))
        receiver = FeatureChange(enable=FEATURE_RX_MSP, disable=RECEIVER_FEATURES & ~FEATURE_RX_MSP)
        return Plan(commands, receiver, notes)

    return plan
