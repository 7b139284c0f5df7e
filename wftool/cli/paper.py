"""Commands: the paper's evaluation reproduced (paper timing). `wftool.paper` runs it."""

from __future__ import annotations

from pathlib import Path

import click
from rich.console import Console

from wftool.cli.analyze import PLOTTING, out, print_table
from wftool.cli.build import project_option
from wftool.cli.number import Number
from wftool.cli.record import print_poll
from wftool.display import shown
from wftool.errors import UsageError
from wftool.extras import require
from wftool.fc.msp_poller import DEFAULT_WINDOW
from wftool.fsp import DEFAULT_BAUDRATE
from wftool.fsp.schedule import DEFAULT_RATE_HZ, RATE_HZ_MAX, RATE_HZ_MIN

err = Console(stderr=True, highlight=False)


@click.group("paper")
def paper_group() -> None:
    """Reproduce the paper's evaluation (needs wftool[analysis])."""


@paper_group.command("timing")
@click.option("--duration", type=Number(1.0, 3600.0, unit="s"), default=30.0, show_default=True,
              help="Seconds of FSP, then seconds of MSP.")  # fmt: skip
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("paper-timing"),
    show_default=True,
    help="Directory for report.md, the recordings and Figs. 2-4 (must not hold a run yet).",
)
@click.option("--port", "msp_url", metavar="URL",
              help="A board's MSP/CLI port (with --fsp-port) [the virtual FC].")  # fmt: skip
@click.option("--fsp-port", "fsp_url", metavar="URL", help="The board's FSP port.")
@click.option("--fsp-baud", type=click.IntRange(1), default=DEFAULT_BAUDRATE, show_default=True)
@click.option(
    "--fsp-rate",
    type=click.IntRange(RATE_HZ_MIN, RATE_HZ_MAX),
    default=DEFAULT_RATE_HZ,
    show_default=True,
    help="fsp_rate_hz: configured on the virtual FC; a board's setting, for the expected rate.",
)
@click.option(
    "--serial-rate",
    type=click.IntRange(100, 2000),
    default=1000,
    show_default=True,
    help="serial_update_rate_hz for the run (the paper's MSP baseline: 1000); set on a board "
    "through the safe workflow, with a backup.",
)
@click.option("--keep-serial-rate", is_flag=True,
              help="Leave a board's serial_update_rate_hz as it is.")  # fmt: skip
@click.option("--window", type=click.IntRange(1, 64), default=DEFAULT_WINDOW, show_default=True,
              help="MSP requests in flight at most (see wftool record msp).")  # fmt: skip
@click.option(
    "--msp-baud",
    type=click.IntRange(9600, 2470000),
    help="The MSP port's baud rate: set on the virtual FC [921600: the paper does not state "
    "it]; a board's port is opened at it [115200].",
)
@click.option(
    "--msp-baud-sweep",
    metavar="BAUD,…",
    help="The virtual FC's MSP polled again at these baud rates, to show how the MSP figures "
    "move with it ('' for none) [115200,1000000].",
)
@click.option(
    "--stock-sitl",
    is_flag=True,
    help="The virtual FC as the SITL is (8 kHz loop, UARTs as fast as TCP) instead of the "
    "paper's board (3148 Hz loop, UARTs at their baud rates).",
)
@click.option("--no-accfilter", is_flag=True,
              help="Leave out the filter harness's Fig. 4 (it needs a C compiler).")  # fmt: skip
@click.option(
    "--binary",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Run this SITL program [build the patched one: wftool build sitl].",
)
@project_option
def timing_command(
    duration: float, out_dir: Path, msp_url: str | None, fsp_url: str | None, fsp_baud: int,
    fsp_rate: int, serial_rate: int, keep_serial_rate: bool, window: int, msp_baud: int | None,
    msp_baud_sweep: str | None, stock_sitl: bool, no_accfilter: bool, binary: Path | None,
    project_dir: Path | None,
) -> None:  # fmt: skip
    """Table 1 and Figs. 2-4 on one FC: an FSP recording, then an MSP recording, and
    report.md: ours beside the paper's, row by row, each difference explained.

    The virtual FC by default, as the paper's board (a 3148 Hz loop from a 3.2 kHz gyro,
    serial_update_rate_hz 1000, UARTs at their baud rates, synthetic motion; built if
    needed), its MSP then polled again at the --msp-baud-sweep rates; or a board with --port
    and --fsp-port. Writes report.md, table1.json, fig2-histograms.png, fig3-intervals.png,
    fig4-fsp-spectrum.png and fig4-accfilter-spectrum.png with the recordings (fsp/, msp/,
    msp-BAUD/, accfilter/). The FC is asked for its `tasks` and `status` at the end, which
    resets it (leaving the CLI does).
    """
    require("analysis", *PLOTTING, what="paper timing")
    from wftool.analysis.setup import MSP_BAUD_SWEEP, PAPER_BOARD
    from wftool.cli.sitl import build_sitl
    from wftool.paper import Board, run_timing
    from wftool.sitl.process import SITL_BOARD

    if (msp_url is None) != (fsp_url is None):
        raise UsageError("a board needs both --port (MSP/CLI) and --fsp-port")
    if keep_serial_rate and msp_url is None:
        raise UsageError("--keep-serial-rate is for a board (--port); the virtual FC is set up")
    board = Board(msp_url, fsp_url, fsp_baud) if msp_url and fsp_url else None
    try:
        sweep = (
            list(MSP_BAUD_SWEEP)
            if msp_baud_sweep is None
            else [int(text) for text in msp_baud_sweep.split(",") if text.strip()]
        )
    except ValueError:
        raise UsageError(f"--msp-baud-sweep takes baud rates separated by commas, not "
                         f"{msp_baud_sweep!r}") from None  # fmt: skip
    if any(not 9600 <= baud <= 2470000 for baud in sweep):
        raise UsageError("--msp-baud-sweep: each baud rate must be 9600-2470000")
    if board is None and binary is None:
        binary = build_sitl(project_dir)
    run = run_timing(
        out_dir,
        duration,
        binary=binary if board is None else None,
        board=board,
        fsp_rate_hz=fsp_rate,
        serial_rate_hz=None if keep_serial_rate else serial_rate,
        window=window,
        project_dir=project_dir,
        with_accfilter=not no_accfilter,
        virtual_board=SITL_BOARD if stock_sitl else PAPER_BOARD,
        msp_baud=msp_baud,
        msp_baud_sweep=sweep if board is None else (),
        log=lambda message: err.print(shown(message, "dim")),
    )
    summary = run.fsp.summary
    out.print(
        f"FSP: {summary.frames} frames, {summary.frame_rate_hz:.1f} Hz received, "
        f"{summary.lost_frames} lost, {summary.fc_drops} dropped on the FC",
        markup=False,
    )
    out.print("MSP:", markup=False)
    print_poll(run.msp, out)
    out.print()
    print_table(run.table, run.notes)
    out.print(shown(f"wrote {', '.join(str(path) for path in run.written)}"))


COMMANDS: list[click.Command] = [paper_group]
