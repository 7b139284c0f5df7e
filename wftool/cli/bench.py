"""Commands: benchmarks that print figures (bench ...)."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.table import Table

from wftool.bench.build import bench_build
from wftool.bench.command import IMMEDIATE, LEAD_S, TIMED, CommandBenchResult
from wftool.bench.decode import STREAMS
from wftool.cli.build import build_options, options_from, project_from
from wftool.cli.number import SECONDS, Number
from wftool.cli.sitl import rate_option
from wftool.stats import Distribution

out = Console(highlight=False, width=None if sys.stdout.isatty() else 200)
LEAD_MS = LEAD_S * 1e3
ROS2_BYTES_PER_FRAME_GOAL = 94.0
"""The size goal of a ROS 2 recording: what the JSON format measured when it was set."""


def sitl_options(command: Callable[..., None]) -> Callable[..., None]:
    """--binary and --project: the virtual FC a benchmark runs (built if not given)."""
    command = click.option(
        "--project", "project_dir", type=click.Path(file_okay=False, path_type=Path)
    )(command)
    return click.option(
        "--binary",
        type=click.Path(exists=True, dir_okay=False, path_type=Path),
        help="SITL program [build the patched one].",
    )(command)


@click.group("bench")
def bench_group() -> None:
    """Measure wftool's own performance and print the figures (never pass/fail)."""


@bench_group.command("build")
@click.argument("target", default="sitl")
@click.option(
    "--repeat",
    type=click.IntRange(1),
    default=1,
    show_default=True,
    help="Full builds of each kind; the fastest counts.",
)
@build_options
def bench_build_command(target: str, repeat: int, project_dir: Path | None, **options: Any) -> None:
    """Time plain make vs wftool build on TARGET, a no-op rebuild and a one-file rebuild.

    Every build is real and ccache is off: on two cores SITL takes about a minute in all,
    speedybeef7v3 several.
    """
    figures = bench_build(project_from(project_dir), target, options_from(**options), repeat)
    table = Table(box=None, pad_edge=False)
    table.add_column("measurement")
    table.add_column("seconds", justify="right")
    table.add_column("note")
    table.add_row("plain make, from scratch", f"{figures.raw_make:.1f}", "")
    table.add_row(
        "wftool build, from scratch",
        f"{figures.wftool_build:.1f}",
        f"overhead {figures.overhead_percent:+.1f} % (target <= 5 %)",
    )
    table.add_row("wftool build, no change", f"{figures.noop:.2f}", "target <= 3 s")
    table.add_row(
        f"wftool build, touched {figures.touched}",
        f"{figures.touch:.1f}",
        f"{figures.touch_compiled} unit(s) compiled",
    )
    out.print(f"bench build {figures.target} (-j{figures.jobs}, ccache off)")
    out.print(table)


