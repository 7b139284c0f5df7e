"""`wftool paper timing`: the paper's timing evaluation reproduced in one call, on the virtual
FC or a board: FSP and MSP recorded, Table 1 beside the paper's, Figs. 2–4
(docs/analysis.md).

    run = run_timing(Path("paper-timing"), duration_s=30, binary=sitl_binary)
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from wftool.analysis import accfilter, spectrum, timing
from wftool.analysis.flight import FlightSpec
from wftool.analysis.harness import PRESETS
from wftool.errors import UsageError
from wftool.fc.board import SerialBoard
from wftool.fc.msp_poller import DEFAULT_WINDOW, PollResult
from wftool.fc.params import apply_plan, plan_from_assignments
from wftool.fsp import DEFAULT_BAUDRATE
from wftool.fsp.schedule import DEFAULT_RATE_HZ
from wftool.progress import Log, quiet
from wftool.recording.msp import record_msp
from wftool.sitl.session import Motion, VirtualFcSession
from wftool.verify.session import VerifyResult, VerifySession, fc_frame_rate_hz

SERIAL_RATE_HZ = 1000
"""The paper's MSP baseline: a 1 kHz serial task (`serial_update_rate_hz`)."""
ACCFILTER_RATE_HZ = 800
"""The BMI270's accelerometer rate, for the harness's Fig. 4."""
ACCFILTER_DURATION_S = 20.0
OUTPUTS = ("fsp", "msp", "sitl", "table1.md", "table1.json")
"""What marks a directory that already holds a run."""


@dataclass(frozen=True)
class Board:
    """A real FC: its MSP/CLI port and its FSP port."""

    msp_url: str
    fsp_url: str
    fsp_baud: int = DEFAULT_BAUDRATE


@dataclass
class TimingRun:
    """What `run_timing` did and wrote."""

    out_dir: Path
    fsp: VerifyResult
    msp: PollResult
    serial_update_rate_hz: int | None
    written: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    table: list[dict[str, str]] = field(default_factory=list)


def run_timing(
    out_dir: Path,
    duration_s: float,
    *,
    binary: Path | None = None,
    board: Board | None = None,
    fsp_rate_hz: int = DEFAULT_RATE_HZ,
    serial_rate_hz: int | None = SERIAL_RATE_HZ,
    window: int = DEFAULT_WINDOW,
    project_dir: Path | None = None,
    with_accfilter: bool = True,
    log: Log = quiet,
) -> TimingRun:
    """The whole comparison (docs/analysis.md) on the virtual FC built as `binary`,
    or on `board`. `serial_rate_hz` None leaves a board's setting as it is (the virtual
    FC then gets the highest it allows). `with_accfilter` False leaves out the harness's Fig. 4
    (it compiles the series' filter code from betaflight/ of `project_dir`)."""
    if (binary is None) == (board is None):
        raise UsageError("run_timing needs either a SITL binary or a board")
    if not duration_s > 0:
        raise UsageError(f"the duration must be positive, not {duration_s:g} s")
    if taken := [name for name in OUTPUTS if (out_dir / name).exists()]:
        raise UsageError(f"{out_dir} already holds a run ({taken[0]}): choose another output")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot create {out_dir}: {exc.strerror or exc}") from None
    if board is not None:
        fc = _board(board, out_dir, fsp_rate_hz, serial_rate_hz, log)
    elif binary is not None:  # one of them, as checked above
        fc = _virtual_fc(binary, out_dir / "sitl", fsp_rate_hz, serial_rate_hz, log)
    with fc as (ports, expected_rate_hz):
        run = _record(ports, out_dir, duration_s, expected_rate_hz, serial_rate_hz, window, log)
    _figures(run, project_dir, with_accfilter, log)
    return run


@contextlib.contextmanager
def _virtual_fc(
    binary: Path, workdir: Path, fsp_rate_hz: int, serial_rate_hz: int | None, log: Log
) -> Iterator[tuple[Board, float]]:
    """The virtual FC set up for the run (its eeprom.bin, log and backups in `workdir`):
    its ports and the frame rate to expect."""
    session = VirtualFcSession(
        binary,
        workdir,
        rate_hz=fsp_rate_hz,
        motion=Motion(),
        port_base=None,  # any free ports: taken at the start, another if one was grabbed
        serial_update_rate_hz=serial_rate_hz,
    )
    log(f"starting the virtual FC in {workdir} (serial_update_rate_hz {serial_rate_hz})")
    with session:
        yield Board(session.msp_url, session.fsp_url), session.expected_rate_hz


