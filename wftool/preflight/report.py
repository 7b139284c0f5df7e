"""The preflight report: what was checked (its header), one line per check — passed, failed
or not checked, never a line passed that was not checked — and the verdict that counts them.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field


class Outcome(enum.Enum):
    PASSED = "ok"
    FAILED = "FAIL"
    NOT_CHECKED = "not checked"


@dataclass(frozen=True)
class Line:
    """One check: what it is, what was measured, its limit, and how it came out."""

    name: str
    outcome: Outcome
    measured: str
    limit: str = ""
    value: float | None = None
    """The figure measured, in `unit` (None: none, or it never happened), for statistics
    over several runs (`scripts/failsafe_timing.py`)."""
    unit: str = ""
    clock: str = ""
    """Whose clock timed it: "FC clock" (the FC's own times, on the FSP stream), "host
    clock" (when MSP showed it: an upper bound), or empty for no time."""

    @property
    def passed(self) -> bool:
        return self.outcome is Outcome.PASSED


@dataclass
class Report:
    """Every line of one run, with what was checked (`subject`: the board or virtual FC,
    where its configuration came from, who flies)."""

    subject: list[str] = field(default_factory=list)
    lines: list[Line] = field(default_factory=list)
    lasting: list[Line] = field(default_factory=list)
    """Lines of what the run did to the board (arming it): `take_back` keeps them."""

    def add(self, line: Line) -> Line:
        self.lines.append(line)
        return line

    def check(
        self,
        name: str,
        ok: bool,
        measured: str,
        limit: str = "",
        *,
        value: float | None = None,
        unit: str = "",
        clock: str = "",
    ) -> Line:
        """A line that was checked: passed if `ok`."""
        outcome = Outcome.PASSED if ok else Outcome.FAILED
        return self.add(Line(name, outcome, measured, limit, value, unit, clock))

    def not_checked(self, name: str, why: str) -> Line:
        return self.add(Line(name, Outcome.NOT_CHECKED, why))

    def timing(self, name: str, ms: float | None, limit_ms: float, clock: str) -> Line:
        """A time that must not exceed `limit_ms` (None: what was waited for never came)."""
        measured = "never" if ms is None else f"{ms:.1f} ms"
        ok = ms is not None and math.isfinite(ms) and ms <= limit_ms
        return self.check(
            name, ok, measured, f"≤ {limit_ms:g} ms", value=ms, unit="ms", clock=clock
        )

    def take_back(self, since: int) -> None:
        """Drop the lines from index `since` on (a try that is no evidence), but the
        `lasting` ones: what they say the run did stays done, and is not said again."""
        self.lines[since:] = [
            line for line in self.lines[since:] if any(line is kept for kept in self.lasting)
        ]

    def extend(self, other: Report) -> None:
        self.lines += other.lines

    @property
    def failed(self) -> list[Line]:
        return [line for line in self.lines if line.outcome is Outcome.FAILED]

    @property
    def unchecked(self) -> list[Line]:
        return [line for line in self.lines if line.outcome is Outcome.NOT_CHECKED]

    @property
    def ok(self) -> bool:
        """No line failed (lines not checked are counted in the verdict, not passed)."""
        return not self.failed

    @property
    def verdict(self) -> str:
        """One line: how many lines passed, failed and were not checked, naming the last two."""
        passed = sum(line.passed for line in self.lines)
        parts = [f"{passed} of {len(self.lines)} lines passed"]
        if failed := self.failed:
            parts.append(f"{len(failed)} failed: " + "; ".join(line.name for line in failed))
        if unchecked := self.unchecked:
            names = "; ".join(line.name for line in unchecked)
            parts.append(f"{len(unchecked)} not checked: {names}")
        return ", ".join(parts)