@bench_group.command("decode")
@click.option(
    "--minutes",
    type=Number(0, 600, min_open=True, unit="min"),
    default=10.0,
    show_default=True,
    help="Length of the replayed stream.",
)
@click.option("--chunk", default=4096, show_default=True, help="Bytes handed to each feed().")
@click.option("--tunnel", is_flag=True, help="Replay the 180-byte MAVLink-tunnel variant.")
@click.option(
    "--repeat",
    type=click.IntRange(1),
    default=3,
    show_default=True,
    help="Runs of each path, interleaved; the best and the median are shown (a shared "
    "machine is noisy).",
)
def bench_decode(minutes: float, chunk: int, tunnel: bool, repeat: int) -> None:
    """FSP decode throughput and memory: the per-frame API, the columnar path (NumPy) with
    and without OBC clock alignment, and pymavlink parsing as many HIGHRES_IMU samples."""
    from wftool.bench.decode import (
        COLUMNAR_ALIGNED,
        LIKE_FOR_LIKE,
        MAVLINK,
        PER_FRAME_ALIGNED,
        compare_decoders,
    )

    result = compare_decoders(minutes, chunk, tunnel, repeat)
    frames = result.frames
    table = Table(
        title=f"FSP decode, {minutes:g} min stream: {frames:,} frames in "
        f"{result.capture_bytes / 1e6:.1f} MB, {chunk} B reads, {repeat} run(s) of each",
        box=None,
        pad_edge=False,
    )
    for column in ("path", "frames/s best", "median", "vs per-frame", "vs pymavlink"):
        table.add_column(column, justify="left" if column == "path" else "right")
    for path in result.runs:
        best, median, reference = result.best(path), result.median(path), LIKE_FOR_LIKE[path]
        table.add_row(
            path, f"{best:,.0f}", f"{median:,.0f}",
            f"{best / result.best(reference):.2f}x / {median / result.median(reference):.2f}x",
            f"{best / result.best(MAVLINK):.2f}x / {median / result.median(MAVLINK):.2f}x",
        )  # fmt: skip
    out.print(table)
    out.print(
        "ratios: best / best and median / median of runs taking turns in one process; "
        "vs per-frame: the per-frame run that works out the same times"
    )
    stats = result.runs[PER_FRAME_ALIGNED][0].stats
    assert stats is not None  # the per-frame runs count
    out.print(
        f"columnar and per-frame totals agree: {'yes' if result.agree else 'NO'} "
        f"({stats.packets:,} packets, {stats.errors} rejected, {stats.lost_frames} lost, "
        f"{stats.fc_drops} FC drops, {stats.wraps} wrap(s), {stats.resets} reset(s))"
    )
    out.print(
        "columnar FC and OBC times identical to the per-frame decoder's: "
        f"{'yes' if result.same_times else 'NO'}"
    )
    held = result.runs[COLUMNAR_ALIGNED][0].result_bytes
    out.print("memory, tracemalloc peak of one more run each (Python and NumPy allocations):")
    for what, peak in result.memory.items():
        out.print(f"  {what:<40} {peak / 2**20:8.1f} MiB  {peak / frames:6,.0f} B/frame")
    out.print(f"  of which the columns themselves        {held / 2**20:8.1f} MiB  "
              f"{held / frames:6,.0f} B/frame")  # fmt: skip


@bench_group.command("stream")
@click.option(
    "--rates",
    default="1100,2000,3000,8000",
    show_default=True,
    help="fsp_rate_hz values to try, comma-separated; the first is the default rate.",
)
@click.option(
    "--seconds", type=SECONDS, default=60.0, show_default=True, help="Streaming time per rate."
)
@sitl_options
def bench_stream(rates: str, seconds: float, binary: Path | None, project_dir: Path | None) -> None:
    """On the virtual FC: the highest fsp_rate_hz that streams without loss, verify's CPU
    share at the default rate, and the decode latency (read to frames)."""
    from wftool.bench.stream import run_stream_bench
    from wftool.cli.sitl import build_sitl

    try:
        values = [int(value) for value in rates.split(",")]
    except ValueError:
        raise click.BadParameter(f"expected integers like 1100,2000: {rates!r}") from None
    result = run_stream_bench(binary or build_sitl(project_dir), values, seconds)
    table = Table(title=f"FSP on the virtual FC, {seconds:g} s per rate")
    columns = ("fsp_rate_hz", "expected frames/s", "frames/s", "ratio", "transport loss",
               "FC drops", "rejected", "FC interval P1/P50/P99 µs",
               "OBC arrival P1/P50/P99 µs", "held")  # fmt: skip
    for column in columns:
        table.add_column(column, justify="right")
    for figures in result.rates:
        ratio = figures.frames_per_s / figures.expected_frames_per_s
        table.add_row(
            str(figures.rate_hz), f"{figures.expected_frames_per_s:.1f}",
            f"{figures.frames_per_s:.1f}", f"{ratio:.4f}", str(figures.lost_frames),
            str(figures.fc_drops), str(figures.errors), _quantiles(figures.fc_interval),
            _quantiles(figures.arrival_interval), "yes" if figures.held else "no",
        )  # fmt: skip
    out.print(table)
    best = result.highest_held
    held = (
        f"fsp_rate_hz {best.rate_hz}, {best.expected_frames_per_s:.0f} frames/s" if best else "none"
    )
    out.print(f"highest rate held with zero loss: {held}")
    first = result.rates[0].rate_hz
    out.print(f"verify CPU at fsp_rate_hz {first}: {result.cpu_percent:.1f} % of one core")
    p50, p99 = result.latency_ms
    out.print(f"decode latency, read to frames: P50 {p50:.3f} ms, P99 {p99:.3f} ms")