@contextlib.contextmanager
def _board(
    board: Board, out_dir: Path, fsp_rate_hz: int, serial_rate_hz: int | None, log: Log
) -> Iterator[tuple[Board, float]]:
    """A board with `serial_rate_hz` set (unless None), and the frame rate to expect."""
    if serial_rate_hz is not None:
        plan = plan_from_assignments([f"serial_update_rate_hz={serial_rate_hz}"])
        report = apply_plan(SerialBoard(board.msp_url), plan, out_dir / "backups", log)
        for row in report.rows:
            log(f"{row.name}: {row.before} -> {row.after} (backup {report.backup})")
        if report.mismatches:
            raise UsageError(f"the board did not take the setting: {'; '.join(report.mismatches)}")
    yield board, fc_frame_rate_hz(board.msp_url, fsp_rate_hz)


def _record(
    fc: Board,
    out_dir: Path,
    duration_s: float,
    expected_rate_hz: float,
    serial_rate_hz: int | None,
    window: int,
    log: Log,
) -> TimingRun:
    """The FSP recording, then the MSP recording, on one FC."""
    log(f"recording FSP on {fc.fsp_url} for {duration_s:g} s (expected {expected_rate_hz:.1f} Hz)")
    fsp = VerifySession(
        fc.fsp_url,
        fc.fsp_baud,
        duration_s,
        expected_rate_hz=expected_rate_hz,
        record_path=out_dir / "fsp",
    ).run()
    acc_1g = fsp.latest.acc_1g if fsp.latest is not None else None
    log(f"recording MSP for {duration_s:g} s (the paper's schedule)")
    msp = record_msp(
        fc.msp_url,
        out_dir / "msp",
        duration_s,
        window=window,
        acc_1g=acc_1g or None,
        serial_update_rate_hz=serial_rate_hz,
        log=log,
    )
    if msp.interrupted:  # Ctrl-C: the recording is finished; the comparison is abandoned
        raise KeyboardInterrupt
    return TimingRun(out_dir, fsp, msp, serial_rate_hz, [out_dir / "fsp", out_dir / "msp"])


def _figures(run: TimingRun, project_dir: Path | None, with_accfilter: bool, log: Log) -> None:
    """Table 1 and Figs. 2–4 from the recordings (and the filter harness)."""
    out_dir = run.out_dir
    series = [
        timing.load_timing(out_dir / "fsp", label="FSP"),
        timing.load_timing(out_dir / "msp", label="MSP"),
    ]
    run.table = timing.table_rows(series, paper=True)
    run.notes += timing.table_notes(series, paper=True)
    run.written += timing.write_table(series, out_dir, "table1", paper=True)
    figures = {
        out_dir / "fig2-histograms.png": timing.draw_histograms,
        out_dir / "fig3-intervals.png": timing.draw_intervals,
    }
    for path, draw in figures.items():
        draw(series, path)
        run.written.append(path)
    _spectrum(spectrum.read_series(out_dir / "fsp"), out_dir / "fig4-fsp-spectrum.png", run)
    if with_accfilter:
        log("flying the accelerometer-filter harness (the series' filter code, compiled)")
        _, written = accfilter.run(
            project_dir,
            [PRESETS["paper"]],
            [ACCFILTER_RATE_HZ],
            FlightSpec(duration_s=ACCFILTER_DURATION_S),
            out_dir / "accfilter",
            repeat=1,
            with_m7=False,
            progress=log,
        )
        run.written += written
        flight = out_dir / "accfilter" / f"flight-{ACCFILTER_RATE_HZ}hz.npz"
        _spectrum(spectrum.read_series(flight), out_dir / "fig4-accfilter-spectrum.png", run)


def _spectrum(series: spectrum.AccSeries, out: Path, run: TimingRun) -> None:
    spectrum.draw(series, spectrum.spectrogram(series), out)
    run.notes += [f"{out.name}: {note}" for note in series.notes]
    run.written.append(out)
