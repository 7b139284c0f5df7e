"""The report: three states a line can be in, a verdict that counts and names the failed and
the unchecked, and a time that is no number never passes."""

from __future__ import annotations

import math

from wftool.preflight.report import Outcome, Report


def test_a_line_not_checked_is_neither_passed_nor_failed() -> None:
    report = Report()
    report.check("a", True, "yes")
    line = report.not_checked("stage 2", "needs --arm")
    assert line.outcome is Outcome.NOT_CHECKED and not line.passed
    assert report.ok and report.unchecked == [line] and report.failed == []
    assert report.verdict == "1 of 2 lines passed, 1 not checked: stage 2"


def test_the_verdict_names_every_failed_and_unchecked_line() -> None:
    report = Report()
    report.timing("sticks back", 60.0, 100.0, "FC clock")
    report.timing("never came", None, 100.0, "FC clock")
    report.timing("too late", 101.0, 100.0, "host clock: MSP")
    report.not_checked("radio lost", "this pilot cannot")
    assert not report.ok
    assert [(line.name, line.measured) for line in report.failed] == [
        ("never came", "never"),
        ("too late", "101.0 ms"),
    ]
    assert report.verdict == (
        "1 of 4 lines passed, 2 failed: never came; too late, 1 not checked: radio lost"
    )


def test_a_time_that_is_no_number_fails() -> None:
    report = Report()
    assert not report.timing("nan", math.nan, 100.0, "FC clock").passed
    assert not report.timing("inf", math.inf, math.inf, "FC clock").passed
    line = report.timing("ok", 100.0, 100.0, "FC clock")
    assert line.passed and line.value == 100.0 and line.unit == "ms" and line.clock == "FC clock"
