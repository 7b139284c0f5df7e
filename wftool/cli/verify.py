"""Commands: the FSP stream (verify, replay). The verify API (`wftool.verify.session`) runs
and judges; this module parses options and renders the dashboard."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.live import Live

from wftool.errors import UsageError
from wftool.fsp import DEFAULT_BAUDRATE
from wftool.verify.criteria import VIRTUAL_FC, Criteria
from wftool.verify.dashboard import render
from wftool.verify.session import VerifyResult, VerifySession, criteria_for, replay


def _options(*options: Callable) -> Callable:
    def decorate(command: Callable) -> Callable:
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


criteria_options = _options(
    click.option("--expected-rate", type=float, help="Frame rate the FC should stream (Hz)."),
    click.option("--min-rate", type=float, help="Minimum frame rate [95 % of expected]."),
    click.option("--max-spread-ms", type=float,
                 help="Max FC-interval P99−P1 "
                 f"[half a period; virtual FC: {VIRTUAL_FC.max_spread_ms:g}]."),
    click.option("--max-loss", type=float, default=Criteria.max_loss_pct, show_default=True,
                 help="Max transport loss, % of frames."),
    click.option("--max-fc-drops", type=float,
                 help="Max frames the FC dropped (queue full), % of frames "
                 f"[{Criteria.max_drops_pct:g}; virtual FC: {VIRTUAL_FC.max_drops_pct:g}]."),
    click.option("--max-errors", type=int, default=Criteria.max_errors, show_default=True,
                 help="Max rejected chunks (COBS, length, version, CRC)."),
    click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout."),
)  # fmt: skip

run_options = _options(
    click.option("--uplink", is_flag=True, help="Send a command pattern and expect it back in RC."),
    click.option("--uplink-rate", type=float, default=50.0, show_default=True,
                 help="Commands per second."),
    click.option("--record", "record_path", type=click.Path(dir_okay=False, path_type=Path),
                 help="Record frames and raw bytes to this MCAP file."),
    click.option("--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path),
                 help="Record frames to this CSV file."),
)  # fmt: skip


def criteria_from(uplink: bool, virtual_fc: bool = False, **options: Any) -> Criteria:
    """The criteria the `criteria_options` ask for."""
    return criteria_for(
        uplink=uplink,
        virtual_fc=virtual_fc,
        min_rate_hz=options["min_rate"],
        max_spread_ms=options["max_spread_ms"],
        max_loss_pct=options["max_loss"],
        max_drops_pct=options["max_fc_drops"],
        max_errors=options["max_errors"],
    )


def _finish(result: VerifyResult, as_json: bool) -> None:
    """Print JSON if asked; a failed verdict becomes exit 1 naming the failed checks."""
    if as_json:
        click.echo(json.dumps(result.as_json(), indent=1))
    result.check()


def verify_stream(
    url: str,
    baud: int,
    duration: float | None,
    *,
    uplink: bool,
    uplink_rate: float,
    record_path: Path | None,
    csv_path: Path | None,
    expected_rate: float | None,
    as_json: bool,
    virtual_fc: bool = False,
    **criteria_values: Any,
) -> None:
    """The live dashboard until the duration is up (or Ctrl-C), then the verdict."""
    session = VerifySession(
        url,
        baud,
        duration,
        criteria=criteria_from(uplink, virtual_fc, **criteria_values),
        expected_rate_hz=expected_rate,
        uplink_rate_hz=uplink_rate if uplink else None,
        record_path=record_path,
        csv_path=csv_path,
    )

    def view(result: VerifyResult) -> Any:
        return render(result.summary, result.latest, result.verdict)

    console = Console(stderr=as_json)
    try:
        with Live(view(session.result()), console=console, refresh_per_second=4) as live:
            try:
                result = session.run(on_refresh=lambda s: live.update(view(session.result(s))))
            except KeyboardInterrupt:  # the normal end of an open-ended run
                result = session.result()
            live.update(view(result))
    finally:
        session.close()
    if not console.is_terminal:
        console.line()  # rich leaves a non-terminal's last line open
    _finish(result, as_json)


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
@click.argument("recording", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@criteria_options
def replay_command(
    recording: Path, expected_rate: float | None, as_json: bool, **options: Any
) -> None:
    """The statistics and verdict of a `verify --record` MCAP file, computed again."""
    result = replay(recording, expected_rate, criteria_from(False, **options))
    Console(stderr=as_json).print(render(result.summary, result.latest, result.verdict))
    _finish(result, as_json)


COMMANDS: list[click.Command] = [verify, replay_command]
