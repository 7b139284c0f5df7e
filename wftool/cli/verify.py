"""Commands: the FSP stream (verify, replay). The verify API (`wftool.verify.session`) runs
and judges; this module parses options and renders the dashboard."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.live import Live
from rich.text import Text

from wftool.cli.number import SECONDS, Number
from wftool.display import shown
from wftool.errors import UsageError
from wftool.fsp import DEFAULT_BAUDRATE, ESTIMATORS
from wftool.fsp.schedule import RATE_HZ_MAX, RATE_HZ_MIN
from wftool.recording.events import Sink
from wftool.recording.recorder import RECORD_FORMATS
from wftool.verify.criteria import FLAGS, Criteria, criteria_for
from wftool.verify.dashboard import render
from wftool.verify.foxglove import DEFAULT_HOST as FOXGLOVE_HOST
from wftool.verify.foxglove import DEFAULT_PORT as FOXGLOVE_PORT
from wftool.verify.foxglove import exposure_warning
from wftool.verify.live import LEAD_MAX_S, Commander, check_uplink_lead
from wftool.verify.session import (
    VerifyResult,
    VerifySession,
    fc_frame_rate_hz,
    replay,
)
from wftool.verify.uplink import check_uplink_rate

err = Console(stderr=True, highlight=False)


def _options(*options: Callable) -> Callable:
    def decorate(command: Callable) -> Callable:
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


PERCENT = Number(0, 100, unit="%")


def _check_lead(lead_ms: float, name: str) -> None:
    check_uplink_lead(lead_ms / 1e3, name)


criteria_options = _options(
    click.option("--expected-rate", type=Number(0, min_open=True, unit="Hz"),
                 help="Frame rate the FC should stream (Hz)."),
    # Each limit's destination is its `Criteria` field: `criteria_from` passes them on as
    # they are.
    click.option("--min-rate", "min_rate_hz", type=Number(0, unit="Hz"),
                 help="Minimum frame rate [95 % of expected]."),
    click.option("--max-spread-ms", "max_spread_ms", type=Number(0, unit="ms"),
                 help="Max FC-interval P99−P1 [half a period]."),
    click.option("--max-loss", "max_loss_pct", type=PERCENT, default=Criteria.max_loss_pct,
                 show_default=True, help="Max transport loss, % of frames."),
    click.option("--max-fc-drops", "max_drops_pct", type=PERCENT,
                 help="Max frames the FC dropped (queue full), % of frames "
                 f"[{Criteria.max_drops_pct:g}]."),
    click.option("--max-errors", "max_errors", type=click.IntRange(0),
                 default=Criteria.max_errors, show_default=True,
                 help="Max rejected chunks (COBS, length, version, CRC) and outlier packets."),
    click.option("--max-outage", "max_outage_s", type=Number(0, unit="s"),
                 default=Criteria.max_outage_s, show_default=True, metavar="SECONDS",
                 help="Max time the port may be gone during the run, all outages together "
                 "(0: a reconnect fails the run)."),
    click.option("--max-timed-late", "max_timed_late_pct", type=PERCENT,
                 default=Criteria.max_timed_late_pct, show_default=True,
                 help="With --uplink-lead: max timed commands the FC applied late (their time "
                 "had come when it took them), % of those it reported on."),
    click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout."),
    click.option("--clock", type=click.Choice(ESTIMATORS),
                 help=f"Clock estimator for the OBC times: {ESTIMATORS[0]} (lower envelope), "
                 "kalman (the paper's filter) or twoway (the envelope and the FC's time replies) "
                 f"[{ESTIMATORS[0]}; replay: the recorded run's]."),
)  # fmt: skip

run_options = _options(
    click.option("--uplink", is_flag=True, help="Send a command pattern and expect it back in RC."),
    click.option("--uplink-rate",
                 type=Number(0, RATE_HZ_MAX, min_open=True, unit="commands/s",
                             check=check_uplink_rate),
                 default=50.0, show_default=True,
                 help=f"Commands per second (at most {RATE_HZ_MAX})."),
    click.option("--uplink-lead", "uplink_lead_ms",
                 type=Number(0, LEAD_MAX_S * 1e3, unit="ms", check=_check_lead), metavar="MS",
                 help="Send the pattern as timed commands (E4), each to act MS after it is "
                 "sent; the FC reports when each did, and the verdict judges it (less than the "
                 "FC's command timeout) [immediate commands]."),
    click.option("--record", "record_path", type=click.Path(path_type=Path),
                 help="Record the run (messages and raw bytes): a rosbag2 directory, or one "
                 "MCAP file if the path ends in .mcap. `wftool replay` reads either."),
    click.option("--record-format", type=click.Choice(RECORD_FORMATS),
                 default=RECORD_FORMATS[0], show_default=True,
                 help="ROS 2 messages (ros2 bag play, Foxglove) or the older JSON MCAP file."),
    click.option("--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path),
                 help="Record frames to this CSV file."),
    click.option("--foxglove", "foxglove_port", type=click.IntRange(0, 65535), is_flag=False,
                 flag_value=FOXGLOVE_PORT, metavar="[PORT]",
                 help=f"Serve the stream live to Foxglove (WebSocket) [port {FOXGLOVE_PORT}]."),
    click.option("--foxglove-host", default=FOXGLOVE_HOST, show_default=True,
                 help="Address the Foxglove server binds to."),
)  # fmt: skip


expected_rate_options = _options(
    click.option("--fsp-rate", type=click.IntRange(RATE_HZ_MIN, RATE_HZ_MAX), metavar="HZ",
                 help="The FC's fsp_rate_hz: with --fc, the expected rate follows."),
    click.option("--fc", "fc_url", metavar="URL",
                 help="The FC's MSP port, to read its PID looptime (with --fsp-rate)."),
)  # fmt: skip


def expected_rate_from(
    expected_rate: float | None, fsp_rate: int | None, fc_url: str | None
) -> float | None:
    """The expected frame rate: given, or from `fsp_rate_hz` and the FC's PID looptime."""
    if fsp_rate is None and fc_url is None:
        return expected_rate
    if fsp_rate is None or fc_url is None:
        raise UsageError("--fsp-rate and --fc go together: the rate, and where to ask the FC")
    if expected_rate is not None:
        raise UsageError("give --expected-rate or --fsp-rate with --fc, not both")
    return fc_frame_rate_hz(fc_url, fsp_rate)


