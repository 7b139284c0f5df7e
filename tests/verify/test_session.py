"""The verify API over a real TCP connection: a run, its verdict, its recording replayed;
faults on the line from a stand-in FC (`fake_fc`): outages, damage, loss."""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from cobs import cobs

from tests.conftest import run_cli
from tests.fsp.test_decoder import PERIOD, packet_at, stream
from tests.verify.fake_fc import FRAME_RATE_HZ, PACKET_S, FakeFc, intact
from tests.waits import wait_for
from wftool.errors import UsageError, VerificationFailed
from wftool.fsp.framing import encode_frame
from wftool.verify.criteria import RATE_UNCHECKED, Criteria, judge
from wftool.verify.session import VerifySession, criteria_for, replay

NEVER_S = 30.0
"""Only bounds "never": a run that waits for what the fake FC did."""


@pytest.fixture
def fc_stream() -> Iterator[tuple[str, list[int]]]:
    """A TCP server that streams 600 packets, packet 100 missing, then holds the line until
    the reader hangs up."""
    listener = socket.create_server(("127.0.0.1", 0))
    sent = [i for i in range(600) if i != 100]
    wire = stream(sent, e1=True)

    def serve() -> None:
        conn, _ = listener.accept()
        with conn:
            time.sleep(0.2)  # pyserial flushes input on open: talk once it is up
            for start in range(0, len(wire), 2000):
                conn.sendall(wire[start : start + 2000])
                time.sleep(0.005)
            conn.settimeout(30.0)
            with contextlib.suppress(OSError):
                conn.recv(1)  # hold the line until the reader hangs up

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield f"socket://127.0.0.1:{listener.getsockname()[1]}", sent
    thread.join(5)
    listener.close()


def test_run_judges_what_it_saw_and_the_recording_replays_it(fc_stream, tmp_path: Path) -> None:
    url, sent = fc_stream
    recording = tmp_path / "run.mcap"
    # Sent faster than real time: the rate check is not what this test is about.
    fast = criteria_for(min_rate_hz=1.0)
    session = VerifySession(url, duration_s=30.0, criteria=fast, record_path=recording)
    refreshed = []
    frames = []
    done = threading.Event()  # all sent was read: however loaded the machine, the run ends

    def on_packets(packets, _t):
        frames.extend(frame for packet in packets for frame in packet.frames)
        if len(frames) >= 2 * len(sent):
            done.set()

    result = session.run(on_refresh=refreshed.append, stop=done, on_packets=on_packets)

    assert result.summary.frames == 2 * len(sent)
    assert (result.summary.lost_packets, result.summary.lost_frames) == (1, 2)
    assert refreshed and refreshed[-1].frames <= result.summary.frames
    failed = [check.name for check in result.verdict.checks if not check.passed]
    assert failed == ["transport loss"]  # 2 of 1200 frames: over the 0.1 % default
    with pytest.raises(VerificationFailed, match="stream verification failed: transport loss"):
        result.check()

    again = replay(recording, criteria=criteria_for(min_rate_hz=1.0, max_loss_pct=1.0))
    assert again.summary == result.summary
    assert again.verdict.passed


def test_criteria_take_the_defaults_or_the_users_limits() -> None:
    assert criteria_for() == Criteria()
    mine = criteria_for(uplink=True, max_drops_pct=5.0)
    assert mine.uplink and mine.max_drops_pct == 5.0
    assert mine.max_loss_pct == Criteria().max_loss_pct


def test_the_rate_is_judged_against_the_expected_rate_never_the_streams_own(
    fc_stream: tuple[str, list[int]],
) -> None:
    url, _ = fc_stream
    session = VerifySession(url, duration_s=1.5)
    result = session.run()
    assert "frame rate" not in [check.name for check in result.verdict.checks]
    assert result.verdict.notes == (RATE_UNCHECKED,)
    assert result.summary.source_rate_hz  # the stream's own rate is known, and not used

    expecting = session.result(session.monitor.summary())
    assert expecting.verdict.notes == (RATE_UNCHECKED,)
    session.monitor.expected_rate_hz = 10 * result.summary.frame_rate_hz
    judged = session.result()
    rate = next(check for check in judged.verdict.checks if check.name == "frame rate")
    assert not rate.passed and not judged.verdict.passed
    assert judged.verdict.notes == ()


