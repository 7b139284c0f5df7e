"""The CLI's `tasks` and `status` as Betaflight 2025.12 prints them (cli.c), parsed."""

from __future__ import annotations

from wftool.fc.tasks import parse_status, parse_tasks

# The patched SITL (USE_LATE_TASK_STATISTICS: late, run and reqd columns)
LATE_STATS = """\
Task list             rate/hz  max/us  avg/us maxload avgload  total/ms   late    run reqd/us
00 - (         SYSTEM)     10       0       0    0.0%    0.0%         0      0    108       0
01 - (         SYSTEM)    998       0       0    0.0%    0.0%         0      0  10774       0
02 - (           GYRO)   3149       1       0    0.3%    0.0%         0      0  33937       0
04 - (            PID)   3149      25       0    7.8%    0.0%         0      0  33937       0
08 - (         SERIAL)   2000       0       0    0.0%    0.0%         0      0  21537       0
17 - (            FSP)   1049       0       0    0.0%    0.0%         0      0  11313       0
RX Check Function                   0       0                         0
Total (excluding SERIAL)                                 0.0%
"""
# A board's build (no late-task statistics)
BOARD = """\
Task list             rate/hz  max/us  avg/us maxload avgload  total/ms
00 - (         SYSTEM)     10       2       1    0.0%    0.0%         0
01 - (         SYSTEM)    996       5       2    0.4%    0.2%       312
02 - (           GYRO)   3148      28      17    8.8%    5.3%      6120
08 - (         SERIAL)    994      61       9    6.0%    0.8%       951
"""


def test_rows_by_task_with_run_counts_where_the_build_counts_them() -> None:
    rows = parse_tasks(LATE_STATS)
    assert list(rows) == ["SYSTEM/LOAD", "SYSTEM/UPDATE", "GYRO", "PID", "SERIAL", "FSP"]
    assert (rows["PID"].rate_hz, rows["PID"].runs) == (3149, 33937)
    assert rows["SYSTEM/LOAD"].runs == 108
    board = parse_tasks(BOARD)
    assert (board["GYRO"].rate_hz, board["GYRO"].runs) == (3148, None)
    assert board["SERIAL"].rate_hz == 994


def test_status_gives_the_cycle_time_and_gyro_rate() -> None:
    line = "CPU:0%, cycle time: 317, GYRO rate: 3154, RX rate: 0, System rate: 10"
    assert parse_status(f"System Uptime: 11 seconds\n{line}\n") == (317, 3154)
    assert parse_status("no status here") is None
