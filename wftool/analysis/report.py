"""The report of `paper timing`: Table 1 ours beside the paper's, row by row, with the
difference and a line on whether and why it differs, the set-up of both, how the MSP figures
move with the MSP port's baud rate, the FC's own account (`tasks`, `status`) and the figures.

Every paper figure comes from `wftool.analysis.published`, cited; every explanation is
computed from this run (the FC's `tasks`, the poll's counts, the link model: 10 bits a byte
at the port's baud rate, the virtual FC's lateness log), not written to match.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wftool.analysis import markdown
from wftool.analysis.published import (
    FSP_MEAN_CAUSE,
    FSP_SPREAD_CAUSE,
    MSP_MODES_US,
    MSP_OUTLIER_RATIO,
    MSP_OUTLIERS,
    PAPER,
    SETUP,
    TABLE1,
    Published,
    PublishedRow,
)
from wftool.analysis.timing import TimingSeries
from wftool.errors import UsageError
from wftool.fc.msp import Cmd
from wftool.fc.msp_poller import PollResult
from wftool.fc.tasks import TaskRow
from wftool.sitl.truth import Lateness
from wftool.stats import median, quantile

BITS_PER_BYTE = 10
"""A UART byte on the wire: start bit, 8 data bits, stop bit."""
MSP_V1_OVERHEAD = 6
"""`$M>`, length, command, checksum."""
RAW_IMU_PAYLOAD = 18
"""MSP_RAW_IMU: acc, gyro and mag, 3 × int16 each."""
MODE_MIN_SHARE = 0.005
"""A histogram peak holding less than this share of the intervals is no mode."""


def wire_us(nbytes: int, baud: int) -> float:
    """How long `nbytes` take on a UART at `baud`."""
    return nbytes * BITS_PER_BYTE / baud * 1e6


@dataclass(frozen=True)
class MspRun:
    """One MSP recording: the port's baud rate, its intervals and what the poll got."""

    baud: int
    series: TimingSeries
    poll: PollResult
    lateness: Lateness | None = None
    """How late the virtual FC's host ran it meanwhile (None: a board, or not known)."""


@dataclass(frozen=True)
class FcAccount:
    """What the FC said it ran (CLI `tasks` and `status`, after the recordings)."""

    tasks: dict[str, TaskRow]
    cycle_us: int | None
    gyro_rate_hz: int | None
    text: str


@dataclass
class ReportInput:
    """Everything the report is made of."""

    fc: str
    """Which FC: "the virtual FC …" or the board's ports."""
    fsp: TimingSeries
    fsp_obc: TimingSeries | None
    """FSP on the OBC clock, aligned by the paper's estimator (None: no arrival times)."""
    msp: MspRun
    sweep: list[MspRun]
    """MSP at other baud rates of the MSP port (the virtual FC)."""
    account: FcAccount | None
    setup: list[tuple[str, str, str]]
    """(item, ours, the paper's) of the set-up."""
    fsp_lateness: Lateness | None = None
    figures: list[tuple[str, str]] = field(default_factory=list)
    """(file name, caption) in the output directory."""
    notes: list[str] = field(default_factory=list)


def _us(value: float | None, digits: int = 1) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def _ms(value: float | None) -> str:
    return "—" if value is None else f"{value / 1000.0:.3f}"


def _cite(figure: Published) -> str:
    return f"{PAPER}, {figure.source}"


def _rows(series: TimingSeries) -> list[tuple[str, float | None]]:
    stats = series.stats
    return [
        ("expected", series.expected_us),
        ("mean", stats.mean_us),
        ("median", stats.p50_us),
        ("1st percentile", stats.p1_us),
        ("99th percentile", stats.p99_us),
        ("P99−P1 spread", stats.spread_us),
    ]


