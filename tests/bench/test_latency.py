"""`bench latency` on the virtual FC: the pipeline measured against the SITL's true clock.

Behaviour, not timing: the truth is consistent with what was read (no packet arrives
before its true send instant), and the two-way estimate holds the true clock within the
uncertainty it reports, frame after frame.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from wftool.bench.latency import run_latency_bench

pytestmark = pytest.mark.slow


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
    assert result.sample_to_frame is not None and result.sample_to_frame.p50_s > 0


def test_one_way_only_without_time_replies(sitl_binary: Path) -> None:
    result = run_latency_bench(sitl_binary, seconds=6.0, time_reply=False)
    assert [e.name for e in result.estimators] == ["envelope", "kalman"]
    assert result.round_trips == 0 and result.rtt is None
