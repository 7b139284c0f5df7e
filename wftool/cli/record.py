"""Commands: recordings other than the FSP stream's (record msp).

`wftool.fc.msp_poller` polls, `wftool.recording.msp` records; this module parses
options and prints what the run asked and got.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from wftool.cli.number import SECONDS
from wftool.display import shown
from wftool.fc.msp import MspVersion
from wftool.fc.msp_poller import DEFAULT_WINDOW, PAPER_SCHEDULE, PollResult, parse_schedule

out = Console(highlight=False, width=None if sys.stdout.isatty() else 200)
err = Console(stderr=True, highlight=False)


@click.group("record")
def record_group() -> None:
    """Record what an FC gives an OBC (the FSP stream: wftool verify --record); repair a
    recording cut short."""


@record_group.command("msp")
@click.option("--port", "url", required=True, help="The FC's MSP port: device or pyserial URL.")
@click.option("--baud", type=click.IntRange(1), default=115200, show_default=True)
@click.option("--duration", type=SECONDS, help="Seconds to poll [until Ctrl-C].")
@click.option(
    "--out",
    "out_path",
    type=click.Path(path_type=Path),
    help="The recording: a rosbag2 directory, or one MCAP file if it ends in .mcap "
    "[msp-DATE-TIME].",
)
@click.option(
    "--schedule",
    "schedule_items",
    multiple=True,
    metavar="NAME=HZ",
    help="A command and its poll rate; repeatable [the paper's: "
    + ", ".join(f"{rate.name}={rate.rate_hz:g}" for rate in PAPER_SCHEDULE)
    + "].",
)
@click.option(
    "--window",
    type=click.IntRange(1, 64),
    default=DEFAULT_WINDOW,
    show_default=True,
    help="Requests in flight at most; a slot that finds the window full waits for room "
    "until its command's next slot (then it is skipped). 1: request-reply.",
)
@click.option(
    "--msp-version", type=click.Choice(["1", "2"]), default="1", show_default=True,
    help="MSP v1 ($M) or v2 ($X) requests.",
)  # fmt: skip
@click.option(
    "--acc-1g",
    type=click.IntRange(1, 65535),
    help="The FC's 1 g in raw accelerometer units, to record acceleration in m/s² "
    "(MSP does not report it) [recorded as no estimate].",
)
@click.option("--json", "as_json", is_flag=True, help="Print the poll's counts as JSON.")
def record_msp_command(
    url: str, baud: int, duration: float | None, out_path: Path | None,
    schedule_items: tuple[str, ...], window: int, msp_version: str, acc_1g: int | None,
    as_json: bool,
) -> None:  # fmt: skip
    """Poll MSP on a fixed schedule, as the paper's baseline, and record every reply.

    Each command is requested at its own rate without waiting for replies, at most WINDOW
    unanswered at a time; each reply is stamped when it is received (the OBC clock). The
    FC answers one MSP command per serial task run (serial_update_rate_hz), so what it
    cannot answer shows as skipped requests. Ctrl-C ends the run; the recording is kept.
    """
    from wftool.recording.msp import record_msp

    schedule = parse_schedule(schedule_items) if schedule_items else PAPER_SCHEDULE
    path = out_path or Path(time.strftime("msp-%Y%m%d-%H%M%S"))
    result = record_msp(
        url,
        path,
        duration,
        schedule=schedule,
        window=window,
        version=MspVersion(int(msp_version)),
        baudrate=baud,
        acc_1g=acc_1g,
        log=lambda message: err.print(shown(message), soft_wrap=True),
    )
    if as_json:
        click.echo(json.dumps(result.as_json(), indent=1))
    else:
        print_poll(result, out)
    err.print(
        shown(f"wrote {path}" + (" (interrupted)" if result.interrupted else "")), soft_wrap=True
    )


@record_group.command("repair")
@click.argument("recording", type=click.Path(exists=True, path_type=Path))
def record_repair_command(recording: Path) -> None:
    """Make a recording cut short (its run killed) readable by any tool again, as `ros2 bag
    reindex` does: a bag's metadata.yaml rebuilt from its MCAP file, and an MCAP file
    without its ending written again with one (the file as found kept as NAME.mcap.cut).

    RECORDING is a rosbag2 directory or an MCAP file. What was recorded is not changed: a
    recording the run never closed still says so (wftool replay: "cut short at ...").
    """
    from wftool.recording.repair import repair

    for line in repair(recording).describe():
        out.print(shown(line), soft_wrap=True)


def print_poll(result: PollResult, console: Console) -> None:
    """What the poll asked and got, per command."""
    table = Table(box=None, pad_edge=False)
    columns = ("command", "rate Hz", "slots", "sent", "skipped", "missed", "replies", "lost",
               "replies/s", "latency ms (median, P99)")  # fmt: skip
    for column in columns:
        table.add_column(column, justify="left" if column == "command" else "right")
    summary = result.as_json()
    for row in summary["commands"]:
        median, p99 = row["latency_median_ms"], row["latency_p99_ms"]
        table.add_row(
            row["command"], f"{row['rate_hz']:g}", str(row["slots"]), str(row["sent"]),
            str(row["skipped"]), str(row["missed"]), str(row["replies"]), str(row["lost"]),
            f"{row['reply_rate_hz']:.1f}",
            "—" if median is None else f"{median:.2f}, {p99:.2f}",
        )  # fmt: skip
    console.print(table)
    replies = sum(row["replies"] for row in summary["commands"])
    duration = result.duration_s
    console.print(
        f"{duration:.1f} s, window {result.window}, MSP v{result.version}: the FC answered "
        f"{replies / duration if duration > 0 else 0:.1f} commands/s"
        + (f"; {result.corrupt_frames} corrupt frames" if result.corrupt_frames else "")
        + (f"; {result.stray_replies} stray replies" if result.stray_replies else "")
        + (
            f"; {result.echoed_requests} requests came back (the link echoes them; they are "
            "no replies)"
            if result.echoed_requests
            else ""
        ),
        markup=False,
    )


COMMANDS: list[click.Command] = [record_group]