def _table(series: TimingSeries, paper: PublishedRow, why: dict[str, str]) -> list[str]:
    """One protocol's Table 1 in ms, as the paper gives it, with µs differences and why."""
    rows = []
    theirs = list(paper.figures().values())
    for (name, ours), figure in zip(_rows(series), theirs, strict=True):
        difference = None if ours is None else ours - figure.value
        rows.append((name, _ms(ours), _ms(figure.value), _signed(difference), why[name]))
    rate = series.stats.rate_hz
    rate_difference = None if rate is None else rate - paper.rate_hz.value
    rows.append(
        (
            "mean rate (Hz)",
            _us(rate),
            f"{paper.rate_hz.value:.0f}",
            f"{_signed(rate_difference)} Hz",
            why["rate"],
        )
    )
    header = ("metric", "ours (ms)", "the paper (ms)", "ours − paper (µs)", "whether and why")
    return markdown.table(header, rows, "lrrrl")


def _signed(value: float | None) -> str:
    return "—" if value is None else f"{value:+.1f}"


def _verdict(ours: float | None, figure: Published, unit: str = "µs") -> str:
    """ "agrees" within the paper's rounding (Table 1: 1 µs, §5.2: 1 Hz), else by how much."""
    if ours is None:
        return "not measured"
    difference = ours - figure.value
    return "agrees" if abs(difference) <= 0.5 else f"differs by {difference:+.1f} {unit}"


# -- FSP ------------------------------------------------------------------------------------


def _fsp_why(report: ReportInput) -> dict[str, str]:
    series, paper = report.fsp, TABLE1["FSP"]
    stats = series.stats
    deltas = series.deltas_us
    values, counts = np.unique(np.round(deltas).astype(np.int64), return_counts=True)
    shares = ", ".join(
        f"{value} µs {100 * count / deltas.size:.1f} %"
        for value, count in sorted(zip(values, counts), key=lambda vc: -vc[1])[:3]
    )
    account = report.account
    pid = account.tasks.get("PID") if account else None
    fsp_task = account.tasks.get("FSP") if account else None
    n = round(SETUP.lockstep_n.value)
    loop = f", its scheduler's PID loop at {pid.rate_hz} Hz (`tasks`)" if pid else ""
    expected = (
        f"{_verdict(series.expected_us, paper.expected_us)}: N = {n} PID periods as the FC "
        f"measures them (MSP_STATUS, averaged){loop}; the paper's: N = {n} "
        f"({SETUP.lockstep_n.source}) at {SETUP.loop_hz.value:.0f} Hz ({SETUP.loop_hz.source})"
    )
    obc = report.fsp_obc
    if obc is not None:
        ppm = (obc.stats.mean_us / stats.mean_us - 1.0) * 1e6
        aligned = (
            f" Aligned by the paper's estimator (its Kalman filter, §4.2) ours are "
            f"{obc.stats.mean_us:.3f} µs apart on average: its clock-rate estimate over this run "
            f"is {ppm:+.0f} ppm off the true rate (the virtual FC's clock is the host's, 0 ppm)."
        )
    else:
        aligned = ""
    mean = (
        f"{_verdict(stats.mean_us, paper.mean_us)}: ours are the FC's own sample times, "
        f"{stats.mean_us:.3f} µs apart on average, N loop periods exactly; the paper's are "
        f"{paper.setup} (§5.2), which carry the estimated FC/OBC clock rate: 1 µs is 1000 ppm."
        f"{aligned} {FSP_MEAN_CAUSE.source} {FSP_MEAN_CAUSE.text}"
    )
    median = (
        f"{_verdict(stats.p50_us, paper.median_us)}: micros() truncates the exact sample "
        f"instants, N loop periods apart, to whole µs: intervals {shares}; the paper's median "
        f"is on clock-aligned times (see the mean)"
    )
    board = (
        f"the virtual FC's tasks take no time (`tasks` avg/us 0) and its gyro samples exactly, "
        f"so every capture sits on its loop iteration and the spread is micros()' truncation "
        f"alone; the paper's board adds {FSP_SPREAD_CAUSE.text} ({FSP_SPREAD_CAUSE.source} "
        f"those), and its clock alignment"
    )
    late = report.fsp_lateness
    host = (
        f" FC sample times do not carry the host's lateness ({_late_share(late)})." if late else ""
    )
    rate = f"{_verdict(stats.rate_hz, paper.rate_hz, 'Hz')}: 1 / mean" + (
        f"; the FC's FSP task ran at {fsp_task.rate_hz} Hz (`tasks`)" if fsp_task else ""
    )
    return {
        "expected": expected,
        "mean": mean,
        "median": median,
        "1st percentile": f"{_verdict(stats.p1_us, paper.p1_us)}: {board}.{host}",
        "99th percentile": f"{_verdict(stats.p99_us, paper.p99_us)}: as the 1st percentile",
        "P99−P1 spread": f"{_verdict(stats.spread_us, paper.spread_us)}: {board}",
        "rate": rate,
    }