@bench_group.command("ros2")
@click.option(
    "--seconds", type=SECONDS, default=20.0, show_default=True, help="Streaming time per reader."
)
@rate_option
@sitl_options
def bench_ros2(seconds: float, rate_hz: int, binary: Path | None, project_dir: Path | None) -> None:
    """On the virtual FC: the ROS 2 node's CPU per kHz of frames and a subscriber's latency,
    beside FspReader reading the same stream (extra ros2)."""
    from wftool.bench.ros2 import COMMAND_RATE_HZ, run_ros2_bench
    from wftool.cli.sitl import build_sitl
    from wftool.extras import require

    require("ros2", what="bench ros2")
    result = run_ros2_bench(binary or build_sitl(project_dir), seconds, rate_hz)
    out.print(
        f"bench ros2: {result.seconds:g} s per reader at fsp_rate_hz {result.rate_hz} on the "
        "virtual FC; the node publishes fsp/imu, attitude, rc, rpm per frame, a subscriber "
        "process takes fsp/imu (reliable, events executor)"
    )
    table = Table(box=None, pad_edge=False)
    for column in ("reader", "frames", "Hz", "CPU % of a core", "CPU % per kHz",
                   "stamp → in hand P50 ms", "P99 ms", "max ms"):  # fmt: skip
        table.add_column(column, justify="right")
    for reader in (result.direct, result.node):
        latency = reader.latency
        table.add_row(
            reader.name, f"{reader.frames:,}", f"{reader.rate_hz:.1f}",
            f"{reader.cpu_percent:.1f}", f"{reader.cpu_percent_per_khz:.1f}",
            *(("–",) * 3 if latency is None else
              tuple(f"{v / 1e3:.2f}" for v in (latency.p50_us, latency.p99_us, latency.max_us))),
        )  # fmt: skip
    out.print(table)
    hop = result.hop
    if hop is not None:
        out.print(
            f"the node's hop (its read → the subscriber's callback), per frame: P50 "
            f"{hop.p50_us / 1e3:.2f} ms, P99 {hop.p99_us / 1e3:.2f} ms, "
            f"max {hop.max_us / 1e3:.2f} ms"
        )
    lost = result.published - result.received_of_published
    out.print(
        f"subscriber: {result.received_of_published:,} of the {result.published:,} frames "
        f"published while it measured ({lost} lost); its own CPU "
        f"{result.subscriber_cpu_percent:.1f} % of a core"
    )
    commands = result.commands
    out.print(
        f"commands at {COMMAND_RATE_HZ} Hz from the subscriber's process meanwhile: "
        f"{commands.sent} of {commands.received} sent ({result.commands_sent_fraction:.1%}); "
        f"{commands.superseded} superseded and {commands.stale} stale before the loop came "
        f"to them, {commands.dropped - commands.superseded - commands.stale} dropped otherwise"
    )


