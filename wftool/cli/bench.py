"""Commands: benchmarks that print figures (bench ...)."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.table import Table

from wftool.build.bench import bench_build
from wftool.cli.build import build_options, options_from, project_from

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
    default="1100,2000,3000,4000",
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
    from wftool.cli.stream import build_sitl

    try:
        values = [int(value) for value in rates.split(",")]
    except ValueError:
        raise click.BadParameter(f"expected integers like 1100,2000: {rates!r}") from None
    result = run_stream_bench(binary or build_sitl(project_dir), values, seconds)
    table = Table(title=f"FSP on the virtual FC, {seconds:g} s per rate")
    for column in ("fsp_rate_hz", "frames/s", "transport loss", "FC drops", "rejected", "held"):
        table.add_column(column, justify="right")
    for figures in result.rates:
        table.add_row(
            str(figures.rate_hz), f"{figures.frames_per_s:.1f}", str(figures.lost_frames),
            str(figures.fc_drops), str(figures.errors), "yes" if figures.held else "no",
        )  # fmt: skip
    out.print(table)
    out.print(f"highest rate held with zero loss: {result.highest_held_rate or 'none'}")
    first = result.rates[0].rate_hz
    out.print(f"verify CPU at fsp_rate_hz {first}: {result.cpu_percent:.1f} % of one core")
    p50, p99 = result.latency_ms
    out.print(f"decode latency, read to frames: P50 {p50:.3f} ms, P99 {p99:.3f} ms")


@bench_group.command("record")
@click.option("--seconds", default=60.0, show_default=True, help="Length of the recorded stream.")
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
def bench_record(seconds: float, chunk: int, repeat: int) -> None:
    """Bytes and CPU per frame of recording, JSON vs ROS 2 MCAP, at 1 kHz."""
    from wftool.bench.record import run_record_bench

    result = run_record_bench(seconds, chunk, repeat)
    json_figures = result.format("json")
    table = Table(
        title=f"recording {result.frames:,} frames ({seconds:g} s at ~1 kHz), "
        f"{chunk} B reads, best of {repeat}"
    )
    for column in ("format", "bytes/frame", "CPU µs/frame", "% of a core at 1 kHz", "vs JSON"):
        table.add_column(column, justify="left" if column == "format" else "right")
    for figures in result.formats:
        size_ratio = figures.bytes_per_frame / json_figures.bytes_per_frame
        cpu_ratio = figures.cpu_us_per_frame / json_figures.cpu_us_per_frame
        table.add_row(
            figures.name,
            f"{figures.bytes_per_frame:.1f}",
            f"{figures.cpu_us_per_frame:.1f}",
            f"{figures.core_percent_at_1khz:.2f}",
            f"size {size_ratio:.2f}x, CPU {cpu_ratio:.2f}x",
        )
    out.print(table)
    reference = 1e6 * result.reference_cpu_s / result.frames
    out.print(f"reference (decode + monitor, no recording): {reference:.1f} µs/frame")
    out.print("targets: ROS 2 no larger than JSON; recording <= 5 % of one core at 1 kHz")


COMMANDS: list[click.Command] = [bench_group]