# -- MSP ------------------------------------------------------------------------------------


def _late_share(late: Lateness) -> str:
    if late.waits == 0:
        return "no instants logged"
    over = late.over_us
    return (
        f"the virtual FC's host reached {100 * over[500] / late.waits:.2f} % of its "
        f"{late.waits} instants more than 0.5 ms late, {100 * over[1000] / late.waits:.2f} % "
        f"more than 1 ms, the latest {late.max_us / 1000:.1f} ms"
    )


def find_modes(deltas_us: np.ndarray, bin_us: float = 50.0) -> list[tuple[float, float]]:
    """(centre µs, share) of the histogram's local peaks holding `MODE_MIN_SHARE` or more,
    largest first; a centre is the median of the intervals within a bin of its peak."""
    ordered = np.sort(deltas_us)
    top = quantile(ordered, 0.999)
    edges = np.arange(0.0, top + 2 * bin_us, bin_us)
    counts, _ = np.histogram(deltas_us, edges)
    share = counts / max(deltas_us.size, 1)
    padded = np.concatenate([[0.0], share, [0.0]])
    peaks = []
    for i in range(share.size):
        if share[i] >= MODE_MIN_SHARE and share[i] >= padded[i] and share[i] > padded[i + 2]:
            near = deltas_us[np.abs(deltas_us - (edges[i] + bin_us / 2)) <= bin_us]
            peaks.append((median(near), float(share[i])))
    return sorted(peaks, key=lambda peak: -peak[1])


