"""StreamMonitor and the verdict, fed with real encoded streams and explicit arrival times."""

from __future__ import annotations

import json

import pytest

from tests.fsp.test_decoder import frame, stream
from tests.fsp.test_twoway import RC, Link
from wftool.fsp import CommandOutcome, CommandPacket, CommandReport, StatePacket, UplinkFlag
from wftool.fsp.encoder import encode_command_report, encode_state
from wftool.verify.criteria import Criteria, judge
from wftool.verify.monitor import HealthSampler, IntervalHistogram, StreamMonitor
from wftool.verify.uplink import UplinkTracker, pattern_command

PACKET_S = 2 * 953e-6


def feed_steady(monitor: StreamMonitor, indices, t0: float, chunk: int = 10) -> float:
    """Feed packets `indices` in reads of `chunk` packets, arriving in real time."""
    indices = list(indices)
    t = t0
    for start in range(0, len(indices), chunk):
        part = indices[start : start + chunk]
        t = t0 + (part[-1] + 1) * PACKET_S
        monitor.feed(stream(part, e1=True), t)
    return t


def test_histogram_percentiles():
    histogram = IntervalHistogram()
    for value in range(1, 101):
        histogram.add(value)
    summary = histogram.summary()
    assert (summary.p1_us, summary.p50_us, summary.p99_us) == (1, 50, 99)  # nearest rank
    assert summary.mean_us == 50.5
    assert summary.spread_us == 98


def test_steady_stream_passes():
    monitor = StreamMonitor("test")
    monitor.connected(0.0)
    t = feed_steady(monitor, range(1000), 0.0)
    monitor.disconnected(t)
    summary = monitor.summary()
    assert summary.frames == 2000
    assert summary.frame_rate_hz == pytest.approx(1e6 / 953, rel=0.01)
    assert summary.source_rate_hz == pytest.approx(1e6 / 953)
    assert summary.fc_interval.spread_us == 0
    assert summary.e1 is True and summary.clock is not None
    verdict = judge(summary, Criteria())
    assert verdict.passed, verdict


def test_loss_and_rejections_fail_the_verdict():
    monitor = StreamMonitor("test", expected_rate_hz=1e6 / 953)
    monitor.connected(0.0)
    t = feed_steady(monitor, [i for i in range(1000) if i % 100 != 5], 0.0)
    monitor.feed(b"\x02\x07\x00", t)  # a chunk that is no packet, after sync: an error
    summary = monitor.summary()
    assert summary.lost_frames == 20 and summary.errors == 1
    failed = {c.name for c in judge(summary, Criteria()).checks if not c.passed}
    assert failed == {"transport loss", "rejected chunks"}
    assert judge(summary, Criteria(max_loss_pct=2.0, max_errors=1)).passed


def test_joining_mid_stream_is_not_an_error():
    monitor = StreamMonitor("test")
    monitor.connected(0.0)
    wire = stream(range(50), e1=True)
    monitor.feed(wire[37:], 0.1)  # starts inside packet 0
    summary = monitor.summary()
    assert (summary.errors, summary.sync_rejected, summary.packets) == (0, 1, 49)


def test_reconnect_is_counted_and_totals_survive_it():
    monitor = StreamMonitor("test")
    monitor.connected(0.0)
    t = feed_steady(monitor, range(100), 0.0)
    monitor.disconnected(t)
    monitor.connected(t + 1.0)
    t2 = feed_steady(monitor, range(100), t + 1.0)
    summary = monitor.summary(t2)
    assert summary.reconnects == 1 and summary.connected
    assert summary.frames == 400
    assert summary.connected_s == pytest.approx(t2 - 1.0, abs=1e-9)


def test_rate_below_expectation_fails():
    monitor = StreamMonitor("test", expected_rate_hz=2000.0)
    monitor.connected(0.0)
    monitor.disconnected(feed_steady(monitor, range(500), 0.0))
    verdict = judge(monitor.summary(), Criteria())
    assert [c.name for c in verdict.checks if not c.passed] == ["frame rate"]


def test_uplink_echo_is_matched_with_round_trip_time():
    """The FC echoes each command's roll 15 ms later; the tracker must see exactly that."""
    tracker = UplinkTracker()
    monitor = StreamMonitor("test", uplink=tracker)
    monitor.connected(0.0)
    rate = 50.0
    echo_roll = 1500
    sent = []
    for i in range(100):
        t = i / rate
        rc = pattern_command(i, rate)
        monitor.command_sent(rc, t)
        sent.append((t, rc[0]))
        while sent and sent[0][0] <= t - 0.015:
            echo_roll = sent.pop(0)[1]
        rc_frame = (echo_roll, 1500, 1500, 1000, 1000, 1000)
        base = 1_000_000 + i * 20_000  # a frame every 10 ms, a packet every 20 ms
        packet = StatePacket(
            base + 10_500, (frame(base, rc=rc_frame), frame(base + 10_000, rc=rc_frame)), i, True
        )
        monitor.feed(encode_state(packet), t + 0.0001)
    uplink = monitor.summary().uplink
    assert uplink.commands_sent == 100
    assert uplink.steps_echoed >= uplink.steps_sent - 1
    assert uplink.rtt_p50_ms == pytest.approx(20.1, abs=0.5)  # 15 ms echo, seen on the next packet
    checks = judge(monitor.summary(), Criteria(uplink=True)).checks
    assert [c.passed for c in checks if c.name == "uplink echoed"] == [True]


