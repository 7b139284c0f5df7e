"""The virtual FC's true clock read from a SITL log (`wftool.sitl.truth`): anchors, epochs,
wraps. The log lines are the exact format patch 0002 prints; the SITL itself is used in
tests/bench/test_latency.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from wftool.errors import SitlError
from wftool.sitl.truth import TrueClock, lateness_between, read_anchors, read_lateness

U32 = 1 << 32


def anchor(fc_us: int, monotonic_ns: int, reason: str = "start", step_us: str = "125.000") -> str:
    return (
        f"[SITL] lockstep anchor: fc_us={fc_us} monotonic_ns={monotonic_ns} step_us={step_us} "
        f"reason={reason}\n"
    )


def write(path: Path, *lines: str) -> Path:
    with path.open("a") as log:
        log.writelines(lines)
    return path


def test_maps_fc_time_through_the_latest_anchor_before_it(tmp_path: Path) -> None:
    log = write(
        tmp_path / "sitl.log",
        "bind port 5761 for UART1\n",
        anchor(500_000, 10_000_000_000),
        "[NEW]UART1: 1,1\n",
        anchor(3_000_000, 12_600_000_000, "host-lag", "317.662"),  # the host fell 100 ms behind
    )
    clock = TrueClock(log)
    assert [a.reason for a in clock.anchors] == ["start", "host-lag"]
    assert [a.step_us for a in clock.anchors] == [125.0, 317.662]  # a gyro clock of its own
    assert clock.monotonic(500_000) == pytest.approx(10.0, abs=1e-12)
    assert clock.monotonic(2_999_875) == pytest.approx(12.499875, abs=1e-12)
    assert clock.monotonic(3_000_000) == pytest.approx(12.6, abs=1e-12)
    assert clock.monotonic(4_000_000) == pytest.approx(13.6, abs=1e-12)


def test_a_line_being_written_waits_and_refresh_picks_up_new_anchors(tmp_path: Path) -> None:
    log = write(tmp_path / "sitl.log", anchor(500_000, 10_000_000_000))
    half = anchor(2_000_000, 11_600_000_000, "host-lag")
    write(log, half[:30])
    clock = TrueClock(log)
    assert len(clock.anchors) == 1
    write(log, half[30:])
    clock.refresh()
    assert clock.monotonic(2_000_000) == pytest.approx(11.6, abs=1e-12)


def test_a_restarted_sitl_is_a_new_clock(tmp_path: Path) -> None:
    log = write(tmp_path / "sitl.log", anchor(500_000, 10_000_000_000))
    clock = TrueClock(log)
    write(log, anchor(400_000, 50_000_000_000), anchor(900_000, 50_600_000_000, "host-lag"))
    clock.refresh()
    assert clock.restarted and len(clock.anchors) == 1  # the old process's anchors stay final
    assert clock.monotonic(900_000) == pytest.approx(10.4, abs=1e-12)
    fresh = TrueClock(log)  # the latest process: its start and what followed
    assert [a.fc_us for a in fresh.anchors] == [400_000, 900_000]


def test_u32_times_are_lifted_to_the_sitls_micros64(tmp_path: Path) -> None:
    """After 71.6 min the decoder's times (unwrapped from the first raw reading) and raw
    `micros()` differ from micros64 by whole wraps: lifting finds the right one."""
    start = U32 + 5_000_000  # this SITL has run 72 minutes
    log = write(tmp_path / "sitl.log", anchor(start, 4_000_000_000_000))
    clock = TrueClock(log)
    now = 4_000.0 + 10.0  # host time: FC time is start + 10 s
    sample = start + 9_000_000
    assert clock.micros64(sample % U32, now) == sample
    assert clock.micros64(sample - U32, now) == sample
    assert clock.instant(sample % U32, now) == pytest.approx(4_009.0, abs=1e-9)
    assert clock.micros64((start - 1000) % U32, now) == start - 1000  # before the anchor


def test_read_anchors_resumes_at_an_offset(tmp_path: Path) -> None:
    log = write(tmp_path / "sitl.log", anchor(1, 1000))
    first, offset = read_anchors(log)
    write(log, anchor(2, 2000, "host-lag"))
    second, _ = read_anchors(log, offset)
    assert [a.fc_us for a in first] == [1] and [a.fc_us for a in second] == [2]


def test_a_log_without_anchors_is_a_clear_error(tmp_path: Path) -> None:
    log = write(tmp_path / "sitl.log", "bind port 5761 for UART1\n")
    with pytest.raises(SitlError, match="no lockstep anchor"):
        TrueClock(log)
    with pytest.raises(SitlError, match="cannot read"):
        TrueClock(tmp_path / "missing.log")


def lateness(fc_us: int, waits: int, over: tuple[int, int, int, int], max_us: int) -> str:
    counts = " ".join(f"over_{b}us={n}" for b, n in zip((100, 250, 500, 1000), over, strict=True))
    return f"[SITL] lockstep lateness: fc_us={fc_us} waits={waits} {counts} max_us={max_us}\n"


def test_lateness_totals_of_the_latest_process_and_their_differences(tmp_path: Path) -> None:
    log = write(
        tmp_path / "sitl.log",
        lateness(500_000, 1, (0, 0, 0, 0), 20),
        lateness(10_500_000, 50_000, (900, 300, 100, 40), 4000),
        "[system]Reset!\n",  # a new process: its totals start again
        lateness(480_000, 1, (0, 0, 0, 0), 12),
        lateness(10_480_000, 40_000, (100, 20, 5, 1), 1100),
        lateness(20_480_000, 90_000, (300, 50, 15, 2), 1300),
    )
    totals = read_lateness(log)
    assert [t.fc_us for t in totals] == [480_000, 10_480_000, 20_480_000]
    window = totals[2].since(totals[1])
    assert (window.waits, window.over_us, window.max_us) == (
        50_000,
        {100: 200, 250: 30, 500: 10, 1000: 1},
        1300,
    )


def test_lateness_between_two_host_instants(tmp_path: Path) -> None:
    """Totals logged every 10 s of FC time, told apart over the lines within the window."""
    log = write(
        tmp_path / "sitl.log",
        anchor(500_000, 10_000_000_000),  # FC time 0.5 s is host 10 s
        lateness(500_000, 1, (0, 0, 0, 0), 20),
        lateness(10_500_000, 50_000, (900, 300, 100, 40), 4000),
        lateness(20_500_000, 90_000, (1000, 320, 110, 41), 4000),
        lateness(30_500_000, 140_000, (1500, 400, 150, 60), 6000),
    )
    window = lateness_between(log, 19.0, 31.0)  # host 20 s and 30 s: FC 10.5 s and 20.5 s
    assert window is not None
    assert (window.waits, window.over_us[500], window.over_us[1000]) == (40_000, 10, 1)
    assert lateness_between(log, 19.0, 25.0) is None  # one line within: nothing to tell apart
