"""Commands: the FSP stream (verify, replay, sitl)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import click
from rich.console import Console
from rich.live import Live

from wftool.errors import UsageError, WftoolError
from wftool.fsp.reader import DEFAULT_BAUDRATE
from wftool.verify.criteria import Criteria, judge
from wftool.verify.dashboard import render
from wftool.verify.monitor import StreamMonitor, StreamSummary
from wftool.verify.uplink import UplinkTracker


class VerificationFailed(WftoolError):
    """The stream ran but did not meet the criteria (exit 1)."""


def criteria_options(command: Callable) -> Callable:
    options = [
        click.option("--expected-rate", type=float, help="Frame rate the FC should stream (Hz)."),
        click.option("--min-rate", type=float, help="Minimum frame rate [95 % of expected]."),
        click.option("--max-spread-ms", type=float, help="Max FC-interval P99−P1 [half a period]."),
        click.option(
            "--max-loss", type=float, default=0.1, show_default=True,
            help="Max transport loss and FC drops, % of frames.",
        ),
        click.option(
            "--max-errors", type=int, default=0, show_default=True, help="Max rejected chunks."
        ),
        click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON."),
    ]  # fmt: skip
    for option in reversed(options):
        command = option(command)
    return command


def _finish(summary: StreamSummary, criteria: Criteria, as_json: bool) -> None:
    """Print JSON if asked; a failed verdict becomes exit 1 with the failed checks."""
    verdict = judge(summary, criteria)
    if as_json:
        click.echo(json.dumps({**summary.as_json(), "verdict": verdict.as_json()}, indent=1))
    if not verdict.passed:
        failed = "; ".join(c.describe() for c in verdict.checks if not c.passed)
        raise VerificationFailed(f"stream verification failed: {failed}")


@click.command("verify")
@click.option(
    "--stream", "stream", is_flag=True, help="Verify the FSP stream (the one check so far)."
)
@click.option(
    "--port", "url", required=True, help="Serial device or pyserial URL (socket://host:port)."
)
@click.option("--baud", type=int, default=DEFAULT_BAUDRATE, show_default=True)
@click.option("--duration", type=float, help="Seconds to run [until Ctrl-C].")
@click.option("--uplink", is_flag=True, help="Send a command pattern and expect it back in RC.")
@click.option(
    "--uplink-rate", type=float, default=50.0, show_default=True, help="Commands per second."
)
@click.option(
    "--record",
    "record_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Record to MCAP.",
)
@click.option(
    "--csv",
    "csv_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Record frames to CSV.",
)
@criteria_options
def verify(
    stream: bool, url: str, baud: int, duration: float | None, uplink: bool, uplink_rate: float,
    record_path: Path | None, csv_path: Path | None, expected_rate: float | None,
    min_rate: float | None, max_spread_ms: float | None, max_loss: float, max_errors: int,
    as_json: bool,
) -> None:  # fmt: skip
    """Live dashboard of an FSP stream, then a pass/fail verdict (exit 0 pass, 1 fail).

    Without --duration it runs until Ctrl-C, then judges what it saw.
    """
    from wftool.verify.live import LiveOptions, run_live
    from wftool.verify.recording import Recorder

    if not stream:
        raise UsageError("nothing to verify: pass --stream")
    criteria = Criteria(min_rate, max_spread_ms, max_loss, max_errors, uplink)
    monitor = StreamMonitor(url, expected_rate, uplink=UplinkTracker() if uplink else None)
    options = LiveOptions(url, baud, duration, uplink_rate if uplink else None)
    console = Console(stderr=as_json)
    metadata = {
        "port": url,
        "baud": str(baud),
        "expected_rate_hz": str(expected_rate or ""),
        "uplink_rate_hz": str(uplink_rate if uplink else ""),
    }
    recorder = Recorder(record_path, csv_path, metadata) if record_path or csv_path else None

    def view(summary: StreamSummary) -> object:
        return render(summary, monitor.latest, judge(summary, criteria))

    try:
        with Live(view(monitor.summary()), console=console, refresh_per_second=4) as live:
            try:
                summary = run_live(options, monitor, recorder, lambda s: live.update(view(s)))
            except KeyboardInterrupt:  # the normal end of an open-ended run
                summary = monitor.summary()
            live.update(view(summary))
    finally:
        if recorder is not None:
            recorder.close()
    _finish(summary, criteria, as_json)


@click.command("replay")
@click.argument("recording", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@criteria_options
def replay(
    recording: Path, expected_rate: float | None, min_rate: float | None,
    max_spread_ms: float | None, max_loss: float, max_errors: int, as_json: bool,
) -> None:  # fmt: skip
    """The statistics and verdict of a `verify --record` MCAP file, computed again."""
    from wftool.verify.recording import replay_recording

    monitor = replay_recording(recording, expected_rate)
    criteria = Criteria(min_rate, max_spread_ms, max_loss, max_errors, monitor.uplink is not None)
    summary = monitor.summary()
    console = Console(stderr=as_json)
    console.print(render(summary, monitor.latest, judge(summary, criteria)))
    _finish(summary, criteria, as_json)


COMMANDS: list[click.Command] = [verify, replay]