def test_uplink_echo_is_judged_only_while_the_obc_steers():
    """Under a safety pilot the FC echoes the OBC's commands only once the pilot engaged it
    (spec §15): the steps sent before the FC said so are no steps of the echo's."""
    from wftool.fsp import Authority, AuthorityExit, UplinkFlag, UplinkStatus, encode_uplink_status

    def status(t_us: int, authority: Authority) -> bytes:
        return encode_uplink_status(
            UplinkStatus(
                1, t_us, 1, 0, 0, 0, 50, UplinkFlag.LIVE, 0, 0, authority, AuthorityExit.NONE, 500,
                0, 7, 0, 0, 0, 885, 2115,
            )
        )  # fmt: skip

    monitor = StreamMonitor("test", uplink=UplinkTracker())
    monitor.connected(0.0)
    rate, echo_roll, engaged_at = 50.0, 1500, 60
    for i in range(120):
        t = i / rate
        base = 1_000_000 + i * 20_000
        authority = Authority.ENGAGED if i >= engaged_at else Authority.PROVING
        rc = pattern_command(i, rate)
        monitor.command_sent(rc, t)
        if i > engaged_at:  # the FC flies the OBC's commands once engaged (a period late)
            echo_roll = pattern_command(i - 1, rate)[0]
        rc_frame = (echo_roll, 1500, 1500, 1000, 1000, 1000)
        frames = (frame(base, rc=rc_frame), frame(base + 10_000, rc=rc_frame))
        packet = StatePacket(base + 10_500, frames, i, True)
        monitor.feed(encode_state(packet) + status(base + 10_600, authority), t + 0.0001)
    uplink = monitor.summary().uplink
    assert uplink.commands_sent == 120
    # the first command, before any status (an FC without E3 is judged as ever), then from
    # the 62nd on (61 to 119, the status of the engagement read after the 61st): 12 steps
    assert uplink.steps_sent == 1 + 12
    assert uplink.steps_echoed == 12
    checks = judge(monitor.summary(), Criteria(uplink=True)).checks
    assert [c.passed for c in checks if c.name == "uplink echoed"] == [True]


def feed_two_way(monitor: StreamMonitor, seconds: float, record=None) -> int:
    """A simulated link whose FC answers every command (tests/fsp/test_twoway.py), fed as the
    live loop does; `record(kind, t, payload)` sees every event. The number of commands."""
    link = Link(seed=11)
    monitor.connected(0.0)
    commands = 0
    for t, _, kind, payload in link.build(seconds):
        if kind == "send":
            command = CommandPacket(RC, payload, int(t * 1e6) % (1 << 32))
            monitor.command_sent(RC, t, command)
            commands += 1
        else:
            monitor.feed(payload, t)
        if record is not None:
            record(kind, t, payload)
    return commands


def test_time_replies_show_round_trips_and_the_offset_uncertainty():
    monitor = StreamMonitor("test", clock="twoway")
    commands = feed_two_way(monitor, 12.0)
    summary = monitor.summary()
    assert summary.errors == 0  # the replies are decoded, not rejected
    trip = summary.round_trip
    assert trip is not None and trip.count == commands
    assert 800 < trip.p50_us < 2500  # 0.4 ms + jitter each way, the FC's task wait on the uplink
    two_way = summary.two_way
    assert two_way is not None and two_way.active
    assert 0 < two_way.uncertainty_s < trip.p50_us * 1e-6
    assert summary.clock.uncertainty_s == two_way.uncertainty_s
    assert json.loads(json.dumps(summary.as_json()))["two_way"]["active"] is True
    # the envelope alone shows the round trips, but has no offset from them
    plain = StreamMonitor("test")
    feed_two_way(plain, 3.0)
    assert plain.summary().round_trip is not None and plain.summary().two_way is None


def feed_fc_uplink(monitor: StreamMonitor, packets: int, t0: float = 5000.0) -> list:
    """A piloted FC's stream with its uplink statuses (`flight(statuses=True)`: timed out
    from packet 1000 on, RX loss from 2000 on), fed as the live loop does; every health
    snapshot taken, in order."""
    from tests.recording.test_rosbag import READ_S, flight

    sampler = HealthSampler(monitor)
    monitor.connected(t0)
    t, snapshots = t0, []
    for data in flight(packets, statuses=True):
        t += READ_S
        health = sampler.sample(monitor.feed(data, t), t)
        if health is not None and (not snapshots or health is not snapshots[-1]):
            snapshots.append(health)
    return snapshots


