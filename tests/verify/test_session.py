"""The verify API over a real TCP connection: a run, its verdict, its recording replayed."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.fsp.test_decoder import stream
from wftool.errors import VerificationFailed
from wftool.verify.criteria import VIRTUAL_FC, Criteria
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


def test_criteria_take_the_defaults_or_the_virtual_fcs_allowances() -> None:
    assert criteria_for() == Criteria()
    virtual = criteria_for(virtual_fc=True, uplink=True)
    assert (virtual.max_spread_ms, virtual.max_drops_pct) == (
        VIRTUAL_FC.max_spread_ms,
        VIRTUAL_FC.max_drops_pct,
    )
    assert virtual.uplink and virtual.max_loss_pct == Criteria().max_loss_pct
    assert criteria_for(virtual_fc=True, max_drops_pct=5.0).max_drops_pct == 5.0