def criteria_from(uplink: bool, uplink_lead_ms: float | None = None, **options: Any) -> Criteria:
    """The criteria the `criteria_options` ask for: the uplink judged if sent, and its timed
    commands if it sends them."""
    limits = {field.name for field in fields(Criteria)} - set(FLAGS)
    timed = uplink_lead_ms is not None
    return criteria_for(uplink=uplink, timed=timed, **{name: options[name] for name in limits})


def _finish(result: VerifyResult, as_json: bool) -> None:
    """Print JSON if asked; a failed verdict becomes exit 1 naming the failed checks."""
    if as_json:
        click.echo(json.dumps(result.as_json(), indent=1))
    result.check()


def session_from(
    url: str,
    baud: int,
    duration: float | None,
    *,
    criteria: Criteria | None = None,
    uplink: bool,
    uplink_rate: float,
    uplink_lead_ms: float | None,
    record_path: Path | None,
    record_format: str,
    csv_path: Path | None,
    foxglove_port: int | None,
    foxglove_host: str,
    expected_rate: float | None,
    clock: str | None,
    sinks: Sequence[Sink] = (),
    commander: Commander | None = None,
    **_others: Any,
) -> VerifySession:
    """The session the `run_options` ask for (criteria: the defaults unless given), with
    `sinks` and `commander` besides; says where its live view is served (warning first if it
    reaches beyond this machine)."""
    if foxglove_port is not None and (warning := exposure_warning(foxglove_host, foxglove_port)):
        err.print(shown(warning, "yellow"), soft_wrap=True)
    session = VerifySession(
        url,
        baud,
        duration,
        criteria=criteria,
        expected_rate_hz=expected_rate,  # also kept in a recording, for replay to judge by
        uplink_rate_hz=uplink_rate if uplink else None,
        uplink_lead_s=uplink_lead_ms / 1e3 if uplink_lead_ms is not None else None,
        record_path=record_path,
        csv_path=csv_path,
        clock=clock,
        record_format=record_format,
        foxglove_port=foxglove_port,
        foxglove_host=foxglove_host,
        sinks=sinks,
        commander=commander,
    )
    if session.live_view is not None:
        err.print(Text.assemble("Foxglove  ", shown(session.live_view.url, "bold")))
    return session