def test_the_fcs_uplink_status_is_in_the_summary_its_json_and_the_health():
    from tests.recording.test_rosbag import READ_S

    monitor = StreamMonitor("test")
    snapshots = feed_fc_uplink(monitor, 1200)
    summary = monitor.summary()
    status = summary.fc_uplink.status
    assert status == monitor.decoder.uplink_status  # the newest
    assert status.has(UplinkFlag.OVERRIDE) and not status.has(UplinkFlag.LIVE)
    assert summary.fc_uplink_age_s == pytest.approx(0.0, abs=0.1)
    # its FC times on the OBC clock: when the read that brought it came, within a read
    sent_t = summary.fc_uplink.t
    assert sent_t == pytest.approx(status.arrival_time, abs=READ_S)
    waited_s = (status.tx_time_us - status.timed_out_us) % 2**32 * 1e-6
    assert summary.fc_uplink.timed_out_t == pytest.approx(sent_t - waited_s, abs=1e-5)
    data = json.loads(json.dumps(summary.as_json()))["fc_uplink"]
    assert data == data | {
        "accepted": 500, "stale": 2, "rejected": 1, "timeouts": 1, "timeout_ms": 50,
        "live": False, "override": True, "obc_receiver": False, "rx_loss": False,
        "armed": True, "failsafe_phase": "IDLE", "fc_time_us": status.sent_us,
        "timed_out_fc_time_us": status.timed_out_at_us,
    }  # fmt: skip
    assert snapshots[-1].uplink is not None and snapshots[-1].uplink.status.accepted == 500
    # the change at packet 1000 went to the sinks in the read that brought it
    first_timed_out = next(h for h in snapshots if h.uplink and h.uplink.status.timeouts)
    before = snapshots[snapshots.index(first_timed_out) - 1]
    assert 0 < first_timed_out.t - before.t < 0.1
    assert first_timed_out.t == first_timed_out.uplink.status.arrival_time
    # counters alone wait for the period: no more snapshots than 10 Hz and the 2 changes
    span_s = snapshots[-1].t - snapshots[0].t
    assert len(snapshots) <= span_s * 10 + 3


def test_no_uplink_status_before_the_fc_sends_one():
    monitor = StreamMonitor("test")
    monitor.connected(0.0)
    feed_steady(monitor, range(200), 0.0)
    summary = monitor.summary()
    assert summary.fc_uplink is None and summary.fc_uplink_age_s is None
    assert summary.as_json()["fc_uplink"] is None
    assert summary.health(None, 1.0).uplink is None


def feed_timed(monitor: StreamMonitor, delays_us: list[int], outcomes: list[int]) -> None:
    """A stream with one command report after each state packet: the FC applied a timed
    command `delay` µs after the time it asked for (`outcome` per report)."""
    counts = [0] * len(CommandOutcome)
    t = 0.0
    for index, (delay, outcome) in enumerate(zip(delays_us, outcomes, strict=True)):
        t = (index + 1) * PACKET_S
        counts[outcome] += 1
        tx_us = 1_000_000 + 2 * index * 953 + 953 + 100
        at_us = tx_us - 500
        report = CommandReport(
            index,
            0,
            at_us,
            at_us + delay,
            outcome,
            0,
            tuple(counts),  # type: ignore[arg-type]
        )
        monitor.feed(stream([index], e1=True) + encode_command_report(report), t)


def test_the_fc_reports_on_timed_commands_are_summed_up():
    monitor = StreamMonitor("socket://127.0.0.1:5762")
    monitor.connected(0.0)
    assert monitor.summary().timed is None  # no timed commands, no figures
    delays = [(17 * k) % 125 for k in range(200)] + [3000, 0, 0]
    outcomes = [CommandOutcome.ON_TIME] * 200 + [
        CommandOutcome.LATE, CommandOutcome.TOO_FAR, CommandOutcome.SUPERSEDED,
    ]  # fmt: skip
    feed_timed(monitor, delays, outcomes)
    timed = monitor.summary().timed
    assert timed is not None
    assert (timed.reports, timed.late, timed.refused, timed.dropped) == (203, 1, 1, 1)
    assert timed.apply is not None and timed.apply.count == 200
    assert timed.apply.p1_us == 0 and 120 <= timed.apply.p99_us < 125  # the late one apart
    assert timed.latest_us == 3000 and timed.lost_reports == 0
    data = json.loads(json.dumps(monitor.summary().as_json()))
    assert data["timed"]["apply"]["spread_us"] == timed.apply.spread_us
    assert data["timed"]["outcomes"]["ON_TIME"] == 200
    assert judge(monitor.summary(), Criteria()).passed  # reported, never judged