@bench_group.command("latency")
@click.option("--seconds", type=SECONDS, default=60.0, show_default=True, help="Streaming time.")
@rate_option
@click.option(
    "--time-reply/--no-time-reply",
    default=True,
    show_default=True,
    help="Have the FC answer commands (fsp_time_reply) and score the two-way estimator.",
)
@click.option(
    "--command-rate",
    type=Number(1.0, 1000.0, unit="commands/s"),
    default=50.0,
    show_default=True,
    help="Commands per second sent to the FC.",
)
@sitl_options
def bench_latency(
    seconds: float, rate_hz: int, time_reply: bool, command_rate: float, binary: Path | None,
    project_dir: Path | None,
) -> None:  # fmt: skip
    """On the virtual FC, against its true clock: each clock estimator's true error, and the
    true latency from FC sample to decoded frame."""
    from wftool.bench.latency import STEP_SETTLE_S, run_latency_bench
    from wftool.cli.sitl import build_sitl

    result = run_latency_bench(
        binary or build_sitl(project_dir), seconds, rate_hz, time_reply, command_rate
    )
    out.print(
        f"bench latency: {result.seconds:g} s at fsp_rate_hz {result.rate_hz}, "
        f"{result.frames:,} frames, {result.errors} rejected, {result.lost_frames} lost, "
        f"{result.reanchors} re-anchors (host > 50 ms behind)"
    )
    table = Table(title="true clock error (frames after lock)", box=None, pad_edge=False)
    for column in ("estimator", "lock s", "frames", "RMS µs", "P99 |err| µs",
                   "RMS − d_min µs", "within ± uncertainty", "uncertainty µs"):  # fmt: skip
        table.add_column(column, justify="right")
    for e in result.estimators:
        table.add_row(
            e.name, f"{e.lock_s:.1f}", f"{e.frames:,}", f"{e.rms_s * 1e6:.1f}",
            f"{e.p99_s * 1e6:.1f}",
            "–" if math.isnan(e.envelope_rms_s) else f"{e.envelope_rms_s * 1e6:.1f}",
            "–" if e.within_uncertainty is None else f"{100 * e.within_uncertainty:.1f} %",
            "–" if e.uncertainty_s is None else f"{e.uncertainty_s * 1e6:.1f}",
        )  # fmt: skip
    out.print(table)
    if settling := max(e.settling_frames for e in result.estimators):
        out.print(
            f"not scored: up to {settling:,} frames within {STEP_SETTLE_S:g} s of FC time after a "
            "re-anchor (the virtual FC's clock stood still; a board's does not)"
        )
    out.print(f"true minimum delay d_min (FC send → OBC read): {result.min_delay_s * 1e6:.1f} µs")
    table = Table(title="true latency to the decoded frame", box=None, pad_edge=False)
    for column in ("from", "P50 µs", "P99 µs", "max µs"):
        table.add_column(column, justify="right")
    for label, quantiles in (
        ("FC sample instant", result.sample_to_frame),
        ("FC packet send (tx_time_us)", result.send_to_frame),
        ("read returned (decode only)", result.decode),
        ("round trip (command → reply read)", result.rtt),
    ):
        if quantiles is not None:
            table.add_row(
                label, f"{quantiles.p50_us:.1f}", f"{quantiles.p99_us:.1f}",
                f"{quantiles.max_us:.1f}",
            )  # fmt: skip
    out.print(table)
    if result.time_reply:
        rejected = ", ".join(f"{k} {v}" for k, v in result.round_trip_rejected.items()) or "none"
        out.print(f"round trips: {result.round_trips:,}; not used: {rejected}")