def _msp_why(report: ReportInput) -> dict[str, str]:
    run, paper = report.msp, TABLE1["MSP"]
    stats, poll = run.series.stats, run.poll
    imu = poll.commands.get(int(Cmd.RAW_IMU))
    duration = poll.duration_s or 1.0
    others = sum(c.replies for cmd, c in poll.commands.items() if cmd != int(Cmd.RAW_IMU))
    others_hz = others / duration
    account = report.account
    serial = account.tasks.get("SERIAL") if account else None
    reply_us = wire_us(MSP_V1_OVERHEAD + RAW_IMU_PAYLOAD, run.baud)
    request_us = wire_us(MSP_V1_OVERHEAD, run.baud)
    answers = (
        f"the FC answers one MSP command per SERIAL task run (msp_serial.c), and `tasks` "
        f"reports SERIAL at {serial.rate_hz} Hz; RC, ATTITUDE and ANALOG took "
        f"{others_hz:.1f} of them a second, which leaves the IMU at most "
        f"{serial.rate_hz - others_hz:.1f} Hz"
        if serial
        else f"RC, ATTITUDE and ANALOG took {others_hz:.1f} answers a second"
    )
    poll_counts = (
        f"; of {imu.slots} IMU slots {imu.sent} were sent, {imu.skipped} skipped (the window "
        f"of requests in flight full), {imu.missed} missed, {imu.lost} lost"
        if imu
        else ""
    )
    paper_serial = paper.rate_hz.value + others_hz
    rate = (
        f"{_verdict(stats.rate_hz, paper.rate_hz, 'Hz')}: {answers}{poll_counts}. The paper's "
        f"{paper.rate_hz.value:.0f} Hz with the same schedule (§5.2) fits a SERIAL task "
        f"answering about {paper_serial:.0f} times a second: on a board a task that falls due "
        f"while the gyro/PID tasks run waits for them; the virtual FC's tasks take no time"
    )
    modes = find_modes(run.series.deltas_us)
    ours_modes = ", ".join(f"{c / 1000:.2f} ms ({100 * s:.1f} %)" for c, s in modes[:5])
    paper_modes = ", ".join(f"{m.value / 1000:g} ms" for m in MSP_MODES_US)
    late = run.lateness
    host = f"; {_late_share(late)}" if late else ""
    short = float(np.mean(run.series.deltas_us < 1000.0 - reply_us))
    p1 = (
        f"{_verdict(stats.p1_us, paper.p1_us)}: the FC answers at most one command a SERIAL "
        f"run, 1 ms apart, and a RAW_IMU reply takes {reply_us:.0f} µs on the wire at "
        f"{run.baud} baud; {100 * short:.1f} % of intervals are shorter than "
        f"{1000 - reply_us:.0f} µs: a reply received late, then one on time (or two in one "
        f"read){host}; the OBC's reading shares that host. The paper's FC ran on a board of "
        f"its own: its {paper.p1_us.value / 1000:.3f} ms is its OBC's reception jitter"
    )
    expected = run.series.expected_us or paper.expected_us.value
    longest = float(run.series.deltas_us.max())
    beyond = float(np.mean(run.series.deltas_us > MSP_OUTLIER_RATIO * expected))
    p99 = (
        f"{_verdict(stats.p99_us, paper.p99_us)}: the longest usual wait is an IMU request "
        f"queued behind RC, ATTITUDE and ANALOG (their slots coincide every 100 ms: 3 more "
        f"SERIAL runs, 4 ms). Our modes: {ours_modes}; the paper's lie around {paper_modes} "
        f"({MSP_MODES_US[0].source.split(':')[0]}): its 1.2 and 3.2 ms are 0.2 ms after 1 and "
        f"3 runs, answers late as a board's SERIAL task is when it falls due while the "
        f"gyro/PID tasks run; the virtual FC's tasks take no time. Outliers: the longest of ours "
        f"is {longest / 1000:.1f} ms ({longest / expected:.1f} × expected, "
        f"{100 * beyond:.2f} % beyond {MSP_OUTLIER_RATIO:g} ×); the paper's reach "
        f"{MSP_OUTLIERS.text} ({MSP_OUTLIERS.source})"
    )
    return {
        "expected": (
            f"{_verdict(run.series.expected_us, paper.expected_us)}: MSP_RAW_IMU requested at "
            f"{imu.rate_hz if imu else 0:g} Hz ({SETUP.msp_rates_hz['RAW_IMU'].source}); a "
            f"request takes {request_us:.0f} µs on the wire"
        ),
        "mean": f"{_verdict(stats.mean_us, paper.mean_us)}: 1 / the mean rate (below)",
        "median": (
            f"{_verdict(stats.p50_us, paper.median_us)}: most IMU replies follow each other one "
            f"SERIAL run (1 ms) apart"
        ),
        "1st percentile": p1,
        "99th percentile": p99,
        "P99−P1 spread": (
            f"{_verdict(stats.spread_us, paper.spread_us)}: the 99th percentile minus the 1st "
            f"(above)"
        ),
        "rate": rate,
    }


