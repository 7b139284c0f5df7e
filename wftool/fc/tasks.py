"""Betaflight's own account of what it ran: the CLI's `tasks` table and `status` line, parsed.

    rows = parse_tasks(session.run("tasks"))
    rows["PID"].rate_hz, rows["SERIAL"].runs

`rate/hz` is the scheduler's moving average over its last runs; builds with
USE_LATE_TASK_STATISTICS (the SITL's) add `late` and `run` columns, counts since the previous
`tasks`. The two SYSTEM rows are named SYSTEM/LOAD and SYSTEM/UPDATE, as in `tasks.c`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_ROW = re.compile(r"^\d+ - \(\s*([\w/]+)\)\s+(\d+)((?:\s+-?[\d.]+%?)*)\s*$")
_STATUS = re.compile(r"cycle time: (\d+), GYRO rate: (\d+)")


@dataclass(frozen=True)
class TaskRow:
    """One task as `tasks` shows it."""

    name: str
    rate_hz: int
    runs: int | None
    """Runs since the previous `tasks` (None where the build does not count them)."""


def parse_tasks(output: str) -> dict[str, TaskRow]:
    """The rows of a `tasks` table by task name."""
    rows: dict[str, TaskRow] = {}
    for line in output.splitlines():
        match = _ROW.match(line.strip())
        if match is None:
            continue
        name, rate, rest = match.group(1), int(match.group(2)), match.group(3).split()
        if name == "SYSTEM":
            name = "SYSTEM/UPDATE" if "SYSTEM/LOAD" in rows else "SYSTEM/LOAD"
        runs = int(rest[6]) if len(rest) >= 8 else None  # max avg maxload avgload total late run
        rows[name] = TaskRow(name, rate, runs)
    return rows


def parse_status(output: str) -> tuple[int, int] | None:
    """`status`'s (cycle time µs, GYRO rate Hz): the latest PID period and its inverse."""
    match = _STATUS.search(output)
    return (int(match.group(1)), int(match.group(2))) if match else None
