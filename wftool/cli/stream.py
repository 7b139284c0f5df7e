"""Commands: the FSP stream (verify, replay) and the virtual FC (sitl)."""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.live import Live

from wftool.errors import UsageError, WftoolError
from wftool.fsp.reader import DEFAULT_BAUDRATE
from wftool.verify.criteria import Criteria, judge
from wftool.verify.dashboard import render
from wftool.verify.monitor import StreamMonitor, StreamSummary
from wftool.verify.uplink import UplinkTracker

err = Console(stderr=True, highlight=False)

SITL_MAX_SPREAD_MS = 50.0
SITL_MAX_FC_DROPS_PCT = 1.0
"""SITL is not real time: its loop sleeps between iterations and, on a shared or virtual
machine, stalls for tens of ms, long enough for the FC's 4-frame queue to overflow now and
then. The virtual FC's limits allow for that; on hardware the defaults apply."""


class VerificationFailed(WftoolError):
    """The stream ran but did not meet the criteria (exit 1)."""


def _options(*options: Callable) -> Callable:
    def decorate(command: Callable) -> Callable:
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


criteria_options = _options(
    click.option("--expected-rate", type=float, help="Frame rate the FC should stream (Hz)."),
    click.option("--min-rate", type=float, help="Minimum frame rate [95 % of expected]."),
    click.option("--max-spread-ms", type=float, help="Max FC-interval P99−P1 [half a period]."),
    click.option("--max-loss", type=float, default=0.1, show_default=True,
                 help="Max transport loss, % of frames."),
    click.option("--max-fc-drops", type=float,
                 help="Max frames the FC dropped (queue full), % of frames [0.1; virtual FC: 1]."),
    click.option("--max-errors", type=int, default=0, show_default=True,
                 help="Max rejected chunks (COBS, length, version, CRC)."),
    click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout."),
)  # fmt: skip

run_options = _options(
    click.option("--uplink", is_flag=True, help="Send a command pattern and expect it back in RC."),
    click.option("--uplink-rate", type=float, default=50.0, show_default=True,
                 help="Commands per second."),
    click.option("--record", "record_path", type=click.Path(path_type=Path),
                 help="Record frames and raw bytes: a rosbag2 directory (ros2) or MCAP file."),
    click.option("--record-format", type=click.Choice(["ros2", "json"]), default="ros2",
                 show_default=True, help="ROS 2 messages (ros2 bag play) or JSON MCAP."),
    click.option("--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path),
                 help="Record frames to this CSV file."),
    click.option("--foxglove", "foxglove_port", type=int, is_flag=False, flag_value=8765,
                 metavar="[PORT]", help="Serve the stream live to Foxglove [port 8765]."),
    click.option("--foxglove-host", default="127.0.0.1", show_default=True,
                 help="Address the Foxglove server binds to."),
)  # fmt: skip


def _criteria(uplink: bool, **options: Any) -> Criteria:
    criteria = Criteria(
        min_rate_hz=options["min_rate"],
        max_spread_ms=options["max_spread_ms"],
        max_loss_pct=options["max_loss"],
        max_errors=options["max_errors"],
        uplink=uplink,
    )
    if options["max_fc_drops"] is not None:
        criteria = replace(criteria, max_drops_pct=options["max_fc_drops"])
    return criteria


def _finish(summary: StreamSummary, criteria: Criteria, as_json: bool) -> None:
    """Print JSON if asked; a failed verdict becomes exit 1 naming the failed checks."""
    verdict = judge(summary, criteria)
    if as_json:
        click.echo(json.dumps({**summary.as_json(), "verdict": verdict.as_json()}, indent=1))
    if not verdict.passed:
        failed = "; ".join(c.describe() for c in verdict.checks if not c.passed)
        raise VerificationFailed(f"stream verification failed: {failed}")


def verify_stream(
    url: str,
    baud: int,
    duration: float | None,
    *,
    uplink: bool,
    uplink_rate: float,
    record_path: Path | None,
    record_format: str,
    csv_path: Path | None,
    foxglove_port: int | None,
    foxglove_host: str,
    expected_rate: float | None,
    as_json: bool,
    **criteria_values: Any,
) -> None:
    """The live dashboard until the duration is up (or Ctrl-C), then the verdict."""
    from wftool.verify.foxglove import FoxgloveLive
    from wftool.verify.live import LiveOptions, run_live
    from wftool.verify.recording import Recorder

    criteria = _criteria(uplink, **criteria_values)
    monitor = StreamMonitor(url, expected_rate, uplink=UplinkTracker() if uplink else None)
    options = LiveOptions(url, baud, duration, uplink_rate if uplink else None)
    metadata = {
        "port": url,
        "baud": str(baud),
        "expected_rate_hz": str(expected_rate or ""),
        "uplink_rate_hz": str(uplink_rate if uplink else ""),
    }
    live_view = None
    if foxglove_port is not None:
        live_view = FoxgloveLive(foxglove_port, foxglove_host)
        err.print(f"Foxglove  [bold]{live_view.url}[/]")
    recorder = None
    try:
        if record_path or csv_path:
            recorder = Recorder(record_path, csv_path, metadata, record_format)
    except WftoolError:
        if live_view is not None:
            live_view.close()
        raise

    def view(summary: StreamSummary) -> Any:
        return render(summary, monitor.latest, judge(summary, criteria))

    console = Console(stderr=as_json)
    try:
        with Live(view(monitor.summary()), console=console, refresh_per_second=4) as live:
            try:
                summary = run_live(
                    options, monitor, recorder, lambda s: live.update(view(s)), live_view=live_view
                )
            except KeyboardInterrupt:  # the normal end of an open-ended run
                summary = monitor.summary()
            live.update(view(summary))
        if not console.is_terminal:
            console.line()  # rich leaves a non-terminal's last line open
    finally:
        if live_view is not None:
            live_view.close()
        if recorder is not None:
            recorder.close()
    _finish(summary, criteria, as_json)


