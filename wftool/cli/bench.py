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
    """Benchmarks that print figures."""


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


COMMANDS: list[click.Command] = [bench_group]
