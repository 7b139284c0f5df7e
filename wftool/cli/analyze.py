"""Commands: analysis of recordings and of the firmware's filters (analyze ...).

They need the `analysis` extra; without it they say so in one line and exit 2. The heavy
imports happen inside the commands, so `wftool --help` never pays for them.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from wftool.analysis.harness import PRESETS
from wftool.cli.build import project_option
from wftool.extras import require

out = Console(highlight=False, markup=False, width=None if sys.stdout.isatty() else 200)
err = Console(stderr=True, highlight=False)
PLOTTING = ("numpy", "scipy", "matplotlib")
EMULATOR = ("unicorn",)
"""The Cortex-M7 emulator that counts the filter's instructions (part of the same extra)."""


@click.group("analyze")
def analyze_group() -> None:
    """Figures from recordings and from the firmware's filters (needs wftool[analysis])."""


@analyze_group.command(
    "spectrum", short_help="Fig. 4: acceleration spectrogram with the motor fundamentals."
)
@click.argument("recording", type=click.Path(path_type=Path))
@click.option(
    "--out",
    "out_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="The PNG to write (default: RECORDING with the suffix .spectrum.png).",
)
@click.option(
    "--axis",
    type=click.Choice(["sum", "x", "y", "z", "norm"]),
    default="sum",
    show_default=True,
    help="sum: PSD of x + y + z; x, y, z: one axis; norm: PSD of |a|.",
)
def spectrum_command(recording: Path, out_path: Path | None, axis: str) -> None:
    """Fig. 4: acceleration spectrogram with the motor fundamentals, as a PNG.

    RECORDING is a `wftool verify --record` recording (a rosbag2 directory or an MCAP file,
    either format) or an acceleration series (.npz) such as `wftool analyze accfilter`
    writes (before and after the RPM filter).
    """
    require("analysis", *PLOTTING, what="analyze spectrum")
    from wftool.analysis.spectrum import dominant_peaks, draw, read_series, spectrogram

    series = read_series(recording)
    spec = spectrogram(series, axis)
    target = out_path or recording.with_suffix(".spectrum.png")
    draw(series, spec, target)
    for note in series.notes:
        err.print(f"note: {note}", markup=False, soft_wrap=True)
    out.print(
        f"wrote {target}: {len(series.panels)} panel(s), {series.time_s[-1]:.1f} s at "
        f"{series.sample_rate_hz:.0f} Hz, {series.motor_hz.shape[1]} motor(s)"
    )
    for index, panel in enumerate(series.panels):
        peaks = ", ".join(f"{hz:.0f} Hz ({db:.0f} dB)" for hz, db in dominant_peaks(spec, index))
        out.print(f"  {panel.title}: strongest peaks {peaks or 'none'}")


@analyze_group.command("accfilter")
@click.option(
    "--config",
    "configs",
    multiple=True,
    metavar="NAME[:key=value,...]",
    help=f"A filter configuration: a preset ({', '.join(PRESETS)}) or e.g. "
    f"'wide:harmonics=2,q=300'; repeatable. Default: all presets.",
)
@click.option(
    "--rate",
    "rates",
    type=click.IntRange(100, 8000),
    multiple=True,
    help="Accelerometer sample rate in Hz; repeatable. Default: 800 (BMI270) and 1000.",
)
@click.option("--duration", type=click.FloatRange(3.0, 600.0), default=30.0, show_default=True,
              help="Length of the synthetic flight in s.")  # fmt: skip
@click.option("--repeat", type=click.IntRange(1), default=15, show_default=True,
              help="Host timing runs; medians are reported.")  # fmt: skip
