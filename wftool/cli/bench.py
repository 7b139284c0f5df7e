"""Commands: benchmarks that print figures (bench ...)."""

from __future__ import annotations

import sys
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
def bench_decode(minutes: float, chunk: int, tunnel: bool) -> None:
    """FSP decoder throughput (bytes in → frames out) and memory over a long replay."""
    from wftool.bench.decode import run_decode_bench

    result = run_decode_bench(minutes, chunk, tunnel)
    table = Table(title=f"FSP decode, {minutes:g} min replay, {chunk} B reads", show_header=False)
    table.add_row("packets", f"{result.packets:,}")
    table.add_row("frames out", f"{result.frames:,}")
    table.add_row("decode time", f"{result.seconds:.2f} s")
    table.add_row("throughput", f"{result.packets_per_s:,.0f} packets/s")
    table.add_row("", f"{result.frames / result.seconds:,.0f} frames/s")
    table.add_row("", f"{result.bytes / result.seconds / 1e6:.1f} MB/s")
    table.add_row("vs real time", f"{result.realtime_factor:,.0f}x (525 packets/s)")
    table.add_row(
        "peak RSS 0/25/50/75/100 %", " / ".join(f"{k / 1024:.1f}" for k in result.rss_kib) + " MiB"
    )
    table.add_row("errors, lost frames", f"{result.errors}, {result.lost_frames}")
    out.print(table)


COMMANDS: list[click.Command] = [bench_group]
