"""`wftool paper timing`: the paper's timing evaluation reproduced in one call, on the virtual
FC or a board: FSP and MSP recorded, Table 1 beside the paper's, Figs. 2–4
(docs/analysis.md).

    run = run_timing(Path("paper-timing"), duration_s=30, binary=sitl_binary)
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from wftool.analysis import accfilter, spectrum, timing
from wftool.analysis.flight import FlightSpec
from wftool.analysis.harness import PRESETS
from wftool.analysis.published import FSP_BAUD, MSP_BAUD, SETUP, TABLE1
from wftool.analysis.report import FcAccount, MspRun, ReportInput, write_report
from wftool.analysis.setup import (
    FSP_BAUD_WHY,
    MSP_BAUD_SWEEP,
    PAPER_BOARD,
    PAPER_MSP_BAUD,
    PAPER_MSP_BAUD_WHY,
    SERIAL_RATE_HZ,
)
from wftool.errors import UsageError
from wftool.fc.board import SerialBoard
from wftool.fc.cli_session import CliSession
from wftool.fc.msp_poller import DEFAULT_WINDOW, PollResult
from wftool.fc.params import apply_plan
from wftool.fc.plan import plan_from_assignments
from wftool.fc.tasks import parse_status, parse_tasks
from wftool.fsp import DEFAULT_BAUDRATE
from wftool.fsp.schedule import DEFAULT_RATE_HZ
from wftool.progress import Log, quiet
from wftool.recording.msp import record_msp
from wftool.sitl.process import SITL_BOARD, VirtualBoard
from wftool.sitl.session import Motion, VirtualFcSession
from wftool.sitl.truth import Lateness, lateness_between
from wftool.verify.session import VerifyResult, VerifySession, fc_frame_rate_hz

BOARD_MSP_BAUD = 115200
"""The baud rate a board's MSP port is opened at unless told (a USB port ignores it)."""
OBC_CLOCK = "kalman"
"""The paper's clock alignment (§4.2), for FSP on the OBC clock beside the FC's times."""
ACCFILTER_RATE_HZ = 800
"""The BMI270's accelerometer rate, for the harness's Fig. 4."""
ACCFILTER_DURATION_S = 20.0
OUTPUTS = ("fsp", "msp", "sitl", "report.md", "table1.json")
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
    msp_baud: int
    written: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    table: list[dict[str, str]] = field(default_factory=list)
    sweep: dict[int, PollResult] = field(default_factory=dict)
    """MSP polled at further baud rates of the port (the virtual FC), by baud rate."""
    account: FcAccount | None = None
    fsp_lateness: Lateness | None = None
    msp_lateness: dict[int, Lateness | None] = field(default_factory=dict)
    setup: list[tuple[str, str, str]] = field(default_factory=list)
    fc: str = ""


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
    virtual_board: VirtualBoard = PAPER_BOARD,
    msp_baud: int | None = None,
    msp_baud_sweep: Sequence[int] = MSP_BAUD_SWEEP,
    log: Log = quiet,
) -> TimingRun:
    """The whole comparison (docs/analysis.md) on the virtual FC built as `binary`,
    emulating `virtual_board` (the paper's, by default), or on `board`. `serial_rate_hz`
    None leaves a board's setting as it is (the virtual FC then gets the highest it allows).
    `msp_baud`: the MSP port's baud rate (the virtual FC: set on it, `PAPER_MSP_BAUD` unless
    told; a board: opened at it, `BOARD_MSP_BAUD` unless told); `msp_baud_sweep`: the virtual
    FC's MSP polled again at these. `with_accfilter` False leaves out the harness's Fig. 4
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
        baud = msp_baud or BOARD_MSP_BAUD
        with _board(board, out_dir, fsp_rate_hz, serial_rate_hz, log) as expected_rate_hz:
            run = _record(board, out_dir, duration_s, expected_rate_hz, serial_rate_hz, window,
                          baud, log)  # fmt: skip
            run.account = _account(board.msp_url, log)
        run.fc = f"a board (MSP {board.msp_url}, FSP {board.fsp_url})"
    elif binary is not None:  # one of them, as checked above
        baud = msp_baud or PAPER_MSP_BAUD
        run = _virtual_fc(binary, out_dir, duration_s, fsp_rate_hz, serial_rate_hz, window,
                          virtual_board, baud, msp_baud_sweep, log)  # fmt: skip
    run.setup = _setup(run, fsp_rate_hz, window, board, virtual_board, duration_s)
    _figures(run, project_dir, with_accfilter, log)
    return run


def _virtual_fc(
    binary: Path,
    out_dir: Path,
    duration_s: float,
    fsp_rate_hz: int,
    serial_rate_hz: int | None,
    window: int,
    virtual_board: VirtualBoard,
    msp_baud: int,
    sweep: Sequence[int],
    log: Log,
) -> TimingRun:
    """The recordings on the virtual FC (its eeprom.bin, log and backups in `sitl/`): FSP and
    MSP, its own account, then MSP at each baud rate of `sweep`."""
    workdir = out_dir / "sitl"
    session = VirtualFcSession(
        binary,
        workdir,
        rate_hz=fsp_rate_hz,
        motion=Motion(),
        port_base=None,  # any free ports: taken at the start, another if one was grabbed
        serial_update_rate_hz=serial_rate_hz,
        board=virtual_board,
        msp_baud=msp_baud,
    )
    paced = ", paced UARTs" if virtual_board.uart_pacing else ""
    log(f"starting the virtual FC in {workdir} (serial_update_rate_hz {serial_rate_hz}, MSP "
        f"port {msp_baud} baud{paced})")  # fmt: skip
    with session:
        ports = Board(session.msp_url, session.fsp_url)
        run = _record(ports, out_dir, duration_s, session.expected_rate_hz, serial_rate_hz,
                      window, msp_baud, log, session.fc.log_path)  # fmt: skip
        run.account = _account(session.msp_url, log)
        session.fc.wait_back()  # leaving the CLI resets the FC
        for baud in sweep:
            if baud == msp_baud:
                continue
            log(f"the MSP port at {baud} baud")
            session.set_msp_baud(baud)
            started = time.monotonic()
            run.sweep[baud] = _record_msp(ports.msp_url, out_dir / f"msp-{baud}", duration_s,
                                          window, None, serial_rate_hz, baud, log)  # fmt: skip
            run.msp_lateness[baud] = lateness_between(
                session.fc.log_path, started, time.monotonic()
            )
            run.written.append(out_dir / f"msp-{baud}")
    board = "the SITL as it is" if virtual_board == SITL_BOARD else "the paper's board"
    run.fc = f"the virtual FC ({board})"
    return run


@contextlib.contextmanager
def _board(
    board: Board, out_dir: Path, fsp_rate_hz: int, serial_rate_hz: int | None, log: Log
) -> Iterator[float]:
    """A board with `serial_rate_hz` set (unless None): the frame rate to expect."""
    if serial_rate_hz is not None:
        plan = plan_from_assignments([f"serial_update_rate_hz={serial_rate_hz}"])
        report = apply_plan(SerialBoard(board.msp_url), plan, out_dir / "backups", log)
        for row in report.rows:
            log(f"{row.name}: {row.before} -> {row.after} (backup {report.backup})")
        if report.mismatches:
            raise UsageError(f"the board did not take the setting: {'; '.join(report.mismatches)}")
    yield fc_frame_rate_hz(board.msp_url, fsp_rate_hz)


def _record(
    fc: Board,
    out_dir: Path,
    duration_s: float,
    expected_rate_hz: float,
    serial_rate_hz: int | None,
    window: int,
    msp_baud: int,
    log: Log,
    sitl_log: Path | None = None,
) -> TimingRun:
    """The FSP recording, then the MSP recording, on one FC (and, with the virtual FC's
    `sitl_log`, how late its host ran it during each)."""
    log(f"recording FSP on {fc.fsp_url} for {duration_s:g} s (expected {expected_rate_hz:.1f} Hz)")
    started = time.monotonic()
    fsp = VerifySession(
        fc.fsp_url,
        fc.fsp_baud,
        duration_s,
        expected_rate_hz=expected_rate_hz,
        record_path=out_dir / "fsp",
    ).run()
    fsp_window = (started, time.monotonic())
    acc_1g = fsp.latest.acc_1g if fsp.latest is not None else None
    log(f"recording MSP for {duration_s:g} s (the paper's schedule)")
    started = time.monotonic()
    msp = _record_msp(fc.msp_url, out_dir / "msp", duration_s, window, acc_1g or None,
                      serial_rate_hz, msp_baud, log)  # fmt: skip
    run = TimingRun(out_dir, fsp, msp, serial_rate_hz, msp_baud, [out_dir / "fsp", out_dir / "msp"])
    if sitl_log is not None:
        run.fsp_lateness = lateness_between(sitl_log, *fsp_window)
        run.msp_lateness[msp_baud] = lateness_between(sitl_log, started, time.monotonic())
    return run


def _record_msp(
    url: str,
    path: Path,
    duration_s: float,
    window: int,
    acc_1g: int | None,
    serial_rate_hz: int | None,
    baud: int,
    log: Log,
) -> PollResult:
    result = record_msp(
        url,
        path,
        duration_s,
        window=window,
        baudrate=baud,
        acc_1g=acc_1g,
        serial_update_rate_hz=serial_rate_hz,
        log=log,
    )
    if result.interrupted:  # Ctrl-C: the recording is finished; the comparison is abandoned
        raise KeyboardInterrupt
    return result


def _account(msp_url: str, log: Log) -> FcAccount:
    """The FC's `tasks` and `status` after the recordings; leaving the CLI resets it."""
    log("asking the FC what it ran (CLI tasks, status)")
    session = CliSession.open(msp_url)
    try:
        tasks, status = session.run("tasks"), session.run("status")
    finally:
        session.exit()
    cycle = parse_status(status)
    return FcAccount(
        parse_tasks(tasks),
        cycle[0] if cycle else None,
        cycle[1] if cycle else None,
        f"# tasks\n{tasks.strip()}\n# status\n{status.strip()}",
    )


