"""Commands: talking to a flight controller (set, config, configure, backup, flash, doctor…)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
from rich.console import Console
from rich.table import Table
from rich.text import Text

from wftool import doctor as doctor_checks
from wftool.cli.number import Number
from wftool.cli.progress import PERCENT, ProgressBars
from wftool.display import shown
from wftool.errors import ProtocolError, UsageError, WftoolError
from wftool.fc.backup import DEFAULT_BACKUP_DIR
from wftool.fc.board import Board, SerialBoard, leave_open_cli
from wftool.fc.fsp_setup import (
    CMD_TIMEOUT_MS_DEFAULT,
    CMD_TIMEOUT_MS_RANGE,
    FAILSAFE_PROCEDURES,
    FSP_BAUD_RATES,
    Control,
    ObcOnly,
    SafetyPilot,
    check_baud,
    fsp_planner,
    parse_channel,
    parse_range,
)
from wftool.fc.msp import MspClient
from wftool.fc.params import ChangeReport, apply_plan, take_backup
from wftool.fc.plan import Plan, Planner, plan_from_assignments, plan_from_file
from wftool.fc.versions import version_of
from wftool.flash import flasher
from wftool.fsp.schedule import DEFAULT_RATE_HZ, RATE_HZ_MAX, RATE_HZ_MIN

F = TypeVar("F", bound=Callable[..., Any])
console = Console(highlight=False, soft_wrap=True)
status = Console(stderr=True, highlight=False, soft_wrap=True)


def log(message: str) -> None:
    status.print(Text.assemble(("wftool:", "dim"), " ", shown(message)))


def find_board(port: str | None, *, present: bool = True) -> Board:
    """The FC to talk to (tests substitute a virtual FC here)."""
    return SerialBoard.find(port, present=present)


port_option = click.option(
    "--port",
    "-p",
    metavar="URL",
    help="Serial device or pyserial URL of the FC [default: the only STM32 USB serial port].",
)
backup_dir_option = click.option(
    "--backup-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=DEFAULT_BACKUP_DIR,
    show_default=True,
    help="Where configuration backups are written.",
)


def uplink_options(command: F) -> F:
    """`configure fsp`'s options of the safety pilot's switch and the command timeout (the
    virtual FC of `preflight --sitl` takes them too)."""
    for option in reversed((
        click.option(
            "--override-switch", metavar="AUXn", default="AUX2", show_default=True,
            help="The pilot's switch that hands roll, pitch, yaw and throttle to the OBC "
            "(the MSP OVERRIDE mode); ARM and the switch stay with the pilot.",
        ),
        click.option(
            "--override-range", metavar="START-END", default="1700-2100", show_default=True,
            help="Where the switch is on, in µs; its low end (up to 1100 µs) must be off.",
        ),
        click.option(
            "--cmd-timeout-ms", type=click.IntRange(*CMD_TIMEOUT_MS_RANGE),
            default=CMD_TIMEOUT_MS_DEFAULT, show_default=True,
            help="fsp_cmd_timeout_ms: this long after its last fresh command the OBC counts "
            "as gone.",
        ),
    )):  # fmt: skip
        command = option(command)
    return command


def _apply(port: str | None, plan: Plan | Planner, backup_dir: Path) -> None:
    report = apply_plan(find_board(port), plan, backup_dir, log)
    _print_report(report)
    if report.mismatches:
        saved = "saved" if report.save_confirmed else "`save` was not confirmed"
        raise ProtocolError(f"{saved}, but read back differs: {'; '.join(report.mismatches)}")


def _print_report(report: ChangeReport) -> None:
    table = Table(title="parameters (read back after save)", title_justify="left")
    for column in ("setting", "scope", "before", "after", ""):
        table.add_column(column)
    for row in report.rows:
        changed = Text("ok", "green") if row.ok else shown(f"wanted {row.requested}", "red")
        cells = (row.name, row.scope or "", row.before, row.after)
        table.add_row(*(shown(cell) for cell in cells), changed)
    if report.features:
        before, after = report.features
        mark = Text("ok", "green") if report.features_ok else Text("not persisted", "red")
        table.add_row("features (MSP)", "", f"0x{before:08x}", f"0x{after:08x}", mark)
    console.print(table)
    console.print(shown(f"backup of the previous configuration: {report.backup}"))


@click.command("set")
@click.argument("assignments", nargs=-1, required=True, metavar="NAME=VALUE...")
@port_option
@backup_dir_option
def set_(assignments: tuple[str, ...], port: str | None, backup_dir: Path) -> None:
    """Change parameters safely: back up, validate all with the FC, apply, save, read back."""
    _apply(port, plan_from_assignments(assignments), backup_dir)


@click.group()
def config() -> None:
    """Apply configuration files."""


def _apply_file_command(name: str, help_text: str) -> click.Command:
    """`config apply` and `restore`: one implementation under two names."""

    @click.command(name, help=help_text)
    @click.argument("file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
    @port_option
    @backup_dir_option
    def apply_file(file: Path, port: str | None, backup_dir: Path) -> None:
        _apply(port, plan_from_file(file), backup_dir)

    return apply_file


config.add_command(
    _apply_file_command(
        "apply", "Apply FILE (a Betaflight CLI script such as `diff` output, or TOML name = value)."
    )
)


@click.group()
def configure() -> None:
    """One-step setups."""


@configure.command("fsp")
@click.option("--uart", type=click.IntRange(1, 10), required=True, help="UART number for FSP.")
@click.option(
    "--baud", type=int, required=True,
    help=f"FSP baud rate: one of the FC's ({FSP_BAUD_RATES[0]} ... {FSP_BAUD_RATES[-1]}).",
)  # fmt: skip
@click.option(
    "--rate",
    type=click.IntRange(RATE_HZ_MIN, RATE_HZ_MAX),
    default=DEFAULT_RATE_HZ,
    show_default=True,
    help="Target FSP sample rate (fsp_rate_hz).",
)
@uplink_options
@click.option(
    "--obc-only", is_flag=True,
    help="No safety pilot: the OBC is the FC's only receiver (feature RX_MSP). Needs "
    "--failsafe-procedure.",
)  # fmt: skip
@click.option(
    "--failsafe-procedure", type=click.Choice(list(FAILSAFE_PROCEDURES)),
    help="With --obc-only: what the FC does when the OBC is gone (failsafe stage 2).",
)  # fmt: skip
@port_option
@backup_dir_option
def configure_fsp(
    uart: int, baud: int, rate: int, override_switch: str, override_range: str,
    cmd_timeout_ms: int, obc_only: bool, failsafe_procedure: str | None, port: str | None,
    backup_dir: Path,
) -> None:  # fmt: skip
    """Set up FSP on a UART: port, who flies, command timeout, bidir DShot, RPM filters, rates.

    By default the board's radio stays its receiver and the OBC's commands override roll,
    pitch, yaw and throttle only once the pilot has engaged it with --override-switch (the
    OBC ready, the switch turned on); a silent, stuck, garbled, restarted or twinned OBC
    hands them back to the pilot within --cmd-timeout-ms, until engaged again. --obc-only
    makes the OBC the only receiver, arming only by its arming requests (ARM on AUX1, held
    by the FC): when it is gone, Betaflight's failsafe does what --failsafe-procedure says,
    and no human can take over. What the FC will do is printed before anything is applied.
    """
    try:
        check_baud(baud)
    except ValueError as exc:
        raise UsageError(f"--baud: {exc}") from None
    control = _control(obc_only, failsafe_procedure, override_switch, override_range)
    _apply(
        port,
        fsp_planner(uart, baud, rate, control=control, cmd_timeout_ms=cmd_timeout_ms),
        backup_dir,
    )


def _control(obc_only: bool, procedure: str | None, switch: str, on_range: str) -> Control:
    """Who flies, from the options; bad combinations refused before the FC is touched."""
    source = click.get_current_context()
    switch_given = (
        source.get_parameter_source("override_switch") != click.core.ParameterSource.DEFAULT
    )
    range_given = (
        source.get_parameter_source("override_range") != click.core.ParameterSource.DEFAULT
    )
    if obc_only:
        if procedure is None:
            raise UsageError(
                "--obc-only needs --failsafe-procedure drop|land|gps-rescue: what the FC does "
                "when the OBC is gone, since no pilot can take over"
            )
        if switch_given or range_given:
            raise UsageError(
                "--override-switch/--override-range are for a safety pilot, not --obc-only"
            )
        return ObcOnly(procedure)
    if procedure is not None:
        raise UsageError(
            "--failsafe-procedure is for --obc-only; with a safety pilot losing the radio is "
            "the board's own failsafe set-up"
        )
    try:
        return SafetyPilot(parse_channel(switch), parse_range(on_range))
    except ValueError as exc:
        raise UsageError(str(exc)) from None


@click.command()
@port_option
@backup_dir_option
def backup(port: str | None, backup_dir: Path) -> None:
    """Save the FC's configuration (`diff all`) to a timestamped file. The FC reboots."""
    console.print(shown(take_backup(find_board(port), backup_dir, log)))