def test_the_clock_estimator_is_chosen_by_name_recorded_and_replayed(
    fc_stream: tuple[str, list[int]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    url, _ = fc_stream
    recording = tmp_path / "run.mcap"
    session = VerifySession(url, duration_s=1.5, record_path=recording, clock="kalman")
    result = session.run()
    assert result.summary.clock_estimator == "kalman"
    assert result.summary.clock is not None and result.summary.clock.locked

    again = replay(recording)  # the recorded run's estimator
    assert again.summary == result.summary
    other = replay(recording, clock="envelope")
    assert other.summary.clock_estimator == "envelope"
    assert other.summary.clock != result.summary.clock
    # Not locked after 1.5 s: its lock time is NaN in Python, null in JSON.
    assert other.summary.clock is not None and not other.summary.clock.locked
    assert json.loads(json.dumps(other.as_json(), allow_nan=False))["clock"]["lock_time_s"] is None

    code, out, _ = run_cli(capsys, "replay", str(recording), "--clock", "envelope", "--json")
    assert json.loads(out)["clock_estimator"] == "envelope"
    assert code == 1  # the transport loss, as above


def test_an_unknown_clock_estimator_is_refused_before_the_run() -> None:
    with pytest.raises(UsageError, match="unknown clock estimator 'best'"):
        VerifySession("socket://127.0.0.1:1", duration_s=1.0, clock="best")


# -- faults on the line: outages, damage at each start, loss -----------------------------------


def test_an_outage_is_counted_as_loss_and_fails_the_run_unless_allowed() -> None:
    """Connected 1.5 s, gone 1 s, twice, then connected to the end. What the FC sent
    meanwhile is lost and E1 `seq` says exactly how much; the rate is over the whole run;
    the time disconnected fails the run unless the user allows it."""
    received: list[int] = []
    with FakeFc(connected_s=(1.5, 1.5), outages_s=(1.0, 1.0)) as fc:
        session = VerifySession(fc.url, duration_s=8.0, expected_rate_hz=FRAME_RATE_HZ)
        result = session.run(on_packets=lambda packets, t: received.extend(p.seq for p in packets))
    summary = result.summary
    assert fc.connections == 3 and summary.reconnects == 2
    missing = received[-1] - received[0] + 1 - len(received)
    assert (summary.lost_packets, summary.lost_frames) == (missing, 2 * missing)
    assert summary.frame_rate_hz < 0.7 * FRAME_RATE_HZ  # frames over the whole run
    assert summary.resets == 0 and summary.errors == 0 and summary.sync_rejected == 0
    assert 2.0 < summary.outage_s < 5.0  # the outages, and the reconnects' backoff
    assert missing > 0.9 * summary.outage_s / PACKET_S
    failed = {check.name for check in result.verdict.checks if not check.passed}
    assert failed == {"time disconnected", "transport loss", "frame rate"}

    allowed = criteria_for(max_outage_s=5.0, max_loss_pct=100.0, min_rate_hz=100.0)
    assert judge(summary, allowed).passed


def crc_damaged(index: int) -> bytes:
    """Packet `index` of the steady stream, its CRC byte wrong (the COBS framing intact)."""
    payload = cobs.decode(intact(index)[:-1])
    return encode_frame(payload[:-1] + bytes([payload[-1] ^ 0x5A]))


def test_a_crc_error_at_the_start_of_each_connection_is_an_error() -> None:
    """Each connection starts on a packet boundary: its first chunk decodes, and the damaged
    one after it is no chunk cut by joining mid-stream."""
    second_damaged = lambda index, nth: crc_damaged(index) if nth == 1 else intact(index)  # noqa: E731
    with FakeFc(second_damaged, connected_s=(1.0, 1.0), outages_s=(0.3, 0.3)) as fc:
        # until the third connection has streamed past its damaged packet, however late the
        # host runs the fake FC (3.8 s of host clock cut it off before then on a loaded host)
        done = threading.Event()

        def third_connection_streamed() -> None:
            wait_for(lambda: fc.connections == 3, NEVER_S)
            first = len(fc.sent)
            wait_for(lambda: len(fc.sent) >= first + 10, NEVER_S)
            done.set()

        watcher = threading.Thread(target=third_connection_streamed, daemon=True)
        watcher.start()
        result = VerifySession(fc.url, duration_s=NEVER_S).run(stop=done)
        watcher.join()
    summary = result.summary
    assert fc.connections == 3 and summary.reconnects == 2
    assert summary.rejected["crc"] == 3 and summary.sync_rejected == 0
    failed = {check.name for check in result.verdict.checks if not check.passed}
    assert failed == {"rejected chunks", "transport loss", "time disconnected"}


def test_transport_loss_and_fc_drops_are_no_fc_jitter() -> None:
    """One packet in 30 lost, one frame in 70 dropped by the FC: the FC sampled every 953 µs
    all along, and that is what the intervals show; the loss and the drops are counted."""

    def wire(index: int, _nth: int) -> bytes | None:
        drops = index // 35  # a frame dropped before every 35th packet
        t_us = 1_000_000 + (2 * index + drops) * PERIOD
        return None if index % 30 == 7 else packet_at(index, t_us, drops=drops)

    with FakeFc(wire) as fc:
        result = VerifySession(fc.url, duration_s=3.0, expected_rate_hz=FRAME_RATE_HZ).run()
    summary = result.summary
    assert summary.lost_packets > 20 and summary.fc_drops > 20
    interval = summary.fc_interval
    assert (interval.p1_us, interval.p50_us, interval.p99_us, interval.mean_us) == (953,) * 4
    assert summary.source_rate_hz == pytest.approx(FRAME_RATE_HZ)
    checks = {check.name: check.passed for check in result.verdict.checks}
    assert checks["FC interval spread"] and not checks["transport loss"]


def test_an_uplink_pattern_outside_the_fcs_pulse_range_is_one_usage_error() -> None:
    """The FC reports a pulse range the pattern (rolls 1100-1900 µs, throttle 1000) leaves:
    the run ends in one line naming the value and the FC's range, sending nothing outside."""
    from wftool.fsp import Authority, AuthorityExit, UplinkStatus, encode_uplink_status

    def narrow(index: int, _nth: int) -> bytes | None:
        status = UplinkStatus(
            0, 1_000_000 + 2 * index * PERIOD + 50, 0, 0, 0, 0, 50, 0, 0, 0, Authority.PILOT,
            AuthorityExit.NONE, 500, 0, 0, 0, 0, 0, 1200, 1800,
        )  # fmt: skip
        return intact(index) + encode_uplink_status(status)

    with FakeFc(narrow) as fc:
        session = VerifySession(fc.url, duration_s=5.0, uplink_rate_hz=50.0)
        outside = r"RC \w+ \d+ µs is outside the FC's pulse range 1200\.\.1800 µs"
        with pytest.raises(UsageError, match=rf"^cannot send the command \(.*\): {outside}"):
            session.run()
