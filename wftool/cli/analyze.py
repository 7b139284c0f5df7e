"""Commands: analysis of recordings and of the firmware's filters (analyze ...).

They need the `analysis` extra; without it they say so in one line and exit 2. The heavy
imports happen inside the commands, so `wftool --help` never pays for them.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from wftool.analysis.harness import PRESETS
from wftool.cli.build import project_option
from wftool.display import shown
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
        err.print(shown(f"note: {note}"), soft_wrap=True)
    out.print(
        shown(
            f"wrote {target}: {len(series.panels)} panel(s), {series.time_s[-1]:.1f} s at "
            f"{series.sample_rate_hz:.0f} Hz, {series.motor_hz.shape[1]} motor(s)"
        )
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
    from wftool.analysis import accfilter
    from wftool.analysis.flight import FlightSpec
    from wftool.analysis.harness import FilterSettings

    settings = [FilterSettings.parse(text) for text in configs] or list(PRESETS.values())
    names = [s.name for s in settings]
    if len(set(names)) != len(names):
        raise click.BadParameter("configuration names must differ", param_hint="--config")
    evaluation, written = accfilter.run(
        project_dir,
        settings,
        list(dict.fromkeys(rates or (800, 1000))),
        FlightSpec(duration_s=duration),
        out_dir,
        repeat=repeat,
        with_m7=not no_m7,
        progress=lambda message: err.print(shown(message, "dim")),
    )
    print_table(accfilter.summary_rows(evaluation), left=1)
    check = evaluation.m7_check
    if check:
        out.print(
            f"M7 estimate: {check['cycle_model']} at {int(check['clock_hz']) / 1e6:g} MHz; "
            f"{check['function']} executed {check['executed_instructions']} instructions, "
            f"its disassembly has {check['disassembly_instructions']}"
        )
    out.print(shown(f"wrote {', '.join(str(path) for path in written)}"))
    out.print(shown(f"Fig. 4 of a flight: wftool analyze spectrum {written[2]}"))


@analyze_group.command(
    "timing", short_help="Table 1, Figs. 2-3: sample-interval statistics of recordings."
)
@click.argument("recordings", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("timing"),
    show_default=True,
    help="Directory for timing.md, timing.json, fig2-histograms.png, fig3-intervals.png.",
)
@click.option(
    "--expected-rate",
    type=click.FloatRange(min=0, min_open=True),
    metavar="HZ",
    help="The rate the samples should come at [what each recording says].",
)
@click.option("--paper", is_flag=True, help="Add the paper's published rows for comparison.")
def timing_command(
    recordings: tuple[Path, ...], out_dir: Path, expected_rate: float | None, paper: bool
) -> None:
    """Table 1 and Figs. 2-3: the intervals between consecutive samples of each recording.

    FSP (a verify --record recording or a raw capture of the FSP port): the FC's sample
    times. MSP (a record msp recording): the reception times of MSP_RAW_IMU replies. A
    recording cut by a reconnection, an FC reset or a gap is analysed in its longest
    segment (the table says so; the JSON has every segment).
    """
    require("analysis", "numpy", "matplotlib", what="analyze timing")
    from wftool.analysis import timing

    series = [timing.load_timing(path, expected_rate) for path in recordings]
    print_table(timing.table_rows(series, paper), timing.table_notes(series, paper))
    written = list(timing.write_table(series, out_dir, "timing", paper))
    for name, draw in (
        ("fig2-histograms.png", timing.draw_histograms),
        ("fig3-intervals.png", timing.draw_intervals),
    ):
        draw(series, out_dir / name)
        written.append(out_dir / name)
    out.print(shown(f"wrote {', '.join(str(path) for path in written)}"))


@analyze_group.command(
    "timed",
    short_help="What the uplink's command path (E4, who flies) costs the SPEEDYBEEF7V3's M7.",
)
@project_option
def timed_command(project_dir: Path | None) -> None:
    """What the uplink's command path costs the SPEEDYBEEF7V3: the series' code for timed
    commands (E4) and who flies (spec §15) built with Betaflight's F7 flags and run on an
    emulated Cortex-M7, per PID iteration, per FSP task run and per command, and its RAM."""
    require("analysis", *EMULATOR, what="analyze timed")
    from wftool.analysis import timedcost

    cost = timedcost.run(project_dir, progress=lambda message: err.print(shown(message, "dim")))
    print_table(
        [
            {
                "where": case.where,
                "what": case.name,
                "instructions": f"{case.instructions}",
                "cycles": f"{case.cycles}",
                "µs at 216 MHz": f"{case.us:.3f}",
                **{
                    f"% of a {rate:g} Hz loop": f"{case.percent_of(rate):.2f}"
                    for rate in timedcost.PID_RATES_HZ
                },
            }
            for case in cost.cases
        ]
    )
    check = cost.check
    out.print(
        f"RAM: {cost.authority_bytes} bytes (sizeof(fspAuthority_t)), of them the queue's "
        f"{cost.queue_bytes} (sizeof(fspQueue_t)); cycles: one per executed "
        f"instruction at {int(check['clock_hz']) / 1e6:g} MHz; {check['function']} executed "
        f"{check['executed_instructions']} instructions, its disassembly has "
        f"{check['disassembly_instructions']}"
    )


def print_table(rows: list[dict[str, str]], notes: Sequence[str] = (), left: int = 2) -> None:
    """Rows (column -> text) as a table on stdout, the first `left` columns left-aligned
    and the rest (numbers) right-aligned; then the notes."""
    table = Table(box=None, pad_edge=False)
    for index, column in enumerate(rows[0]):
        table.add_column(column, justify="left" if index < left else "right")
    for row in rows:
        table.add_row(*(shown(value) for value in row.values()))
    out.print(table)
    for note in notes:
        out.print(shown(f"note: {note}"), soft_wrap=True)


COMMANDS: list[click.Command] = [analyze_group]
