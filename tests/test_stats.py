"""One definition of a percentile (`wftool.stats`): NumPy's "inverted_cdf" (nearest rank), and
every figure wftool reports takes it: verify's interval histograms, Table 1, the uplink's
round trips, the MSP poll's latencies, the benchmarks' spreads."""

from __future__ import annotations

import random
from array import array

import numpy as np
import pytest

from tests.fsp.test_decoder import frame
from wftool.analysis.timing import interval_stats
from wftool.fc.msp_poller import CommandStats
from wftool.fsp import StatePacket
from wftool.fsp.encoder import encode_state
from wftool.stats import Distribution, Histogram, median, quantile, rank
from wftool.verify.monitor import StreamMonitor
from wftool.verify.uplink import UplinkTracker

QS = (0.01, 0.5, 0.99)
SIZES = (1, 2, 4, 7, 100, 101, 250, 1001)
"""Counts where the old rules (⌊q·(n−1)⌋, round(q·(n−1))) and nearest rank part ways."""


def values_of(count: int, seed: int = 0) -> list[int]:
    """`count` whole µs in random order, about a frame period (within the decoder's idea of
    a steady stream); distinct up to 250 of them, so each rank has its own value."""
    rng, band = random.Random(seed), range(900, 1150)
    return rng.sample(band, count) if count <= len(band) else rng.choices(band, k=count)


def reference(values: list[int], q: float) -> float:
    """The definition, by NumPy (an independent implementation)."""
    return float(np.quantile(np.array(values, dtype=np.float64), q, method="inverted_cdf"))


@pytest.mark.parametrize("count", SIZES)
def test_a_quantile_is_the_nearest_rank(count: int) -> None:
    values = values_of(count)
    ordered = sorted(values)
    for q in (0.0, *QS, 0.25, 0.999, 1.0):
        assert quantile(ordered, q) == reference(values, q), (count, q)
    assert quantile(ordered, 0.0) == ordered[0] and quantile(ordered, 1.0) == ordered[-1]


def test_a_whole_rank_is_not_taken_one_too_high() -> None:
    """0.07 · 100 is 7.000000000000001 in floating point: the 7th value, not the 8th."""
    assert rank(0.07, 100) == 6 and rank(0.99, 100) == 98 and rank(0.01, 100) == 0
    assert rank(0.5, 4) == 1 and rank(0.5, 5) == 2


def test_no_values_and_no_quantile_outside_0_to_1_are_errors() -> None:
    with pytest.raises(ValueError, match="no values"):
        quantile([], 0.5)
    with pytest.raises(ValueError, match="0 to 1"):
        rank(1.5, 10)
    assert Distribution.of([]) is None and Histogram().summary() is None


def test_a_histogram_gives_the_quantiles_of_its_values() -> None:
    values = [953] * 500 + [952] * 300 + [1000] * 5 + [10] * 2
    histogram = Histogram()
    for value in values:
        histogram.add(value)
    summary = histogram.summary()
    assert summary is not None
    assert (summary.p1_us, summary.p50_us, summary.p99_us, summary.max_us) == tuple(
        reference(values, q) for q in (*QS, 1.0)
    )
    assert summary.mean_us == pytest.approx(sum(values) / len(values))
    assert summary.count == len(values) and summary.spread_us == summary.p99_us - summary.p1_us


def test_the_median_of_an_even_count_is_the_lower_middle_value() -> None:
    assert median([4, 1, 3, 2]) == 2 and median([3, 1, 2]) == 2


def intervals_in_verify(intervals: list[int]) -> tuple[Distribution | None, list[int]]:
    """The FC sample intervals `verify` reports for a stream whose frames are `intervals`
    apart (packets of two frames, E1, nothing lost), and the intervals the stream has: one
    more (of 1000 µs) when they do not fill whole packets."""
    intervals = [*intervals, 1000] if len(intervals) % 2 == 0 else list(intervals)
    times = [1_000_000]
    for interval in intervals:
        times.append(times[-1] + interval)
    monitor = StreamMonitor("test")
    monitor.connected(0.0)
    for seq in range(len(times) // 2):
        first, second = times[2 * seq], times[2 * seq + 1]
        packet = StatePacket(second + 100, (frame(first), frame(second)), seq, True)
        monitor.feed(encode_state(packet), (second - times[0]) * 1e-6 + 0.0005)
    return monitor.summary().fc_interval, intervals


def round_trips_in_verify(rtts_us: list[int]) -> tuple[float | None, float | None]:
    """The uplink's RTT P50 and P99 (ms) `verify` reports for roll steps echoed `rtts_us`
    after they were sent."""
    tracker = UplinkTracker()
    for index, rtt in enumerate(rtts_us):
        roll = 1000 + index
        t = 10.0 * index
        tracker.sent((roll, 1500, 1500, 1000, 1000, 1000), t)
        rc = (roll, 1500, 1500, 1000, 1000, 1000)
        echo = StatePacket(0, (frame(0, rc=rc), frame(1, rc=rc)), index, True)
        tracker.observe(echo, t + rtt * 1e-6)
    stats = tracker.stats()
    return stats.rtt_p50_ms, stats.rtt_p99_ms


@pytest.mark.parametrize("count", [n for n in SIZES if n > 2])
def test_every_reported_figure_takes_the_one_definition(count: int) -> None:
    values = values_of(count, seed=count)
    p1, p50, p99 = (reference(values, q) for q in QS)

    verify, intervals = intervals_in_verify(values)
    assert verify is not None and verify.count == len(intervals)
    assert (verify.p1_us, verify.p50_us, verify.p99_us) == tuple(
        reference(intervals, q) for q in QS
    )

    table1 = interval_stats(np.array(values, dtype=np.float64))
    assert (table1.p1_us, table1.p50_us, table1.p99_us) == (p1, p50, p99)

    assert round_trips_in_verify(values) == pytest.approx((p50 / 1e3, p99 / 1e3))

    poll = CommandStats("RAW_IMU", 1000.0, latencies_s=array("d", (v * 1e-6 for v in values)))
    latency = poll.as_json(1.0)
    assert (latency["latency_median_ms"], latency["latency_p99_ms"]) == pytest.approx(
        (p50 / 1e3, p99 / 1e3)
    )

    spread = Distribution.of(values)  # the benchmarks' (bench command, latency, ros2, stream)
    assert spread is not None and (spread.p1_us, spread.p50_us, spread.p99_us) == (p1, p50, p99)
