"""`bench latency` on the virtual FC: the pipeline measured against the SITL's true clock.

Behaviour, not timing: the truth is consistent with what was read (no packet arrives
before its true send instant), and the two-way estimate holds the true clock within the
uncertainty it reports, frame after frame.
"""

from __future__ import annotations

import os
import random
import signal
import threading
import time
from pathlib import Path

import pytest

import wftool.bench.latency
from tests.fsp.test_decoder import frame
from wftool.bench.latency import STEP_SETTLE_S, _Capture, _replay, run_latency_bench
from wftool.fsp import StatePacket
from wftool.fsp.encoder import encode_state
from wftool.sitl.session import VirtualFcSession


def test_two_way_offset_holds_the_true_clock_within_its_uncertainty(sitl_binary: Path) -> None:
    result = run_latency_bench(sitl_binary, seconds=15.0)
    assert result.errors == 0 and result.lost_frames == 0
    assert result.min_delay_s > 0  # every packet read after its true send instant
    scored = {e.name: e for e in result.estimators}
    assert set(scored) == {"envelope", "kalman", "twoway"}
    two_way = scored["twoway"]
    assert result.round_trips > 300 and two_way.frames > 5000
    assert two_way.within_uncertainty is not None and two_way.within_uncertainty >= 0.99, (
        two_way,
        result.reanchors,
        result.round_trip_rejected,
        result.rtt,
    )
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


def test_a_re_anchor_after_lock_costs_the_frames_of_its_settling_time_and_no_more() -> None:
    """The scoring, on a stream made here: the FC clock stands still 0.1 s at 10.2 s (a
    re-anchor), after the envelope locked. Its frames within STEP_SETTLE_S are left out and
    counted; every other frame is scored, and within a few µs of the truth."""
    step_us, stood_s, period_us = 10_200_000, 0.1, 953
    rng = random.Random(3)

    def true_obc(fc_us: int) -> float:
        return 100.0 + fc_us * 1e-6 + (stood_s if fc_us >= step_us else 0.0)

    capture = _Capture()
    for seq, t_us in enumerate(range(1_000_000, 16_000_000, 2 * period_us)):
        packet = StatePacket(t_us + period_us + 50, (frame(t_us), frame(t_us + period_us)), seq)
        arrival = true_obc(packet.tx_time_us) + 0.6e-3 + rng.expovariate(1 / 0.3e-3)
        capture.events.append((arrival, encode_state(packet)))
    scored = _replay("envelope", capture, true_obc, 0.6e-3, False, [step_us])
    unscored = _replay("envelope", capture, true_obc, 0.6e-3, False)
    settling = round(STEP_SETTLE_S * 1e6 / period_us)  # (those it delivered locked, at most)
    assert 0 < scored.settling_frames <= settling and unscored.settling_frames == 0
    assert scored.frames + scored.settling_frames == unscored.frames > 5000
    assert scored.p99_s - 0.6e-3 < 20e-6
    assert unscored.p99_s > stood_s / 2  # the step's frames, scored, would be the p99
