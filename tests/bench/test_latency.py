"""`bench latency` on the virtual FC: the pipeline measured against the SITL's true clock.

Behaviour, not timing: the truth is consistent with what was read (no packet arrives
before its true send instant), and the two-way estimate holds the true clock within the
uncertainty it reports, frame after frame.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

import wftool.bench.latency
from wftool.bench.latency import run_latency_bench
from wftool.sitl.session import VirtualFcSession


def test_two_way_offset_holds_the_true_clock_within_its_uncertainty(sitl_binary: Path) -> None:
    result = run_latency_bench(sitl_binary, seconds=15.0)
    assert result.errors == 0 and result.lost_frames == 0
    assert result.min_delay_s > 0  # every packet read after its true send instant
    scored = {e.name: e for e in result.estimators}
    assert set(scored) == {"envelope", "kalman", "twoway"}
    two_way = scored["twoway"]
    assert result.round_trips > 300 and two_way.frames > 5000
    assert two_way.within_uncertainty is not None and two_way.within_uncertainty >= 0.99
    assert two_way.uncertainty_s is not None and two_way.uncertainty_s > 0
    assert result.sample_to_frame is not None and result.sample_to_frame.p50_us > 0


def test_one_way_only_without_time_replies(sitl_binary: Path) -> None:
    result = run_latency_bench(sitl_binary, seconds=6.0, time_reply=False)
    assert [e.name for e in result.estimators] == ["envelope", "kalman"]
    assert result.round_trips == 0 and result.rtt is None


class _HostStall(VirtualFcSession):
    """Scaffolding: the virtual FC as the bench starts it, stopped (SIGSTOP) for PAUSE_S at
    AT_S after it started, as a host that fell behind would; its lockstep clock re-anchors."""

    AT_S = 2.0
    PAUSE_S = 0.3

    def start(self) -> VirtualFcSession:
        super().start()
        process = self.fc._process
        assert process is not None

        def stall() -> None:
            time.sleep(self.AT_S)
            os.kill(process.pid, signal.SIGSTOP)
            time.sleep(self.PAUSE_S)
            os.kill(process.pid, signal.SIGCONT)

        threading.Thread(target=stall, daemon=True).start()
        return self


def test_estimators_lock_again_after_a_re_anchor_while_learning_the_rate(
    sitl_binary: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The FC clock stands still 0.3 s before the envelope knows the rate: both estimators
    learn it again after the step and hold the true clock, not a rate spanning the step."""
    monkeypatch.setattr(wftool.bench.latency, "VirtualFcSession", _HostStall)
    result = run_latency_bench(sitl_binary, seconds=16.0)
    assert result.reanchors >= 1 and result.lost_frames == 0
    scored = {e.name: e for e in result.estimators}
    envelope, two_way = scored["envelope"], scored["twoway"]
    assert envelope.frames > 3000 and envelope.p99_s - result.min_delay_s < 1e-3
    assert two_way.frames > 3000 and two_way.within_uncertainty is not None
    assert two_way.within_uncertainty >= 0.99
