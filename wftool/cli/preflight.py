"""Commands: preflight (does control change hands only as the board's configuration says?)."""

from __future__ import annotations

import sys
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from wftool.cli.fc import _control, find_board, log, port_option, uplink_options
from wftool.cli.number import Number
from wftool.cli.sitl import build_sitl
from wftool.errors import UsageError, VerificationFailed
from wftool.fc.board import leave_open_cli
from wftool.fc.fsp_setup import FAILSAFE_PROCEDURES
from wftool.fsp import DEFAULT_BAUDRATE
from wftool.link.transport import url_problem
from wftool.preflight.flight import LIMIT_MS
from wftool.preflight.pilot import HumanPilot
from wftool.preflight.report import Outcome, Report
from wftool.preflight.run import Preflight
from wftool.preflight.scenarios import BY_KEY
from wftool.sitl.process import MAX_PORT_BASE

console = Console(highlight=False, width=None if sys.stdout.isatty() else 140)
MARKS = {Outcome.PASSED: "[green]ok[/]", Outcome.FAILED: "[red]FAIL[/]",
         Outcome.NOT_CHECKED: "[yellow]not checked[/]"}  # fmt: skip


@click.command("preflight")
@port_option
@click.option("--fsp-port", metavar="URL", help="The OBC's FSP port (device or pyserial URL).")
@click.option(
    "--baud", type=click.IntRange(1), default=DEFAULT_BAUDRATE, show_default=True,
    help="FSP baud rate.",
)  # fmt: skip
@click.option(
    "--limit-ms", type=Number(1, 1000, unit="ms"), default=LIMIT_MS, show_default=True,
    help="The pilot's sticks back (safety pilot), or RXLOSS (OBC alone), within this long "
    "after the OBC's last fresh command; fsp_cmd_timeout_ms at most this.",
)  # fmt: skip
@click.option(
    "--arm", is_flag=True,
    help="Arm (props off!): the pilot arms, or the OBC alone asks the FC to, so 'stays "
    "armed', restarts and failsafe stage 2 are checked too. Without it preflight commands no "
    "armed FC.",
)  # fmt: skip
@click.option(
    "--settings-only", is_flag=True,
    help="Read and check the board's settings only: nothing is commanded.",
)  # fmt: skip
@click.option(
    "--scenario", "scenarios", multiple=True, type=click.Choice(list(BY_KEY)),
    help="Play only this scenario (repeatable) [all that apply].",
)  # fmt: skip
@click.option(
    "--sitl", is_flag=True,
    help="Run on a virtual FC (built if needed) configured by `configure fsp` with the "
    "options below — or with --config — and flown by the simulated radio.",
)  # fmt: skip
@click.option(
    "--config", type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="With --sitl: load this backup (`wftool backup`, or a `diff all`) into the virtual FC "
    "and check that configuration.",
)  # fmt: skip
@click.option(
    "--obc-only", is_flag=True,
    help="With --sitl: configure fsp --obc-only (the switch and timeout options below: with "
    "--sitl, configure fsp's).",
)  # fmt: skip
@click.option(
    "--failsafe-procedure", type=click.Choice(list(FAILSAFE_PROCEDURES)),
    help="With --sitl --obc-only: configure fsp --failsafe-procedure [drop].",
)  # fmt: skip
@uplink_options
@click.option(
    "--binary", type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="With --sitl: this SITL program [build the patched one].",
)  # fmt: skip
@click.option(
    "--port-base", type=click.IntRange(0, MAX_PORT_BASE), default=0,
    help="With --sitl: the virtual FC's port base [0: any free ports].",
)  # fmt: skip
@click.option("--yes", is_flag=True, help="On a board: the props are off; do not ask.")
def preflight(
    port: str | None, fsp_port: str | None, baud: int, limit_ms: float, arm: bool,
    settings_only: bool, scenarios: tuple[str, ...], sitl: bool, config: Path | None,
    obc_only: bool, failsafe_procedure: str | None, override_switch: str, override_range: str,
    cmd_timeout_ms: int, binary: Path | None, port_base: int, yes: bool,
) -> None:  # fmt: skip
    """Check that control changes hands only as it must: read and check the board's own
    settings, then play the OBC failing in every way and time what the FC does.

    wftool plays the OBC on the FSP port and reads the FC back over MSP. With a safety pilot
    the OBC steers only once the pilot engaged it, and after any loss the pilot's sticks are
    back within --limit-ms and stay until the pilot engages it again; with the OBC alone
    RXLOSS comes within it, then Betaflight's failsafe, and nothing the OBC sends by accident
    disarms. On a board (props off) you hold the transmitter and are asked to flip switches.
    Times are by the FC clock where the FC answers commands (`set fsp_time_reply = ON`; the
    virtual FC does), else by the host's. A line not checked says so. An armed FC is refused
    (exit 2) unless --arm. Exits 1 naming each line that failed.
    """
    only = scenarios or None
    if sitl:
        if port or fsp_port:
            raise UsageError("--sitl runs its own virtual FC: leave out --port and --fsp-port")
        report = _on_sitl(
            binary, config, port_base, obc_only, failsafe_procedure, override_switch,
            override_range, cmd_timeout_ms, limit_ms, arm, settings_only, only,
        )  # fmt: skip
    else:
        given = {"--obc-only": obc_only, "--config": config, "--binary": binary,
                 "--failsafe-procedure": failsafe_procedure}  # fmt: skip
        if misplaced := [name for name, value in given.items() if value]:
            raise UsageError(f"{', '.join(misplaced)}: for --sitl (a board is as configured)")
        if not fsp_port:
            raise UsageError("give the OBC's FSP port: --fsp-port URL (or --sitl)")
        if problem := url_problem(fsp_port):
            raise UsageError(f"--fsp-port {fsp_port}: {problem}")
        asked = settings_only or yes
        if not asked and not click.confirm("Props off, the board on the bench?", default=False):
            raise UsageError("preflight runs with the props off only")
        board = find_board(port)
        leave_open_cli(board, log)
        pilot = HumanPilot(
            lambda what: click.prompt(f"{what}; then Enter", default="", show_default=False)
        )
        report = Preflight(
            board, fsp_port, lambda settings: pilot, baudrate=baud, limit_ms=limit_ms, arm=arm,
            settings_only=settings_only, only=only, log=log,
            subject=[f"board on {board.url}, FSP on {fsp_port} at {baud} baud"],
        ).run()  # fmt: skip
    _print(report)
    if not report.ok:
        raise VerificationFailed(f"preflight: {report.verdict}")


