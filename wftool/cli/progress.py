"""Rich progress bars for the API's progress callbacks: the API reports, the CLI draws."""

from __future__ import annotations

from types import TracebackType

from rich.console import Console
from rich.progress import (
    BarColumn,
    DownloadColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
    TransferSpeedColumn,
)

LABEL = TextColumn("{task.description}")
UNITS = (LABEL, BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
"""Counted work (make's compile units)."""
BYTES = (LABEL, BarColumn(), DownloadColumn(), TransferSpeedColumn(), TimeRemainingColumn())
"""A download."""
PERCENT = (LABEL, BarColumn(), TextColumn("{task.percentage:>3.0f}%"))
"""Work reported in percent (dfu-util)."""


class ProgressBars:
    """Bars drawn from (phase, done, total) reports; nothing is drawn before the first.

    One bar whose label follows the phase (make: compile, link, done), or with `per_phase`
    a bar per phase, and a new one when a phase's count goes back (dfu-util erases and
    writes region by region). Use as a context manager, or call `close()`.
    """

    def __init__(
        self, console: Console, columns: tuple[ProgressColumn, ...], *, per_phase: bool = False
    ) -> None:
        self._console = console
        self._columns = columns
        self._per_phase = per_phase
        self._bars: Progress | None = None
        self._tasks: dict[str, TaskID] = {}

    def __call__(self, phase: str, done: int, total: int | None) -> None:
        if self._bars is None:
            self._bars = Progress(*self._columns, console=self._console)
            self._bars.start()
        key = phase if self._per_phase else ""
        task = self._tasks.get(key)
        if task is None or (self._per_phase and self._bars.tasks[task].completed > done):
            task = self._tasks[key] = self._bars.add_task(phase, total=total)
        self._bars.update(task, description=phase, completed=done, total=total)

    def close(self) -> None:
        if self._bars is not None:
            self._bars.stop()
            self._bars = None

    def __enter__(self) -> ProgressBars:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()