def _sweep(report: ReportInput) -> list[str]:
    runs = sorted([report.msp, *report.sweep], key=lambda run: run.baud)
    header = (
        "MSP baud", "RAW_IMU reply on the wire (µs)", "replies/s the wire carries", "mean (ms)",
        "median (ms)", "P1 (ms)", "P99 (ms)", "P99−P1 (ms)", "mean rate (Hz)",
    )  # fmt: skip
    reply = MSP_V1_OVERHEAD + RAW_IMU_PAYLOAD
    rows = []
    for run in runs:
        stats = run.series.stats
        mark = " (this run's)" if run is report.msp else ""
        rows.append(
            (
                f"{run.baud}{mark}", f"{wire_us(reply, run.baud):.0f}",
                f"{run.baud / BITS_PER_BYTE / reply:.0f}", _ms(stats.mean_us), _ms(stats.p50_us),
                _ms(stats.p1_us), _ms(stats.p99_us), _ms(stats.spread_us), _us(stats.rate_hz),
            )
        )  # fmt: skip
    lines = markdown.table(header, rows, "r" * len(header))
    lines += [
        "",
        f"The paper: mean {_ms(TABLE1['MSP'].mean_us.value)} ms, median "
        f"{_ms(TABLE1['MSP'].median_us.value)}, P1 {_ms(TABLE1['MSP'].p1_us.value)}, P99 "
        f"{_ms(TABLE1['MSP'].p99_us.value)}, {TABLE1['MSP'].rate_hz.value:.0f} Hz "
        f"({PAPER}, Table 1, §5.2).",
    ]
    slow = [run for run in runs if wire_us(reply, run.baud) > 1000.0]
    for run in slow:
        lines.append(
            f"At {run.baud} baud a RAW_IMU reply alone takes {wire_us(reply, run.baud):.0f} µs: "
            f"the wire carries at most {run.baud / BITS_PER_BYTE / reply:.0f} replies a "
            f"second, so 1 kHz polling cannot be met there."
        )
    return lines


def render(report: ReportInput) -> str:
    """report.md's text."""
    lines = [
        f"# Table 1 on {report.fc}: ours beside the paper's",
        "",
        "Timestamp deltas between consecutive IMU samples, as the paper's Table 1 gives them "
        f"(ms). Ours from this run; the paper's from {PAPER}, Table 1 and §5.2, each cited. "
        "Differences in µs (Hz for rates); each row says whether it agrees (within the "
        "paper's rounding) and why it differs, from the FC's own `tasks` and the link model.",
        "",
        "## Set-up",
        "",
        *markdown.table(("", "ours", "the paper"), report.setup),
        "",
        f"## MSP: {report.msp.series.clock} of MSP_RAW_IMU replies",
        "",
        *_table(report.msp.series, TABLE1["MSP"], _msp_why(report)),
        "",
        f"## FSP: {report.fsp.clock}",
        "",
        *_table(report.fsp, TABLE1["FSP"], _fsp_why(report)),
    ]
    if report.fsp_obc is not None:
        obc = report.fsp_obc.stats
        lines += [
            "",
            f"FSP on the OBC clock ({report.fsp_obc.clock}, as the paper's times are): mean "
            f"{obc.mean_us:.3f} µs, median {obc.p50_us:.3f}, P1 {obc.p1_us:.3f}, P99 "
            f"{obc.p99_us:.3f}, spread {obc.spread_us:.3f} µs.",
        ]
    lines += ["", "## MSP and the MSP port's baud rate", "", *_sweep(report)]
    if report.account is not None:
        lines += [
            "",
            "## The FC's own account (after the recordings)",
            "",
            "```",
            report.account.text.strip(),
            "```",
        ]
    if report.figures:
        lines += ["", "## Figures", ""]
        for name, caption in report.figures:
            lines += [f"![{caption}]({name})", "", f"*{caption}* (`{name}`)", ""]
    if report.notes:
        lines += ["", "## Notes", "", *(f"- {note}" for note in report.notes)]
    return "\n".join(lines).rstrip() + "\n"


def write_report(report: ReportInput, out: Path) -> Path:
    """report.md at `out`."""
    try:
        out.write_text(render(report))
    except OSError as exc:
        raise UsageError(f"cannot write {out}: {exc.strerror or exc}") from None
    return out