def verify_stream(
    url: str, baud: int, duration: float | None, *, as_json: bool, **options: Any
) -> None:
    """The live dashboard until the duration is up (or Ctrl-C), then the verdict."""
    criteria = criteria_from(**options)
    session = session_from(url, baud, duration, criteria=criteria, **options)

    def view(result: VerifyResult) -> Any:
        return render(result.summary, result.latest, result.verdict)

    console = Console(stderr=as_json)
    # Transient: a run that never started (the port would not open) leaves nothing on the
    # screen but its error; a finished one prints its last dashboard below.
    try:
        with Live(
            view(session.result()), console=console, refresh_per_second=4, transient=True
        ) as live:
            try:
                result = session.run(on_refresh=lambda s: live.update(view(session.result(s))))
            except KeyboardInterrupt:
                if duration is not None:
                    raise  # a timed run cut short: no verdict, exit 130
                result = session.result()  # the normal end of an open-ended run
    finally:
        session.close()
    console.print(view(result))
    _finish(result, as_json)


@click.command("verify")
@click.option("--stream", is_flag=True, help="Verify the FSP stream (the one check so far).")
@click.option("--port", "url", required=True, help="Serial device or pyserial URL (socket://…).")
@click.option("--baud", type=click.IntRange(1), default=DEFAULT_BAUDRATE, show_default=True)
@click.option("--duration", type=SECONDS, metavar="SECONDS",
              help="Seconds to run, then the verdict (Ctrl-C: stop, exit 130) [until Ctrl-C, "
              "then the verdict].")  # fmt: skip
@run_options
@expected_rate_options
@criteria_options
def verify(
    stream: bool, url: str, baud: int, duration: float | None,
    fsp_rate: int | None, fc_url: str | None, **options: Any,
) -> None:  # fmt: skip
    """Live dashboard of an FSP stream, then a verdict: exit 0 pass, 1 fail, 2 cannot run.

    Without --duration it runs until Ctrl-C, then judges what it saw. The frame rate is
    judged against --expected-rate, or the rate --fsp-rate gives at the PID looptime the FC
    reports on --fc.
    """
    if not stream:
        raise UsageError("nothing to verify: pass --stream")
    options["expected_rate"] = expected_rate_from(options["expected_rate"], fsp_rate, fc_url)
    verify_stream(url, baud, duration, **options)


@click.command("replay")
@click.argument("recording", type=click.Path(exists=True, path_type=Path))
@criteria_options
def replay_command(
    recording: Path, expected_rate: float | None, as_json: bool, clock: str | None, **options: Any
) -> None:
    """The statistics and verdict of a `verify --record` recording, computed again.

    RECORDING is a rosbag2 directory or an MCAP file, in either format.
    """
    result = replay(recording, expected_rate, criteria_from(False, **options), clock)
    Console(stderr=as_json).print(render(result.summary, result.latest, result.verdict))
    _finish(result, as_json)


COMMANDS: list[click.Command] = [verify, replay_command]
