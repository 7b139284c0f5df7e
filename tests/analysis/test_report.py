"""report.md of `paper timing`: each Table 1 row ours beside the paper's with the difference and
a verdict, the set-up, the baud-rate sweep with the link model, the FC's account, the
figures. Built from series with known intervals (the figures here are computed by plain
Python) and the paper's values as `published` holds them."""

from __future__ import annotations

import re

import pytest

from wftool.analysis.published import PAPER, TABLE1
from wftool.fc.msp import Cmd
from wftool.fc.msp_poller import CommandStats, PollResult
from wftool.fc.tasks import parse_tasks
from wftool.sitl.truth import Lateness

np = pytest.importorskip("numpy", reason="needs the analysis extra (NumPy)")

from wftool.analysis.report import (  # noqa: E402
    FcAccount,
    MspRun,
    ReportInput,
    find_modes,
    render,
    wire_us,
)
from wftool.analysis.timing import Samples, TimingSeries, analyse  # noqa: E402

TASKS = """\
02 - (           GYRO)   3148       1       0    0.3%    0.0%         0      0 131767       0
04 - (            PID)   3148      39       0   12.2%    0.0%         0      0 131767       0
08 - (         SERIAL)   1000       1       0    0.1%    0.0%         0      0  41831       0
17 - (            FSP)   1049       1       0    0.1%    0.0%         0      0  43923       0
"""


def series(protocol: str, clock: str, deltas_us: list[float], expected_us: float) -> TimingSeries:
    times = np.concatenate([[0.0], np.cumsum(deltas_us)])
    n = times.size
    samples = Samples(
        protocol, clock, times, np.zeros(n, np.int64), np.zeros(n, np.int64),
        np.ones(n - 1, bool), expected_us,
    )  # fmt: skip
    return analyse(samples, protocol, protocol, expected_us)


def poll(imu_replies: int, duration_s: float = 10.0) -> PollResult:
    commands = {
        int(Cmd.RAW_IMU): CommandStats("RAW_IMU", 1000.0, 10000, imu_replies, 0, 0, imu_replies),
        int(Cmd.RC): CommandStats("RC", 100.0, 1000, 1000, 0, 0, 1000),
        int(Cmd.ATTITUDE): CommandStats("ATTITUDE", 100.0, 1000, 1000, 0, 0, 1000),
        int(Cmd.ANALOG): CommandStats("ANALOG", 10.0, 100, 100, 0, 0, 100),
    }
    return PollResult(duration_s, 4, 1, commands)


def report_input() -> ReportInput:
    fsp_deltas = [953.0] * 986 + [952.0] * 14  # micros() truncating 3 / 3148 s
    msp_deltas = [1000.0] * 700 + [3000.0] * 200 + [4000.0] * 60 + [200.0] * 40
    msp = series("MSP", "OBC reception time", msp_deltas, 1000.0)
    late = Lateness(20_000_000, 40_000, {100: 800, 250: 300, 500: 200, 1000: 100}, 9000)
    account = FcAccount(parse_tasks(TASKS), 318, 3144, TASKS)
    sweep = [MspRun(115200, series("MSP", "OBC reception time", [4000.0] * 50, 1000.0), poll(250))]
    return ReportInput(
        fc="the virtual FC (the paper's board)",
        fsp=series("FSP", "FC sample time", fsp_deltas, 3e6 / 3148),
        fsp_obc=None,
        msp=MspRun(921600, msp, poll(7800), late),
        sweep=sweep,
        account=account,
        setup=[("PID loop", "3148 Hz (`tasks`)", "3148 Hz (§5.1)")],
        figures=[("fig2-histograms.png", "Fig. 2: the sample intervals")],
    )


def table_line(text: str, section: str, metric: str) -> list[str]:
    """The cells of `metric`'s row in `section`'s table."""
    body = text.split(f"## {section}", 1)[1].split("\n## ", 1)[0]
    for line in body.splitlines():
        if line.startswith(f"| {metric} |"):
            return [cell.strip() for cell in line.strip("|").split("|")]
    raise AssertionError(f"no {metric} row in {section}")


