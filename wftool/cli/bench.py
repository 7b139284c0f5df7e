"""Commands: benchmarks that print figures (bench ...)."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.table import Table

from wftool.bench.build import bench_build
from wftool.cli.build import build_options, options_from, project_from
from wftool.verify.monitor import IntervalSummary

out = Console(highlight=False, width=None if sys.stdout.isatty() else 200)


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
@click.option("--minutes", default=10.0, show_default=True, help="Length of the replayed stream.")
@click.option("--chunk", default=4096, show_default=True, help="Bytes handed to each feed().")
@click.option("--tunnel", is_flag=True, help="Replay the 180-byte MAVLink-tunnel variant.")
@click.option(
    "--repeat",
    type=click.IntRange(1),
    default=3,
    show_default=True,
    help="Replays; the best and the median are shown (a shared machine is noisy).",
)
def bench_decode(minutes: float, chunk: int, tunnel: bool, repeat: int) -> None:
    """FSP decoder throughput (bytes in → frames out) and memory over a long replay."""
    from wftool.bench.decode import REALTIME_PACKETS_PER_S, run_decode_bench, write_capture

    with tempfile.TemporaryDirectory(prefix="wftool-bench-") as scratch:
        capture = Path(scratch) / "capture.fsp"
        write_capture(capture, int(minutes * 60 * REALTIME_PACKETS_PER_S), tunnel)
        runs = sorted(
            (run_decode_bench(capture, chunk) for _ in range(repeat)),
            key=lambda r: r.packets_per_s,
        )
    best, median = runs[-1], runs[len(runs) // 2]
    table = Table(title=f"FSP decode, {minutes:g} min replay, {chunk} B reads, {repeat} runs")
    table.add_column("")
    table.add_column("best", justify="right")
    table.add_column("median", justify="right")
    table.add_row("packets", f"{best.packets:,}", f"{median.packets:,}")
    table.add_row("frames out", f"{best.frames:,}", f"{median.frames:,}")
    table.add_row("decode time", f"{best.seconds:.2f} s", f"{median.seconds:.2f} s")
    table.add_row("packets/s", f"{best.packets_per_s:,.0f}", f"{median.packets_per_s:,.0f}")
    table.add_row(
        "frames/s", f"{best.frames / best.seconds:,.0f}", f"{median.frames / median.seconds:,.0f}"
    )
    table.add_row(
        "MB/s",
        f"{best.bytes / best.seconds / 1e6:.1f}",
        f"{median.bytes / median.seconds / 1e6:.1f}",
    )
    table.add_row(
        "vs real time (525 packets/s)",
        f"{best.realtime_factor:,.0f}x",
        f"{median.realtime_factor:,.0f}x",
    )
    table.add_row("errors, lost frames", f"{best.errors}, {best.lost_frames}", "")
    out.print(table)
    rss = " / ".join(f"{k / 1024:.1f}" for k in best.rss_kib)
    out.print(f"peak RSS at 0/25/50/75/100 % of the best replay: {rss} MiB")


@bench_group.command("stream")
@click.option(
    "--rates",
    default="1100,2000,3000,8000",
    show_default=True,
    help="fsp_rate_hz values to try, comma-separated; the first is the default rate.",
)
@click.option("--seconds", default=60.0, show_default=True, help="Streaming time per rate.")
@click.option(
    "--binary",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="SITL program [build the patched one].",
)
@click.option("--project", "project_dir", type=click.Path(file_okay=False, path_type=Path))
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


def _quantiles(interval: IntervalSummary | None) -> str:
    if interval is None:
        return "–"
    return f"{interval.p1_us:.0f}/{interval.p50_us:.0f}/{interval.p99_us:.0f}"


@bench_group.command("clock")
@click.option("--seconds", default=300.0, show_default=True, help="Length of each simulated run.")
@click.option(
    "--seeds", type=click.IntRange(1), default=3, show_default=True, help="Runs per model."
)
@click.option(
    "--drift", default=1.0, show_default=True, help="Drift of the FC's rate, ppm per minute."
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
    from wftool.fsp.clock import ESTIMATORS

    result = run_clock_bench(ESTIMATORS, seeds=range(1, seeds + 1), seconds=seconds,
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
    for name in ESTIMATORS:
        if name != REFERENCE:
            out.print(f"{name}: {result.speed_ratio(name):.2f}x the observations/s of {REFERENCE}")
    misses = ", ".join(f"{s.model} ({s.estimator})" for s in result.goal_misses())
    goal = f"RMS <= {GOAL_RMS_S * 1e6:g} µs and >= {GOAL_RATIO:g}x better than {REFERENCE}"
    out.print(f"goal ({goal}): " + (f"missed on {misses}" if misses else "met on every model"))


COMMANDS: list[click.Command] = [bench_group]