restore = _apply_file_command(
    "restore", "Restore a backup FILE through the same safe path as `set` (backs up first)."
)


@click.command()
@port_option
def info(port: str | None) -> None:
    """Identify the FC over MSP: firmware, board, build, and how wftool talks to it (exit 2
    for a firmware it does not know)."""
    board = find_board(port)
    leave_open_cli(board, log)
    with MspClient.open(board.url) as msp:
        fc = msp.identify()
    for line in (
        f"{fc.variant} {fc.version} (MSP API {fc.api})",
        f"board {fc.board.board_name or '-'} target {fc.board.target_name} "
        f"({fc.board.board_identifier}), flash bootloader: {fc.board.has_flash_bootloader}",
        f"build {fc.build.git_revision} {fc.build.date} {fc.build.time}",
    ):
        console.print(shown(line))
    version = version_of(fc)
    console.print(
        shown(
            f"wftool talks to it as {version.name} (FSP serial function "
            f"{version.fsp_function}, up to {version.fsp_baud_max} baud)"
        )
    )


@click.command()
@click.argument(
    "firmware", required=False, type=click.Path(exists=True, dir_okay=False, path_type=Path)
)
@port_option
@backup_dir_option
@click.option(
    "--build-dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Where `wftool build` left <target>/manifest.json [the build/ of the wftool "
    "checkout around the current directory].",
)
@click.option("--force", is_flag=True, help="Flash even if board or MCU do not match.")
@click.option("--full-erase", is_flag=True, help="Mass-erase first: wipes the configuration.")
@click.option("--no-reboot", is_flag=True, help="The FC is already in DFU mode (no backup).")
@click.option("--restore", is_flag=True, help="Replay the backup after flashing.")
@click.option(
    "--dfu-timeout",
    type=Number(0, 3600, min_open=True, unit="s"),
    default=30.0,
    show_default=True,
    help="Seconds to wait for the DFU bootloader.",
)
def flash(
    firmware: Path | None,
    port: str | None,
    backup_dir: Path,
    build_dir: Path | None,
    force: bool,
    full_erase: bool,
    no_reboot: bool,
    restore: bool,
    dfu_timeout: float,
) -> None:
    """Flash FIRMWARE (.hex, .bin or manifest.json; default: the last build for this FC)."""
    board = find_board(port, present=not no_reboot)
    with ProgressBars(status, PERCENT, per_phase=True) as bars:
        report = flasher.flash_firmware(
            board,
            firmware,
            backup_dir=backup_dir,
            build_dir=build_dir,
            force=force,
            full_erase=full_erase,
            no_reboot=no_reboot,
            restore=restore,
            dfu_timeout=dfu_timeout,
            progress=lambda phase, percent, _bytes: bars(phase, percent, 100),
            log=log,
        )
    erased = ", ".join(str(s) for s in sorted(report.erased))
    console.print(
        shown(
            f"flashed {report.firmware.path.name}; erased sectors {erased}; "
            f"{report.verified} bytes read back as written"
        )
    )
    if report.backup:
        console.print(shown(f"configuration backup: {report.backup}"))
    if report.restored:
        _print_report(report.restored)


