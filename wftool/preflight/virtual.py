"""Preflight on the virtual FC, configured as a board that flies: by `configure fsp`'s own
planner with the options the board gets, or with a user's backup (`diff all`) loaded, so
what is checked is that configuration, not a fresh FC's. The simulated radio is the pilot.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

from wftool.errors import CliCommandError, UsageError
from wftool.fc.cli_session import CliSession
from wftool.fc.fsp_setup import (
    Control,
    ObcOnly,
    SafetyPilot,
    SerialPortConfig,
)
from wftool.fc.migrate import migrate
from wftool.fc.msp import FEATURE_RX_MSP, FEATURE_RX_UDP, RECEIVER_FEATURES
from wftool.fc.plan import Command, FeatureChange, Plan, Planner, plan_from_file, set_command
from wftool.fc.versions import VERSIONS, BetaflightVersion
from wftool.preflight.flight import LIMIT_MS
from wftool.preflight.pilot import NoPilot, Pilot, RadioPilot
from wftool.preflight.run import Preflight
from wftool.preflight.settings import BoardSettings
from wftool.progress import Log, quiet
from wftool.sitl.process import DEFAULT_PORT_BASE, scratch_workdir
from wftool.sitl.radio import SimulatedRadio
from wftool.sitl.session import FSP_UART, MSP_UART, Motion, VirtualFcSession

SITL_UARTS = range(1, 9)
"""The UARTs the virtual FC has (TCP ports)."""
HARDWARE_VERBS = frozenset(
    {"resource", "timer", "dma", "board_name", "manufacturer_id", "mcu_id", "signature", "led",
     "color", "mode_color", "vtxtable", "vtx", "beacon", "beeper", "mixer", "mmix", "smix",
     "servo", "defaults"}
)  # fmt: skip
"""Lines of a board's backup that describe its hardware (or reset everything): not loaded."""
VIRTUAL_AIRFRAME = (set_command("runaway_takeoff_prevention", "OFF"),)
"""What the virtual FC needs besides any configuration: its gyro is synthetic motion, which
no motor moves, so a stick held off centre while armed winds the PID sum up until Betaflight
disarms ("runaway takeoff")."""


@dataclass(frozen=True)
class Backup:
    """A board's configuration as the virtual FC takes it."""

    path: Path
    planner: Planner
    fsp_uart: int
    obc_alone: bool
    skipped: list[str]
    """What of the file the virtual FC does not take, filled in while it is loaded."""


def load_backup(path: Path) -> Backup:
    """A backup (`wftool backup`, or a plain `diff all`) for the virtual FC: its settings,
    modes, map and FSP port, without the board's hardware; its receiver the simulated radio
    unless the backup's feature mask says the MSP receiver (the OBC alone). `UsageError`
    for a file that puts FSP on no UART of the virtual FC's."""
    plan = plan_from_file(path)
    serial = [SerialPortConfig.parse(c.text) for c in plan.commands if c.verb == "serial"]
    # FSP's function bit as the Betaflight that wrote the file numbers it (any, unsaid)
    writers = [plan.written_by.version] if plan.written_by else list(VERSIONS)
    fsp = [c for c in serial if any(c.functions & v.fsp_function for v in writers)]
    uarts = [int(c.port[4:]) for c in fsp if c.port[4:].isdigit() and int(c.port[4:]) in SITL_UARTS]
    if not uarts:
        bits = " or ".join(str(v.fsp_function) for v in writers)
        raise UsageError(
            f"{path}: FSP is on no UART1-UART8 there (`serial` with function {bits}): "
            "nothing to check (run `configure fsp` first, and back it up)"
        )
    obc_alone = plan.features is not None and bool(plan.features.enable & FEATURE_RX_MSP)
    skipped: list[str] = []

    def planner(session: CliSession, version: BetaflightVersion) -> Plan:
        skipped.clear()
        commands: list[Command] = []
        for command in migrate(plan, version).plan.commands:
            adapted = _adapted(session, version, command)
            if adapted is None:
                skipped.append(command.text.split(" =")[0])
            else:
                commands.append(adapted)
        commands += [*VIRTUAL_AIRFRAME, set_command("fsp_time_reply", "ON")]
        receiver = FEATURE_RX_MSP if obc_alone else FEATURE_RX_UDP
        features = FeatureChange(enable=receiver, disable=RECEIVER_FEATURES & ~receiver)
        return Plan(commands, features)

    return Backup(path, planner, uarts[0], obc_alone, skipped)


