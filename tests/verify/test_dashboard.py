"""The dashboard as text, through rich's recording console (what a user's terminal shows)."""

from __future__ import annotations

from rich.console import Console

from tests.verify.test_monitor import feed_fc_uplink, feed_steady, feed_timed, feed_two_way
from wftool.fsp import CommandOutcome
from wftool.verify.criteria import Criteria, judge
from wftool.verify.dashboard import render
from wftool.verify.monitor import StreamMonitor


def screen(monitor: StreamMonitor) -> str:
    console = Console(record=True, width=120, color_system=None)
    summary = monitor.summary()
    console.print(render(summary, monitor.latest, judge(summary, Criteria())))
    return console.export_text()


def test_dashboard_shows_rates_intervals_values_and_verdict():
    monitor = StreamMonitor("socket://127.0.0.1:5762", expected_rate_hz=1049.3)
    monitor.connected(0.0)
    feed_steady(monitor, [i for i in range(1000) if i not in (500, 501)], 0.0)
    text = screen(monitor)
    assert "socket://127.0.0.1:5762 — connected" in text
    assert "1,996 frames" in text
    assert "1049.3" in text  # expected and FC-measured source rate
    fc_row = next(line for line in text.splitlines() if "FC sample" in line)
    # The interval across the lost packets is no FC interval: the mean is the FC's own.
    assert fc_row.split("│")[1].split()[2:7] == ["953.0", "953", "953", "953", "0"]
    assert "loss 4 frames (0.200 %)" in text
    assert "E1 on" in text
    assert "clock envelope acquiring" in text  # the envelope locks after 4 s of data
    assert "ppm" in text and "steps 0" in text
    assert "1500  1500  1500  1300  1000  2000" not in text  # blank frames carry zeros
    assert "0  0  0  0  0  0" in text
    assert "FAIL" in text and "✗ transport loss: 0.2 % (limit ≤ 0.1 %)" in text
    assert "✓ frame rate" in text


def test_dashboard_before_any_data():
    monitor = StreamMonitor("/dev/ttyTHS1")
    text = screen(monitor)
    assert "disconnected" in text and "no frame yet" in text
    assert "FAIL" in text and "✗ frames received: 0" in text


def test_dashboard_shows_two_way_timing_when_the_fc_answers():
    monitor = StreamMonitor("socket://127.0.0.1:5762", clock="twoway")
    feed_two_way(monitor, 8.0)
    text = screen(monitor)
    line = next(line for line in text.splitlines() if "two-way round trip" in line)
    trip = monitor.summary().round_trip
    assert f"P50 {trip.p50_us / 1e3:.3f} ms" in line and f"({trip.count:,})" in line
    assert "offset ± 0." in line and "d_min 0." in text
    plain = StreamMonitor("socket://127.0.0.1:5762")
    feed_two_way(plain, 3.0)
    assert "offset ± with --clock twoway" in screen(plain)
    assert "two-way" not in screen(StreamMonitor("/dev/ttyTHS1"))  # an FC that does not answer


def test_dashboard_shows_a_port_and_notes_as_text():
    monitor = StreamMonitor("socket://[/]x\x1b[2J:1")
    text = screen(monitor)
    assert "FSP socket://[/]x\\x1b[2J:1 — disconnected" in text
    assert "\x1b" not in text


def fc_uplink_lines(text: str) -> str:
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if "FC uplink" in line)
    return " ".join(" ".join(line.strip("│ ").split()) for line in lines[at : at + 2])


def test_dashboard_shows_what_the_fc_made_of_the_commands():
    monitor = StreamMonitor("socket://127.0.0.1:5762")
    feed_fc_uplink(monitor, 1200)  # commands timed out: the pilot has the sticks back
    shown = fc_uplink_lines(screen(monitor))
    assert shown == (
        "FC uplink accepted 500 stale 2 rejected 1 timeouts 1 (50 ms) on: override, armed "
        "failsafe IDLE"
    )
    lost = StreamMonitor("socket://127.0.0.1:5762")
    feed_fc_uplink(lost, 2100)  # and the pilot's radio lost
    assert "on: override, RX loss, armed failsafe RX_LOSS_DETECTED" in fc_uplink_lines(screen(lost))
    assert "FC uplink" not in screen(StreamMonitor("/dev/ttyTHS1"))  # no command, no status


def test_an_fc_uplink_status_that_stopped_coming_shows_its_age():
    monitor = StreamMonitor("socket://127.0.0.1:5762")
    feed_fc_uplink(monitor, 1200)
    read_at = monitor.summary().fc_uplink.status.arrival_time
    console = Console(record=True, width=120, color_system=None)
    console.print(render(monitor.summary(read_at + 3.0), None, None))
    assert "as of 3.0 s ago" in fc_uplink_lines(console.export_text())
    assert "s ago" not in fc_uplink_lines(screen(monitor))


def test_dashboard_shows_when_timed_commands_acted():
    monitor = StreamMonitor("socket://127.0.0.1:5762")
    monitor.connected(0.0)
    assert "timed" not in screen(monitor)
    on_time = [10] * 10 + [60] * 80 + [120] * 10
    feed_timed(monitor, [*on_time, 4000], [CommandOutcome.ON_TIME] * 100 + [CommandOutcome.LATE])
    text = screen(monitor)
    line = next(line for line in text.splitlines() if "timed 101 reports" in line)
    assert "P1 10 µs  P50 60 µs  P99 120 µs  (P99−P1 110 µs, 100 on time)" in line
    assert "late 1  refused 0  dropped 0  reports lost 0  latest 4.000 ms" in text


def test_dashboard_says_who_flies_as_the_fc_reports_it():
    """Firmware with spec §15: the authority and why the OBC last lost it; older firmware
    (36-byte statuses, above) shows no such line."""
    from tests.fsp.test_decoder import authority_status, packet_at
    from wftool.fsp import AuthorityExit

    monitor = StreamMonitor("socket://127.0.0.1:5762")
    monitor.connected(0.0)
    wire = packet_at(0, 1_000_000) + authority_status(1_003_000, 1_001_000, AuthorityExit.TIMEOUT)
    monitor.feed(wire, 0.01)
    text = screen(monitor)
    assert "who flies: proving (last exit: timeout)" in " ".join(text.split())
    feed_fc_uplink(older := StreamMonitor("socket://127.0.0.1:5762"), 1200)
    assert "who flies" not in screen(older)