@click.command()
@click.option("--fix", is_flag=True, help="Install the udev rules (needs root).")
@click.option(
    "--udev-rules-dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Check and install rules here instead of the system directories.",
)
def doctor(fix: bool, udev_rules_dir: Path | None) -> None:
    """Check the toolchain, dfu-util, serial ports, udev rules, groups, ModemManager."""
    rules_dirs = (udev_rules_dir,) if udev_rules_dir else doctor_checks.SYSTEM_RULES_DIRS
    if fix:
        target = udev_rules_dir or doctor_checks.SYSTEM_RULES_DIRS[0]
        for change in doctor_checks.install_udev_rules(target, reload=udev_rules_dir is None):
            log(change)
    checks = doctor_checks.run_checks(rules_dirs)
    colour = {"ok": "green", "warn": "yellow", "fail": "red"}
    for check in checks:
        mark = (f"{check.status:>4}", colour[check.status])
        console.print(Text.assemble(mark, " ", shown(f"{check.name}: {check.detail}")))
        if check.status != "ok" and check.fix:
            console.print(shown(f"      fix: {check.fix}"))
    failed = [check.name for check in checks if check.status == "fail"]
    if failed:
        raise WftoolError(f"not ready: {', '.join(failed)}")


COMMANDS: list[click.Command] = [
    set_,
    config,
    configure,
    backup,
    restore,
    info,
    flash,
    doctor,
]