@bench_group.command("command")
@click.option(
    "--seconds", type=SECONDS, default=20.0, show_default=True, help="Commanding time per row."
)
@click.option(
    "--rates",
    default="100,500",
    show_default=True,
    help="Command rates (Hz), comma-separated: each runs immediate, then timed.",
)
@click.option(
    "--lead-ms",
    type=Number(0.0, 40.0, unit="ms"),
    default=LEAD_MS,
    show_default=True,
    help="How far ahead of its time each timed command is sent.",
)
@click.option(
    "--paper",
    is_flag=True,
    help="As the paper's board: a 3148 Hz PID loop, UARTs at their baud rates, "
    "serial_update_rate_hz 1000.",
)
@sitl_options
def bench_command(
    seconds: float, rates: str, lead_ms: float, paper: bool, binary: Path | None,
    project_dir: Path | None,
) -> None:  # fmt: skip
    """On the virtual FC, against its true clock: when commands act, immediate ones against
    timed ones (E4, spec §13) sent a few ms ahead: the FC apply time − the intended time."""
    from wftool.bench.command import run_command_bench
    from wftool.cli.sitl import build_sitl
    from wftool.sitl.process import SITL_BOARD, VirtualBoard

    try:
        values = [float(value) for value in rates.split(",")]
    except ValueError:
        raise click.BadParameter(f"expected numbers like 100,500: {rates!r}") from None
    if not all(0 < value <= 1000 and math.isfinite(value) for value in values):
        raise click.BadParameter(f"command rates must be above 0 and at most 1000 Hz: {rates!r}")
    board, serial_rate = SITL_BOARD, None
    if paper:
        from wftool.analysis.setup import PAPER_BOARD, SERIAL_RATE_HZ

        board = VirtualBoard(PAPER_BOARD.gyro_hz, PAPER_BOARD.gyro_clock_hz, True)
        serial_rate = SERIAL_RATE_HZ
    result = run_command_bench(
        binary or build_sitl(project_dir), seconds, values, lead_ms / 1e3, board, serial_rate
    )
    pid = result.pid_period_us
    out.print(
        f"bench command: {seconds:g} s per row on the virtual FC (PID loop {1e6 / pid:.0f} Hz, "
        f"{pid:.1f} µs; UARTs {'at their baud rates' if result.uart_pacing else 'as fast as TCP'}"
        f"); timed commands mapped through the two-way clock "
        f"(± {result.clock_uncertainty_us:.0f} µs)"
    )
    spread = ("P1", "P50", "P99", "P99−P1", "max")
    table = Table(title="FC apply time − intended time, µs (true clock)", box=None, pad_edge=False)
    for column in ("command", "Hz", "lead ms", "sent", "applied", "late", "refused",
                   "superseded", *spread):  # fmt: skip
        table.add_column(column, justify="left" if column == "command" else "right")
    for row in result.rows:
        timed = row.mode == TIMED
        table.add_row(
            row.mode, f"{row.rate_hz:g}", f"{row.lead_ms:g}" if timed else "–",
            f"{row.sent:,}", f"{row.applied:,}",
            *((f"{row.late}", f"{row.refused}") if timed else ("–",) * 2), f"{row.superseded}",
            *_spread(row.apply),
        )  # fmt: skip
    out.print(table)
    own = Table(
        title="timed, the FC's own account: applying PID iteration − FC time asked for, µs",
        box=None,
        pad_edge=False,
    )
    for column in ("command", "Hz", "on time", *spread, "late", "latest"):
        own.add_column(column, justify="left" if column == "command" else "right")
    seen = Table(
        title=f"first frame whose RC shows the command − intended time, µs (frames every "
        f"{result.frame_period_us:.0f} µs)",
        box=None,
        pad_edge=False,
    )
    for column in ("command", "Hz", *spread):
        seen.add_column(column, justify="left" if column == "command" else "right")
    for row in result.rows:
        if row.mode == TIMED:
            own.add_row(
                row.mode, f"{row.rate_hz:g}", f"{row.asked.count if row.asked else 0:,}",
                *_spread(row.asked), f"{row.late}",
                "–" if row.latest_us is None else f"{row.latest_us:.0f}",
            )  # fmt: skip
        seen.add_row(row.mode, f"{row.rate_hz:g}", *_spread(row.seen))
    out.print(own)
    out.print(seen)
    late = result.lateness
    host = (
        f"host lateness: {late.over_us[1000]} of {late.waits:,} FC instants reached over 1 ms "
        f"late (worst {late.max_us / 1e3:.1f} ms), {result.reanchors} re-anchors"
        if late is not None
        else f"{result.reanchors} re-anchors"
    )
    unlocked = sum(row.unlocked for row in result.rows)
    one_way = sum(row.one_way for row in result.rows)
    misplaced = sum(row.misplaced for row in result.rows)
    out.print(
        f"{host}; timed commands not sent while the clock was unlocked: {unlocked}, "
        f"placed by the one-way line while the two-way clock relearnt: {one_way}, "
        f"refused as placed across an FC clock step not yet seen: {misplaced}; "
        f"the FC's books (E3): {result.accepted:,} fresh, {result.stale:,} stale of "
        f"{result.packets:,} commands; reports lost: {result.lost_reports}"
    )
    out.print(_command_note(result))


def _spread(spread: Distribution | None) -> tuple[str, ...]:
    if spread is None:
        return ("–",) * 5
    return tuple(
        f"{value:.0f}"
        for value in (spread.p1_us, spread.p50_us, spread.p99_us, spread.spread_us, spread.max_us)
    )