@click.option("--no-m7", is_flag=True, help="Skip the Cortex-M7 estimate (no ARM toolchain).")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("accfilter"),
    show_default=True,
    help="Directory for accfilter.md, accfilter.json and the flights' .npz series.",
)
@project_option
def accfilter_command(
    configs: tuple[str, ...],
    rates: tuple[int, ...],
    duration: float,
    repeat: int,
    no_m7: bool,
    out_dir: Path,
    project_dir: Path | None,
) -> None:
    """Quantify the accelerometer RPM filter: attenuation, motion delay, CPU cost.

    Compiles the patch series' own filter code (betaflight/, fetched and patched if needed)
    into a host harness, flies a synthetic flight through it (four motors sweeping 100 ->
    400 Hz, vibration at the fundamental and harmonics, slow motion, sensor noise), and
    counts its instructions on an emulated Cortex-M7 built with Betaflight's F7 flags.
    """
    require("analysis", *PLOTTING, *(() if no_m7 else EMULATOR), what="analyze accfilter")
    from wftool import __version__
    from wftool.analysis import accfilter, sources
    from wftool.analysis.flight import FlightSpec
    from wftool.analysis.harness import (
        FilterSettings,
        HostHarness,
        compile_host_library,
        host_flags,
    )
    from wftool.analysis.m7 import M7_FLAGS, M7Harness, build_image
    from wftool.analysis.spectrum import Panel, write_series

    settings = [FilterSettings.parse(text) for text in configs] or list(PRESETS.values())
    names = [s.name for s in settings]
    if len(set(names)) != len(names):
        raise click.BadParameter("configuration names must differ", param_hint="--config")
    rate_list = list(dict.fromkeys(rates or (800, 1000)))
    tree = sources.patched_tree(project_dir)
    with tempfile.TemporaryDirectory(prefix="wftool-accfilter-") as scratch:
        filter_sources = sources.filter_sources(tree, Path(scratch))
        harness = HostHarness(compile_host_library(filter_sources, Path(scratch) / "host"))
        provenance: dict[str, object] = {
            "wftool": __version__,
            "betaflight revision": filter_sources.revision,
            "filter sources": ", ".join(str(p.relative_to(tree)) for p in filter_sources.sources),
            "filter sources sha256": filter_sources.sha256,
            "host flags": " ".join(host_flags(filter_sources)),
        }
        m7 = None
        if not no_m7:
            gcc = sources.arm_gcc(project_dir)
            m7 = M7Harness(build_image(filter_sources, Path(scratch) / "m7", gcc))
            provenance["m7 flags"] = " ".join(
                [*M7_FLAGS, *(f"-D{d}" for d in filter_sources.defines)]
            )
            provenance["m7 compiler"] = f"{gcc} {m7.image.gcc_version}"
        evaluation = accfilter.evaluate(
            harness,
            settings,
            rate_list,
            FlightSpec(duration_s=duration),
            m7=m7,
            repeat=repeat,
            provenance=provenance,
            progress=lambda message: err.print(message, style="dim", markup=False),
        )
    markdown, data = accfilter.write_report(evaluation, out_dir)
    written = [markdown, data]
    first = settings[0].name
    for rate, flight in evaluation.flights.items():
        path = out_dir / f"flight-{rate}hz.npz"
        write_series(
            path,
            flight.time_s,
            flight.motor_hz,
            [
                Panel("raw", f"before the RPM filter ({rate} Hz)", flight.raw),
                Panel(
                    "filtered",
                    f"after the RPM filter ({first}: {settings[0].describe()})",
                    evaluation.filtered[(first, rate)],
                ),
            ],
        )
        written.append(path)
    rows = accfilter.summary_rows(evaluation)
    table = Table(box=None, pad_edge=False)
    for column in rows[0]:
        table.add_column(column, justify="left" if column == "config" else "right")
    for row in rows:
        table.add_row(*row.values())
    out.print(table)
    check = evaluation.m7_check
    if check:
        out.print(
            f"M7 estimate: {check['cycle_model']} at {int(check['clock_hz']) / 1e6:g} MHz; "
            f"{check['function']} executed {check['executed_instructions']} instructions, "
            f"its disassembly has {check['disassembly_instructions']}"
        )
    out.print(f"wrote {', '.join(str(path) for path in written)}")
    out.print(f"Fig. 4 of a flight: wftool analyze spectrum {written[2]}")


COMMANDS: list[click.Command] = [analyze_group]
