"""`bench command` on the virtual FC: immediate against timed commands, judged by its true clock.

Behaviour, not timing: every timed command sent gets the FC's report, the FC applies an
on-time command at the first PID iteration at or after its time (never before, never a
period after), and what the FC says it applied is what its frames then carry; none is sent
without a locked clock.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import run_cli
from wftool.bench.command import IMMEDIATE, TIMED, run_command_bench

TIMEOUT_US = 50_000
"""The FC's fsp_cmd_timeout_ms (the default)."""


def test_timed_commands_act_at_the_pid_iteration_of_their_time(sitl_binary: Path) -> None:
    result = run_command_bench(sitl_binary, seconds=3.0, rates_hz=(100.0,))
    assert result.pid_period_us == pytest.approx(125, abs=2)
    rows = {row.mode: row for row in result.rows}
    assert set(rows) == {IMMEDIATE, TIMED}
    timed, immediate = rows[TIMED], rows[IMMEDIATE]
    assert immediate.sent == 300
    # A timed command goes out only while the OBC's clock is locked (else ClockError). A host
    # that falls 50 ms behind the virtual FC makes its lockstep clock re-anchor: a step of
    # the FC clock, which the OBC's clock learns anew. Then, and only then, commands are not
    # sent, and then placed by the one-way line until the round trips agree again (how many
    # is a figure of `wftool bench command`, as is the re-anchor); else by the two-way clock.
    assert timed.sent + timed.unlocked == 300
    assert timed.unlocked == 0 or result.reanchors > 0, (timed.unlocked, result.lateness)
    assert timed.one_way == 0 or result.reanchors > 0, (timed.one_way, result.lateness)
    assert 0 < result.clock_uncertainty_us < 1000
    # Every timed command the FC took fresh is reported on (none lost, by its counts); one
    # it did not (the first after a gap over the command timeout, by its clock) it counted
    # stale (E3).
    assert result.lost_reports == 0 and timed.unreported <= result.stale
    assert timed.applied + timed.refused + timed.superseded == timed.sent - timed.unreported
    # 5 ms ahead: well inside the command timeout and the queue; none refused but those the
    # bench sent after a stall of its loop, a command timeout after their time or more
    # (expired, spec §13), by the FC's account; and, after a re-anchor (above), those the
    # OBC's clock placed across the FC clock's step before it had seen it (too far ahead, by
    # the true clock: misplaced)
    assert timed.refused == timed.expired + timed.misplaced
    assert timed.misplaced == 0 or result.reanchors > 0, (timed.misplaced, result.lateness)
    assert timed.expired_after_us is None or timed.expired_after_us >= TIMEOUT_US
    own = timed.asked
    assert own is not None and own.count == timed.applied - timed.late
    assert own.p1_us >= 0 and own.max_us < result.pid_period_us  # the FC's rule, exactly
    assert timed.apply is not None and timed.seen is not None
    # each applied command shows in the stream, at or after its application
    assert timed.seen.count >= 0.95 * timed.applied and timed.seen.p1_us >= timed.apply.p1_us
    # The FC's books (E3) count every command sent, fresh or stale. It answers the newest
    # fresh command of an FSP task run only (spec §10): each immediate one it applied has a
    # time reply, and one without never shows in its frames (superseded: a loaded host's
    # virtual FC read several in one run; or stale, the first after a gap over 50 ms).
    assert result.accepted + result.stale == result.packets
    assert immediate.applied + immediate.superseded == immediate.sent, immediate


def test_bench_command_prints_both_rows_and_the_note(
    capsys: pytest.CaptureFixture[str], sitl_binary: Path
) -> None:
    code, out, err = run_cli(
        capsys, "bench", "command", "--seconds", "2", "--rates", "100", "--binary",
        str(sitl_binary),
    )  # fmt: skip
    assert (code, err) == (0, "")
    assert "bench command: 2 s per row on the virtual FC (PID loop 8000 Hz" in out
    assert any(line.startswith("immediate  100") for line in out.splitlines()), out
    assert any(line.startswith("timed      100        5") for line in out.splitlines()), out
    assert "P99−P1 of the apply time, µs: 100 Hz: immediate " in out
    assert "Goal, timed ≤ one PID period (125 µs): by the FC's clock " in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--rates", "100,fast"), "expected numbers like 100,500: '100,fast'"),
        (("--rates", "0"), "command rates must be above 0 and at most 1000 Hz: '0'"),
        (("--lead-ms", "50"), "--lead-ms must be a number from 0 to 40 ms, not 50"),
    ],
)
def test_bench_command_bad_options_are_one_line(
    capsys: pytest.CaptureFixture[str], args: tuple[str, ...], message: str
) -> None:
    code, _, err = run_cli(capsys, "bench", "command", *args, "--binary", __file__)
    assert code == 2 and message in err and "Traceback" not in err