def _command_note(result: CommandBenchResult) -> str:
    """The closing note: P99−P1 per rate, immediate against timed, and the goal."""
    pid = result.pid_period_us
    parts, met, end_to_end = [], True, True
    for rate in dict.fromkeys(row.rate_hz for row in result.rows):
        rows = {row.mode: row for row in result.rows if row.rate_hz == rate}
        immediate, timed = rows.get(IMMEDIATE), rows.get(TIMED)

        def figure(spread: Distribution | None) -> str:
            return "–" if spread is None else f"{spread.spread_us:.0f}"

        own = timed.asked if timed is not None else None
        met &= own is not None and own.spread_us <= pid
        true = timed.apply if timed is not None else None
        end_to_end &= true is not None and true.spread_us <= pid
        parts.append(
            f"{rate:g} Hz: immediate {figure(immediate.apply if immediate else None)}, timed "
            f"{figure(timed.apply if timed else None)} ({timed.late if timed else 0} late), "
            f"on time by the FC's clock {figure(own)}"
        )
    return (
        f"P99−P1 of the apply time, µs: {'; '.join(parts)}. Goal, timed ≤ one PID period "
        f"({pid:.0f} µs): by the FC's clock {'met' if met else 'missed'}; end to end, with "
        f"the OBC's clock mapping (± {result.clock_uncertainty_us:.0f} µs), "
        f"{'met' if end_to_end else 'missed'}."
    )


def _quantiles(interval: Distribution | None) -> str:
    if interval is None:
        return "–"
    return f"{interval.p1_us:.0f}/{interval.p50_us:.0f}/{interval.p99_us:.0f}"


@bench_group.command("clock")
@click.option(
    "--seconds",
    type=SECONDS,
    default=300.0,
    show_default=True,
    help="Length of each simulated run.",
)
@click.option(
    "--seeds", type=click.IntRange(1), default=3, show_default=True, help="Runs per model."
)
@click.option(
    "--drift",
    type=Number(unit="ppm/min"),
    default=1.0,
    show_default=True,
    help="Drift of the FC's rate, ppm per minute.",
)
@click.option(
    "--repeat",
    type=click.IntRange(1),
    default=1,
    show_default=True,
    help="Timed passes per run for observations/s; the fastest counts.",
)
def bench_clock(seconds: float, seeds: int, drift: float, repeat: int) -> None:
    """Clock estimators on a simulated link with known truth: error, lock time, speed.

    Errors are over each packet's OBC time right after it arrived, once locked. "envelope"
    is against the true capture instant + the minimum delay (what one-way timing can
    identify); "absolute" is against the true capture instant (includes that delay).
    """
    from wftool.bench.clock import GOAL_RATIO, GOAL_RMS_S, MIN_DELAY_S, REFERENCE, run_clock_bench
    from wftool.fsp.estimators import ONE_WAY_ESTIMATORS

    result = run_clock_bench(ONE_WAY_ESTIMATORS, seeds=range(1, seeds + 1), seconds=seconds,
                             drift_ppm_per_min=drift, repeat=repeat)  # fmt: skip
    table = Table(
        title=f"clock estimators, {seconds:g} s runs × {seeds} seeds (worst seed shown); "
        f"skew ±100 ppm drifting {drift:g} ppm/min, d_min {MIN_DELAY_S * 1e3:g} ms"
    )
    for column in (
        "model", "estimator", "RMS µs", "P99 µs", f"× vs {REFERENCE}",
        "abs RMS µs", "abs P99 µs", "lock s", "obs/s",
    ):  # fmt: skip
        table.add_column(column, justify="left" if column in ("model", "estimator") else "right")
    for summary in result.summaries:
        is_reference = summary.estimator == REFERENCE
        table.add_row(
            summary.model, summary.estimator,
            f"{summary.envelope_rms_s * 1e6:,.1f}", f"{summary.envelope_p99_s * 1e6:,.1f}",
            "" if is_reference else f"{result.rms_ratio(summary):,.0f}",
            f"{summary.absolute_rms_s * 1e6:,.1f}", f"{summary.absolute_p99_s * 1e6:,.1f}",
            f"{summary.lock_time_s:.2f}", f"{summary.observations_per_s:,.0f}",
        )  # fmt: skip
    out.print(table)
    for name in ONE_WAY_ESTIMATORS:
        if name != REFERENCE:
            out.print(f"{name}: {result.speed_ratio(name):.2f}x the observations/s of {REFERENCE}")
    misses = ", ".join(f"{s.model} ({s.estimator})" for s in result.goal_misses())
    goal = f"RMS <= {GOAL_RMS_S * 1e6:g} µs and >= {GOAL_RATIO:g}x better than {REFERENCE}"
    out.print(f"goal ({goal}): " + (f"missed on {misses}" if misses else "met on every model"))


