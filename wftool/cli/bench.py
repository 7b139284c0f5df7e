"""Commands: benchmarks that print figures (`wftool bench …`)."""

from __future__ import annotations

import click
from rich.console import Console
from rich.table import Table


@click.group()
def bench() -> None:
    """Measure wftool's own performance and print the figures."""


@bench.command("decode")
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
    Console().print(table)


COMMANDS: list[click.Command] = [bench]