def _adapted(session: CliSession, version: BetaflightVersion, command: Command) -> Command | None:
    """`command` as the virtual FC takes it, or None where it cannot."""
    verb = command.verb
    if verb in HARDWARE_VERBS:
        return None
    if verb == "set":
        try:
            session.get(command.assignment()[0])
        except CliCommandError:
            return None
        return command
    if verb == "serial":
        config = SerialPortConfig.parse(command.text)
        number = config.port[4:]
        if not config.port.startswith("UART") or not number.isdigit():
            return None
        if int(number) not in SITL_UARTS:
            return None
        msp = version.serial_functions["MSP"]
        functions = config.functions & (version.fsp_function | msp)
        functions |= msp if int(number) == MSP_UART else 0
        return Command(replace(config, functions=functions).command(), command.origin)
    if verb == "feature":
        name = command.text.split()[-1].lstrip("-").upper()
        return None if name.startswith("RX_") else command
    return command


def configure_fsp_options(control: Control, cmd_timeout_ms: int) -> str:
    """The `configure fsp` options the virtual FC was configured with, as a user types them."""
    if isinstance(control, ObcOnly):
        who = f"--obc-only --failsafe-procedure {control.failsafe_procedure}"
    else:
        start, end = control.on_us
        who = f"--override-switch AUX{control.switch} --override-range {start}-{end}"
    return f"{who} --cmd-timeout-ms {cmd_timeout_ms}"


@contextlib.contextmanager
def on_virtual_fc(
    binary: Path,
    *,
    control: Control | None = None,
    cmd_timeout_ms: int = 50,
    backup: Backup | None = None,
    port_base: int | None = DEFAULT_PORT_BASE,
    workdir: Path | None = None,
    log: Log = quiet,
    limit_ms: float = LIMIT_MS,
    arm: bool = False,
    settings_only: bool = False,
    only: Sequence[str] | None = None,
    trials: int = 1,
) -> Iterator[Preflight]:
    """A preflight (`limit_ms` to `trials`: `Preflight`'s) on a virtual FC configured by
    `configure fsp` (`control`, `cmd_timeout_ms`) or with `backup`, whose report's header
    says which; the FC runs until the block ends. `control` None: a safety pilot, the switch
    AUX2 on at 1700-2100 µs (`configure fsp`'s defaults)."""
    control = control or SafetyPilot()
    with scratch_workdir(workdir, "wftool-preflight-") as workdir:
        if backup is not None:
            session = VirtualFcSession(
                binary, workdir, motion=Motion(), port_base=port_base, pilot=not backup.obc_alone,
                configuration=backup.planner, fsp_uart=backup.fsp_uart,
            )  # fmt: skip
            subject = f"the configuration of {backup.path}"
        else:
            session = VirtualFcSession(
                binary, workdir, motion=Motion(), port_base=port_base, control=control,
                cmd_timeout_ms=cmd_timeout_ms, time_reply=True,
            )  # fmt: skip
            subject = (
                f"configured by `configure fsp --uart {FSP_UART} "
                f"{configure_fsp_options(control, cmd_timeout_ms)}`, the planner a board gets"
            )
        log(f"starting the virtual FC in {workdir}")
        with session:
            lines = [f"virtual FC ({binary}), {subject}"]
            if backup is not None and backup.skipped:
                lines.append(f"not loaded (hardware, or not in SITL): {', '.join(backup.skipped)}")
            virtual = ["fsp_time_reply ON (FC-clock timings)", "runaway_takeoff_prevention OFF"]
            if session.radio is not None:
                virtual.append("the simulated radio the pilot's")
                if backup is None:
                    virtual.append("ARM on its AUX1")
            lines.append(f"for the virtual FC: {', '.join(virtual)}")
            yield Preflight(
                session.fc, session.fsp_url, partial(_pilot, session.radio), subject=lines, log=log,
                closing=partial(session.fc.close_client, session.fsp_uart), limit_ms=limit_ms,
                arm=arm, settings_only=settings_only, only=only, trials=trials,
            )  # fmt: skip


def _pilot(radio: SimulatedRadio | None, settings: BoardSettings) -> Pilot:
    if radio is None:
        return NoPilot()
    return RadioPilot(radio, settings)