def _setup(
    run: TimingRun,
    fsp_rate_hz: int,
    window: int,
    board: Board | None,
    virtual_board: VirtualBoard,
    duration_s: float,
) -> list[tuple[str, str, str]]:
    """(item, ours, the paper's) of the set-up, ours from this run."""
    tasks = run.account.tasks if run.account else {}
    pid = tasks.get("PID")
    serial = tasks.get("SERIAL")
    if board is None:
        gyro = (
            f"virtual gyro reporting {virtual_board.gyro_hz or 8000} Hz, samples at "
            f"{virtual_board.gyro_clock_hz or virtual_board.gyro_hz or 8000:g} Hz"
        )
        uarts = "paced: 10 bits a byte at each port's baud, in FC time" if (
            virtual_board.uart_pacing) else "as fast as TCP (unpaced)"  # fmt: skip
        fc = f"the virtual FC (patched SITL), {gyro}; UARTs {uarts}"
    else:
        fc = run.fc
    msp = (
        ", ".join(f"{c.name} {c.rate_hz:g} Hz" for c in run.msp.commands.values())
        + f"; at most {window} in flight; stamped on reception"
    )
    paper_msp = ", ".join(f"{name} {p.value:g} Hz" for name, p in SETUP.msp_rates_hz.items())
    fsp_port = f"{DEFAULT_BAUDRATE} baud ({FSP_BAUD_WHY})"
    msp_port = f"{run.msp_baud} baud"
    if board is not None:
        fsp_port = f"{board.fsp_url} at {board.fsp_baud} baud"
        msp_port = f"{board.msp_url} opened at {run.msp_baud} baud"
    elif run.msp_baud == PAPER_MSP_BAUD:
        msp_port += f" ({PAPER_MSP_BAUD_WHY})"
    host = f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end"
    return [
        ("flight controller", fc, SETUP.board),
        (
            "PID loop",
            f"{pid.rate_hz} Hz by the FC's scheduler (`tasks`)" if pid else "—",
            f"{SETUP.loop_nominal_hz.value:g} Hz nominal, {SETUP.loop_hz.value:g} Hz by the "
            f"scheduler (§5.1)",
        ),
        (
            "serial_update_rate_hz",
            f"{run.serial_update_rate_hz}"
            + (f" (`tasks`: SERIAL {serial.rate_hz} Hz)" if serial else ""),
            f"{SETUP.serial_update_rate_hz.value:g} (§5.1)",
        ),
        (
            "fsp_rate_hz",
            f"{fsp_rate_hz}",
            f"{SETUP.fsp_rate_hz.value:g}, N = {SETUP.lockstep_n.value:g} (§5.2)",
        ),
        ("FSP port", fsp_port, FSP_BAUD),
        ("MSP port", msp_port, MSP_BAUD),
        ("MSP requests", msp, f"{paper_msp} (§5.2); stamped on reception"),
        ("FSP times", "the FC's sample times; also aligned to the OBC clock (Kalman)",
         TABLE1["FSP"].setup + " (§5.2)"),
        ("duration", f"{duration_s:g} s of FSP, then {duration_s:g} s of MSP", "not stated"),
        ("host", host, "Jetson Orin NX 16GB (OBC), the FC on its own (§5.1)"),
    ]  # fmt: skip