@click.command("verify")
@click.option("--stream", is_flag=True, help="Verify the FSP stream (the one check so far).")
@click.option("--port", "url", required=True, help="Serial device or pyserial URL (socket://…).")
@click.option("--baud", type=int, default=DEFAULT_BAUDRATE, show_default=True)
@click.option("--duration", type=float, help="Seconds to run [until Ctrl-C].")
@run_options
@criteria_options
def verify(stream: bool, url: str, baud: int, duration: float | None, **options: Any) -> None:
    """Live dashboard of an FSP stream, then a verdict: exit 0 pass, 1 fail, 2 cannot run.

    Without --duration it runs until Ctrl-C, then judges what it saw.
    """
    if not stream:
        raise UsageError("nothing to verify: pass --stream")
    verify_stream(url, baud, duration, **options)


@click.command("replay")
@click.argument("recording", type=click.Path(exists=True, path_type=Path))
@criteria_options
def replay(recording: Path, expected_rate: float | None, as_json: bool, **options: Any) -> None:
    """The statistics and verdict of a `verify --record` recording, computed again."""
    from wftool.verify.recording import replay_recording

    monitor = replay_recording(recording, expected_rate)
    criteria = _criteria(monitor.uplink is not None, **options)
    summary = monitor.summary()
    Console(stderr=as_json).print(render(summary, monitor.latest, judge(summary, criteria)))
    _finish(summary, criteria, as_json)


@click.command("sitl")
@click.option(
    "--binary",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Run this SITL program [build the patched one: wftool build sitl].",
)
@click.option(
    "--workdir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Where SITL keeps eeprom.bin [a new scratch directory].",
)
@click.option(
    "--rate",
    "rate_hz",
    type=click.IntRange(50, 4000),
    default=1100,
    show_default=True,
    help="fsp_rate_hz to configure.",
)
@click.option(
    "--motion/--no-motion",
    default=True,
    show_default=True,
    help="Feed synthetic IMU motion through SITL's simulator input.",
)
@click.option(
    "--verify",
    "verify_s",
    type=float,
    metavar="SECONDS",
    help="Verify the stream for SECONDS, then stop with the verdict as exit code.",
)
@click.option(
    "--project",
    "project_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="The wftool checkout to build in [found from the current directory].",
)
@run_options
@criteria_options
def sitl(
    binary: Path | None, workdir: Path | None, rate_hz: int, motion: bool,
    verify_s: float | None, project_dir: Path | None, **options: Any,
) -> None:  # fmt: skip
    """Run the virtual FC: the patched SITL with FSP on UART2, until Ctrl-C (or --verify)."""
    from wftool.virtual_fc import Motion, VirtualFcSession

    if options["foxglove_port"] is not None and verify_s is None:
        raise UsageError("--foxglove on sitl needs --verify SECONDS (the stream is read there)")
    if binary is None:
        binary = build_sitl(project_dir)
    workdir = workdir or Path(tempfile.mkdtemp(prefix="wftool-sitl-"))
    session = VirtualFcSession(
        binary, workdir, rate_hz=rate_hz, motion=Motion() if motion else None
    )
    err.print(f"starting the virtual FC in {workdir} …")
    with session:
        err.print(f"MSP/CLI  [bold]{session.msp_url}[/]")
        err.print(f"FSP      [bold]{session.fsp_url}[/]  (fsp_rate_hz {rate_hz})")
        if verify_s is not None:
            if options["max_spread_ms"] is None:
                options["max_spread_ms"] = SITL_MAX_SPREAD_MS
            if options["max_fc_drops"] is None:
                options["max_fc_drops"] = SITL_MAX_FC_DROPS_PCT
            verify_stream(session.fsp_url, DEFAULT_BAUDRATE, verify_s, **options)
            return
        err.print("running; Ctrl-C stops it")
        try:
            session.serve(on_reset=lambda: err.print("the FC reset itself; starting it again"))
        except KeyboardInterrupt:
            err.print("stopping")


def build_sitl(project_dir: Path | None) -> Path:
    """The patched SITL program, built (or found up to date) in the wftool checkout."""
    from wftool.build import build, find_project

    result = build(find_project(project_dir), "sitl", console=err)
    if not result.up_to_date:
        err.print(f"built {result.firmware}")
    return result.firmware


COMMANDS: list[click.Command] = [verify, replay, sitl]
