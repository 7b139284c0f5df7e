"""Commands: preflight (does the board fail safe when the OBC fails?)."""

from __future__ import annotations

import sys
import tempfile
from functools import partial
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from wftool.cli.fc import find_board, log, port_option
from wftool.cli.number import Number
from wftool.cli.sitl import build_sitl
from wftool.errors import UsageError, VerificationFailed
from wftool.fc.board import leave_open_cli
from wftool.fc.fsp_setup import CMD_TIMEOUT_MS_DEFAULT, CMD_TIMEOUT_MS_RANGE
from wftool.fc.msp import MspClient
from wftool.fsp import DEFAULT_BAUDRATE
from wftool.link.transport import url_problem
from wftool.sitl.process import MAX_PORT_BASE
from wftool.verify.preflight import (
    LIMIT_MS,
    HumanPilot,
    NoPilot,
    Pilot,
    Preflight,
    PreflightReport,
)

console = Console(highlight=False, width=None if sys.stdout.isatty() else 120)


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
    "after the OBC's last fresh command.",
)  # fmt: skip
@click.option(
    "--arm", is_flag=True,
    help="Arm (props off!): the pilot arms, or with the OBC alone the OBC arms on AUX3/AUX4, "
    "so 'still armed' and failsafe stage 2 are checked too.",
)  # fmt: skip
@click.option(
    "--sitl", is_flag=True,
    help="Run on a fresh virtual FC (built if needed), as `configure fsp` leaves it; the "
    "simulated radio is the pilot, moved by wftool.",
)  # fmt: skip
@click.option("--obc-only", is_flag=True, help="With --sitl: the OBC flies alone (RX_MSP).")
@click.option(
    "--cmd-timeout-ms", type=click.IntRange(*CMD_TIMEOUT_MS_RANGE),
    default=CMD_TIMEOUT_MS_DEFAULT, show_default=True,
    help="With --sitl: the virtual FC's fsp_cmd_timeout_ms.",
)  # fmt: skip
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
    port: str | None, fsp_port: str | None, baud: int, limit_ms: float, arm: bool, sitl: bool,
    obc_only: bool, cmd_timeout_ms: int, binary: Path | None, port_base: int, yes: bool,
) -> None:  # fmt: skip
    """Check that the FC fails safe when the OBC dies, stalls, repeats itself or sends garbage.

    wftool plays the OBC on the FSP port and reads the FC back over MSP: with a safety pilot
    the pilot's stick values must be back within --limit-ms after the OBC's last fresh
    command, and stay; with the OBC alone RXLOSS must come within it, then Betaflight's
    failsafe. On a board (props off) you hold the transmitter and are asked to flip the
    override switch. Times are by the FC clock where the FC answers commands with time replies
    (`set fsp_time_reply = ON`; the virtual FC does), else by the host's. Exits 1 naming each
    line that failed.
    """
    if sitl:
        if port or fsp_port:
            raise UsageError("--sitl runs its own virtual FC: leave out --port and --fsp-port")
        report = _on_sitl(binary, port_base, obc_only, cmd_timeout_ms, limit_ms, arm)
    else:
        if obc_only or binary:
            raise UsageError("--obc-only and --binary are for --sitl (a board is as configured)")
        if not fsp_port:
            raise UsageError("give the OBC's FSP port: --fsp-port URL (or --sitl)")
        if problem := url_problem(fsp_port):
            raise UsageError(f"--fsp-port {fsp_port}: {problem}")
        if not yes and not click.confirm("Props off, the board on the bench?", default=False):
            raise UsageError("preflight runs with the props off only")
        board = find_board(port)
        leave_open_cli(board, log)
        pilot = HumanPilot(
            lambda what: click.prompt(f"{what}; then Enter", default="", show_default=False)
        )
        with MspClient.open(board.url) as msp:
            report = Preflight(
                msp, fsp_port, pilot, baudrate=baud, limit_ms=limit_ms, arm=arm, log=log
            ).run()
    _print(report)
    if not report.ok:
        failed = "; ".join(line.name for line in report.failed)
        raise VerificationFailed(f"the board does not fail safe: {failed}")


def _on_sitl(
    binary: Path | None, port_base: int, obc_only: bool, cmd_timeout_ms: int, limit_ms: float,
    arm: bool,
) -> PreflightReport:  # fmt: skip
    from wftool.sitl.radio import SimulatedPilot
    from wftool.sitl.session import (
        FSP_UART,
        PILOT_ARM,
        PILOT_OVERRIDE,
        Motion,
        VirtualFcSession,
    )

    binary = binary or build_sitl(None)
    workdir = Path(tempfile.mkdtemp(prefix="wftool-preflight-"))
    session = VirtualFcSession(
        binary, workdir, motion=Motion(), port_base=port_base or None, pilot=not obc_only,
        cmd_timeout_ms=cmd_timeout_ms,
        time_reply=True,  # preflight times by the FC clock (the host's is no measure of a SITL)
    )  # fmt: skip
    flown = "the OBC alone" if obc_only else "a safety pilot"
    log(f"starting the virtual FC in {workdir} ({flown})")
    with session:
        pilot: Pilot = NoPilot()
        if session.radio is not None:
            pilot = SimulatedPilot(session.radio, PILOT_OVERRIDE, PILOT_ARM)
        with MspClient.open(session.msp_url) as msp:
            closing = partial(session.fc.close_client, FSP_UART)
            preflight = Preflight(
                msp, session.fsp_url, pilot, limit_ms=limit_ms, arm=arm, log=log, closing=closing
            )
            return preflight.run()


def _print(report: PreflightReport) -> None:
    table = Table(title=f"preflight ({report.mode})", title_justify="left")
    for column in ("check", "measured", "limit", ""):
        table.add_column(column)
    for line in report.lines:
        mark = "[green]ok[/]" if line.passed else "[red]FAIL[/]"
        table.add_row(line.name, line.measured, line.limit, mark)
    console.print(table)
    verdict = (
        "[green]the board fails safe[/]" if report.ok else "[red]the board does NOT fail safe[/]"
    )
    console.print(verdict)


COMMANDS: list[click.Command] = [preflight]