def test_each_row_is_ours_beside_the_papers_with_the_difference_and_why() -> None:
    report = report_input()
    text = render(report)
    for section, protocol, one in (("MSP", "MSP", report.msp.series), ("FSP", "FSP", report.fsp)):
        stats = one.stats
        ours = {
            "expected": one.expected_us, "mean": stats.mean_us, "median": stats.p50_us,
            "1st percentile": stats.p1_us, "99th percentile": stats.p99_us,
            "P99−P1 spread": stats.spread_us,
        }  # fmt: skip
        for (metric, value), figure in zip(ours.items(), TABLE1[protocol].figures().values()):
            _, mine, theirs, difference, why = table_line(text, section, metric)
            assert float(mine) == pytest.approx(value / 1000, abs=5e-4)
            assert float(theirs) == pytest.approx(figure.value / 1000, abs=5e-4)
            assert float(difference) == pytest.approx(value - figure.value, abs=0.05)
            agrees = abs(value - figure.value) <= 0.5
            assert why.startswith("agrees:" if agrees else "differs by "), (metric, why)
            assert len(why) > 40  # a reason, not a bare verdict
        _, mine, theirs, difference, why = table_line(text, section, "mean rate (Hz)")
        assert float(theirs) == TABLE1[protocol].rate_hz.value
        assert float(difference.removesuffix(" Hz")) == pytest.approx(
            1e6 / stats.mean_us - TABLE1[protocol].rate_hz.value, abs=0.05
        )
    assert "| PID loop | 3148 Hz (`tasks`) | 3148 Hz (§5.1) |" in text
    assert f"{PAPER}, Table 1" in text
    assert "![Fig. 2: the sample intervals](fig2-histograms.png)" in text


def test_the_msp_rate_is_explained_from_the_fcs_serial_task_and_the_poll() -> None:
    text = render(report_input())
    why = table_line(text, "MSP", "mean rate (Hz)")[-1]
    # SERIAL 1000 Hz (`tasks`); RC, ATTITUDE, ANALOG answered 210 a second in the 10 s poll
    assert "SERIAL at 1000 Hz" in why and "took 210.0 of them" in why and "at most 790.0" in why
    p1 = table_line(text, "MSP", "1st percentile")[-1]
    # 921600 baud: a 24-byte reply takes 260 µs; 4 % of the intervals are 200 µs
    assert "260 µs on the wire at 921600 baud" in p1 and "4.0 % of intervals" in p1
    assert "0.50 % of its 40000 instants more than 0.5 ms late" in p1


def test_the_sweep_gives_each_baud_rates_wire_time_and_says_where_1khz_cannot_be_met() -> None:
    text = render(report_input())
    sweep = text.split("## MSP and the MSP port's baud rate", 1)[1]
    rows = {
        line.split("|")[1].strip(): line for line in sweep.splitlines() if re.match(r"\| \d", line)
    }
    assert set(rows) == {"115200", "921600 (this run's)"}
    assert f"| {wire_us(24, 115200):.0f} |" in rows["115200"]
    assert f"| {wire_us(24, 921600):.0f} |" in rows["921600 (this run's)"]
    assert "At 115200 baud a RAW_IMU reply alone takes 2083 µs" in sweep
    assert "At 921600" not in sweep


def test_modes_are_the_histograms_peaks_largest_first() -> None:
    rng = np.random.default_rng(1)
    deltas = np.concatenate(
        [rng.normal(1000, 10, 7000), rng.normal(3000, 10, 2000), rng.normal(4000, 10, 600),
         rng.uniform(0, 6000, 400)]
    )  # fmt: skip
    modes = find_modes(deltas)
    assert [round(centre, -2) for centre, _ in modes[:3]] == [1000, 3000, 4000]
    assert modes[0][1] > modes[1][1] > modes[2][1]
    assert all(share >= 0.005 for _, share in modes)