def _figures(run: TimingRun, project_dir: Path | None, with_accfilter: bool, log: Log) -> None:
    """Table 1, Figs. 2–4 and the report from the recordings (and the filter harness)."""
    out_dir = run.out_dir
    fsp = timing.load_timing(out_dir / "fsp", label="FSP")
    msp = timing.load_timing(out_dir / "msp", label="MSP")
    series = [fsp, msp]
    try:
        fsp_obc = timing.load_timing(out_dir / "fsp", label="FSP, OBC time", obc_clock=OBC_CLOCK)
    except UsageError as exc:
        fsp_obc = None
        run.notes.append(f"FSP on the OBC clock: {exc}")
    run.table = timing.table_rows(series, paper=True)
    run.notes += timing.table_notes(series, paper=True)
    run.written.append(timing.write_table(series, out_dir, "table1", paper=True)[1])
    (out_dir / "table1.md").unlink()  # the table is in report.md
    figures = [
        ("fig2-histograms.png", "Fig. 2: the sample intervals", timing.draw_histograms),
        ("fig3-intervals.png", "Fig. 3: the sample intervals over time", timing.draw_intervals),
    ]
    captions = []
    for name, caption, draw in figures:
        draw(series, out_dir / name)
        run.written.append(out_dir / name)
        captions.append((name, caption))
    _spectrum(spectrum.read_series(out_dir / "fsp"), out_dir / "fig4-fsp-spectrum.png", run)
    captions.append(("fig4-fsp-spectrum.png", "Fig. 4: the FSP recording's acceleration (STFT)"))
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
        captions.append(
            (
                "fig4-accfilter-spectrum.png",
                "Fig. 4: a synthetic flight's acceleration before and after the series' RPM "
                "filter (STFT)",
            )
        )
    sweep = [
        MspRun(baud, timing.load_timing(out_dir / f"msp-{baud}", label=f"MSP {baud}"), poll,
               run.msp_lateness.get(baud))
        for baud, poll in run.sweep.items()
    ]  # fmt: skip
    report = ReportInput(
        fc=run.fc,
        fsp=fsp,
        fsp_obc=fsp_obc,
        msp=MspRun(run.msp_baud, msp, run.msp, run.msp_lateness.get(run.msp_baud)),
        sweep=sweep,
        account=run.account,
        setup=run.setup,
        fsp_lateness=run.fsp_lateness,
        figures=captions,
        notes=run.notes,
    )
    run.written.append(write_report(report, out_dir / "report.md"))


def _spectrum(series: spectrum.AccSeries, out: Path, run: TimingRun) -> None:
    spectrum.draw(series, spectrum.spectrogram(series), out)
    run.notes += [f"{out.name}: {note}" for note in series.notes]
    run.written.append(out)
