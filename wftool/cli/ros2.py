"""Commands: the live ROS 2 node (ros2). The node (`wftool.ros2.node`) publishes and takes
commands; the live loop (`wftool.verify.session`) reads the port; this module wires and tells."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from wftool.cli.number import SECONDS, Number
from wftool.cli.verify import _options, err
from wftool.errors import UsageError
from wftool.fsp import DEFAULT_BAUDRATE, ESTIMATORS
from wftool.fsp.packets import RC_PULSE_US
from wftool.ros2.commands import DEFAULT_MAX_AGE_NS
from wftool.ros2.node import COMMAND_TOPIC, DEFAULT_DEPTH, Ros2Bridge, Ros2Options
from wftool.verify.dashboard import UPLINK_FLAGS, who_flies
from wftool.verify.monitor import StreamSummary
from wftool.verify.session import VerifySession

STATUS_EVERY_S = 10.0

node_options = _options(
    click.option("--namespace", default="/", show_default=True,
                 help="The node's namespace: topics are NAMESPACE/fsp/imu, ..."),
    click.option("--frame-id", default="fc", show_default=True,
                 help="header.frame_id of every message (the FC's body axes as it reports "
                 "them)."),
    click.option("--accept-commands", is_flag=True,
                 help="Take RC commands (wftool_msgs/RcCommand) on NAMESPACE/fsp/command and "
                 "send them to the FC, from one publisher at a time. Each is sent at most once, "
                 "only if fresh, in range and newer than its publisher's last; the rest are "
                 "dropped and counted on NAMESPACE/fsp/command_status."),
    click.option("--command-max-age", "command_max_age_ms",
                 type=Number(0, 1000, min_open=True, unit="ms"), default=DEFAULT_MAX_AGE_NS / 1e6,
                 show_default=True, metavar="MS",
                 help="How long after it arrived a command may still be sent, and how long a "
                 "publisher's silence ends its turn (the node's monotonic clock)."),
    click.option("--domain-id", type=click.IntRange(0, 232),
                 help="The ROS 2 domain [ROS_DOMAIN_ID, or 0]."),
    click.option("--qos-depth", type=click.IntRange(1, 100_000), default=DEFAULT_DEPTH,
                 show_default=True,
                 help="Messages kept per topic for a reliable subscriber that falls behind."),
)  # fmt: skip


def node_from(
    namespace: str,
    frame_id: str,
    accept_commands: bool,
    command_max_age_ms: float,
    domain_id: int | None,
    qos_depth: int,
    **_others: Any,
) -> Ros2Bridge:
    """The node the `node_options` ask for, started; says what it publishes and who may
    command."""
    options = Ros2Options(
        namespace=namespace,
        frame_id=frame_id,
        accept_commands=accept_commands,
        command_max_age_ns=round(command_max_age_ms * 1e6),
        depth=qos_depth,
        domain_id=domain_id,
    )
    bridge = Ros2Bridge(options)
    for line in describe(bridge):
        err.print(line)
    return bridge


def describe(bridge: Ros2Bridge) -> list[str]:
    options = bridge.options
    command = next((t for t in bridge.topics if t.endswith("/" + COMMAND_TOPIC)), None)
    published = [t for t in bridge.topics if t != command and "/fsp/" in t]
    lines = [
        f"ROS 2 node [bold]{bridge.name}[/] (domain {bridge.domain_id}), frame id "
        f"{options.frame_id!r}",
        f"discovery: {bridge.discovery}",
        f"publishing {', '.join(published)}",
    ]
    if command is None:
        lines.append("commands: not taken (--accept-commands takes them on fsp/command)")
    else:
        lines.append(
            f"commands: [bold]taken[/] on {command} from one publisher at a time (another "
            f"after {options.command_max_age_ns / 1e6:g} ms of its silence): sent once each, "
            f"if at most {options.command_max_age_ns / 1e6:g} ms old and every value in the "
            f"FC's pulse range ({RC_PULSE_US[0]}-{RC_PULSE_US[1]} µs until it says); arming "
            "requests only to an FC whose receiver is the OBC"
        )
    return lines


@click.command("ros2")
@click.option("--port", "url", help="Serial device or pyserial URL (socket://…) of the FSP port.")
@click.option("--baud", type=click.IntRange(1), default=DEFAULT_BAUDRATE, show_default=True)
@click.option(
    "--duration",
    type=SECONDS,
    metavar="SECONDS",
    help="Seconds to run [until Ctrl-C].",
)
@click.option(
    "--record",
    "record_path",
    type=click.Path(path_type=Path),
    help="Record the run too (a rosbag2 directory, or one MCAP file if the path ends in .mcap).",
)
@click.option(
    "--clock",
    type=click.Choice(ESTIMATORS),
    help=f"Clock estimator of the stamps [{ESTIMATORS[0]}].",
)
@node_options
@click.option(
    "--build-msgs",
    is_flag=True,
    help="Build wftool_msgs' type support into this Python environment (cmake and "
    "g++; about a minute), then exit.",
)
def ros2(
    url: str | None, baud: int, duration: float | None, record_path: Path | None,
    clock: str | None, build_msgs: bool, **options: Any,
) -> None:  # fmt: skip
    """A ROS 2 node publishing the FSP stream live, as recordings hold it (extra `ros2`).

    Every frame on fsp/imu, fsp/attitude, fsp/rc and fsp/rpm, stamped with its capture time
    on the ROS clock; fsp/battery and fsp/health (loss, drops, reconnects) at 10 Hz;
    fsp/uplink_status, what the FC made of the commands (RX loss, override, failsafe). It stays
    on this host unless ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise, and takes commands only
    with --accept-commands.
    """
    if build_msgs:
        _build_msgs()
        return
    if url is None:
        raise UsageError("which FSP port? --port URL (the virtual FC: wftool sitl --ros2)")
    bridge = node_from(**options)
    commander = bridge if options["accept_commands"] else None
    session = VerifySession(
        url, baud, duration, record_path=record_path, clock=clock, sinks=[bridge],
        commander=commander,
    )  # fmt: skip
    err.print(f"reading {url}; {'Ctrl-C stops' if duration is None else f'{duration:g} s'}")
    try:
        result = session.run(on_refresh=_status_every(STATUS_EVERY_S, bridge))
    except KeyboardInterrupt:
        if duration is not None:
            raise
        result = session.result()
    finally:
        session.close()
    err.print(status_line(result.summary, bridge))


def _build_msgs() -> None:
    from wftool.ros2.typesupport import build

    if build(log=err.print):
        err.print("wftool_msgs built into this Python environment")
    else:
        err.print("wftool_msgs is up to date in this Python environment")


def _status_every(period_s: float, bridge: Ros2Bridge) -> Callable[[StreamSummary], None]:
    next_at = time.monotonic() + period_s

    def show(summary: StreamSummary) -> None:
        nonlocal next_at
        if time.monotonic() >= next_at:
            next_at += period_s
            err.print(status_line(summary, bridge))

    return show


def status_line(summary: StreamSummary, bridge: Ros2Bridge) -> str:
    line = (
        f"{summary.frames} frames published ({summary.frame_rate_hz:.1f} Hz), "
        f"lost {summary.lost_frames}, "
        f"FC drops {summary.fc_drops}, reconnects {summary.reconnects}"
    )
    if bridge.unpublished:
        line += f", {bridge.unpublished} messages the middleware refused"
    if bridge.gate is not None:
        counts = bridge.command_counts
        line += f"; commands {counts.received} received, {counts.sent} sent, "
        line += f"{counts.dropped} dropped ({counts.foreign} of another publisher)"
    report = summary.fc_uplink
    if report is not None:  # what the FC made of them (E3)
        status = report.status
        on = [name for name, flag, _ in UPLINK_FLAGS if status.has(flag)] or ["no flag on"]
        line += (
            f"; the FC: {status.accepted} accepted, {status.stale} stale, "
            f"{status.timeouts} timeouts; {', '.join(on)}; failsafe {status.failsafe_phase_name}"
        )
        if status.authority is not None:
            line += f"; who flies: {who_flies(status)}"
    return line


COMMANDS: list[click.Command] = [ros2]