def _on_sitl(
    binary: Path | None, config: Path | None, port_base: int, obc_only: bool,
    procedure: str | None, switch: str, on_range: str, cmd_timeout_ms: int, limit_ms: float,
    arm: bool, settings_only: bool, only: tuple[str, ...] | None,
) -> Report:  # fmt: skip
    from wftool.preflight.virtual import load_backup, on_virtual_fc

    source = click.get_current_context().get_parameter_source
    backup = None
    if config is not None:
        configured = [
            f"--{name.replace('_', '-')}"
            for name in (
                "obc_only",
                "failsafe_procedure",
                "override_switch",
                "override_range",
                "cmd_timeout_ms",
            )
            if source(name) is not click.core.ParameterSource.DEFAULT
        ]
        if configured:
            raise UsageError(f"--config is the configuration: leave out {', '.join(configured)}")
        backup = load_backup(config)
        control = None
    else:
        procedure = procedure or ("drop" if obc_only else None)
        control = _control(obc_only, procedure, switch, on_range)
    binary = binary or build_sitl(None)
    with on_virtual_fc(
        binary, control=control, cmd_timeout_ms=cmd_timeout_ms, backup=backup,
        port_base=port_base or None, limit_ms=limit_ms, arm=arm, settings_only=settings_only,
        only=only, log=log,
    ) as preflight:  # fmt: skip
        return preflight.run()


def _print(report: Report) -> None:
    for said in report.subject:
        console.print(escape(said))
    table = Table(title="preflight", title_justify="left")
    for column in ("check", "measured", "limit", ""):
        table.add_column(column)
    for line in report.lines:
        name = f"{line.name} ({line.clock})" if line.clock else line.name
        table.add_row(escape(name), escape(line.measured), escape(line.limit), MARKS[line.outcome])
    console.print(table)
    colour = "green" if report.ok else "red"
    console.print(f"[{colour}]{escape(report.verdict)}[/]")


COMMANDS: list[click.Command] = [preflight]
