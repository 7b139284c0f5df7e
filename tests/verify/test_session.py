"""The verify API over a real TCP connection: a run, its verdict, its recording replayed."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import run_cli
from tests.fsp.test_decoder import stream
from wftool.errors import UsageError, VerificationFailed
from wftool.verify.criteria import RATE_UNCHECKED, Criteria
from wftool.verify.session import VerifySession, criteria_for, replay


@pytest.fixture
def fc_stream() -> Iterator[tuple[str, list[int]]]:
    """A TCP server that streams 600 packets, packet 100 missing, then holds the line."""
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
            time.sleep(2.0)

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
    session = VerifySession(url, duration_s=1.5, criteria=fast, record_path=recording)
    refreshed = []
    result = session.run(on_refresh=refreshed.append)

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