@bench_group.command("record")
@click.option(
    "--seconds",
    type=SECONDS,
    default=60.0,
    show_default=True,
    help="Length of the recorded stream.",
)
@click.option(
    "--chunk", default=118, show_default=True, help="Bytes per read [one packet, as live]."
)
@click.option(
    "--repeat",
    type=click.IntRange(1),
    default=3,
    show_default=True,
    help="Runs of each format; the least CPU counts (a shared machine is noisy).",
)
@click.option(
    "--stream",
    "streams",
    type=click.Choice(STREAMS),
    multiple=True,
    help="Stream(s) to record [all]: realistic motion and sensor noise, or every value "
    "sweeping (RC included) without noise.",
)
def bench_record(seconds: float, chunk: int, repeat: int, streams: tuple[str, ...]) -> None:
    """Bytes and CPU per frame of recording, JSON vs ROS 2 MCAP, at 1 kHz."""
    from wftool.bench.record import STALL_SPEED, run_record_bench

    for stream in streams or STREAMS:
        result = run_record_bench(seconds, chunk, repeat, stream)
        json_figures = result.format("json")
        table = Table(
            title=f"recording the {stream} stream, {result.frames:,} frames ({seconds:g} s "
            f"at ~1 kHz), {chunk} B reads, best of {repeat}"
        )
        for column in (
            "format", "bytes/frame", "CPU µs/frame", "% of a core at 1 kHz", "vs JSON",
            "replay frames/s", "columns frames/s",
        ):  # fmt: skip
            table.add_column(column, justify="left" if column == "format" else "right")
        for figures in result.formats:
            size_ratio = figures.bytes_per_frame / json_figures.bytes_per_frame
            cpu_ratio = figures.cpu_us_per_frame / json_figures.cpu_us_per_frame
            columns = figures.columns_frames_per_s
            table.add_row(
                figures.name,
                f"{figures.bytes_per_frame:.1f}",
                f"{figures.cpu_us_per_frame:.1f}",
                f"{figures.core_percent_at_1khz:.2f}",
                f"size {size_ratio:.2f}x, CPU {cpu_ratio:.2f}x",
                f"{figures.replay_frames_per_s:,.0f}",
                "needs wftool[analysis]" if columns is None else f"{columns:,.0f}",
            )
        out.print(table)
        reference = 1e6 * result.reference_cpu_s / result.frames
        out.print(f"reference (decode + monitor, no recording): {reference:.1f} µs/frame")
        stalls = Table(
            title=f"the reading thread's stalls while recording the ROS 2 messages again "
            f"({STALL_SPEED:g}x real time), least worst of {repeat}"
        )
        for column in ("writer", "reads", "chunks", "worst ms", "P99.9 ms", "reads > 1 ms"):
            stalls.add_column(column, justify="left" if column == "writer" else "right")
        for stall in result.stalls:
            stalls.add_row(
                stall.name,
                f"{stall.reads:,}",
                f"{stall.chunks}",
                f"{1e3 * stall.worst_s:.2f}",
                f"{1e3 * stall.p999_s:.2f}",
                f"{stall.over_1ms}",
            )
        out.print(stalls)
        process, in_process = result.stalls
        out.print(
            f"worst stall: writer process {process.worst_s / in_process.worst_s:.2f}x the "
            f"in-process writer's; reads over 1 ms: {process.over_1ms} vs {in_process.over_1ms} "
            f"({in_process.chunks} chunks); target: no chunk stalls the reading thread"
        )
    out.print(
        f"targets: ROS 2 <= {ROS2_BYTES_PER_FRAME_GOAL:g} B/frame and no larger "
        "than JSON; recording <= 5 % of one core at 1 kHz"
    )


COMMANDS: list[click.Command] = [bench_group]
