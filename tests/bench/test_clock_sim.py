"""The clock bench's simulator and scorer: the truth they hold is the truth they claim.

The simulator is checked against its own model (delays never below the minimum, reads on
their grid, the dropout, the wrap, the burst share); the scorer against estimators whose
error is known exactly; the command end to end on a short run. No timing assertions.
"""

from __future__ import annotations

import itertools
import math

import pytest

from tests.conftest import run_cli
from wftool.bench.clock import (
    MIN_DELAY_S,
    MODELS,
    PACKET_PERIOD_US,
    ClockTrace,
    DelayModel,
    run_clock_bench,
    score,
    simulate,
)
from wftool.fsp import estimators
from wftool.fsp.clock import U32, ClockState

MODEL = {model.name: model for model in MODELS}


def delays(trace: ClockTrace) -> list[float]:
    return [a - t for a, t in zip(trace.arrival, trace.true_obc)]


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_every_delay_is_at_least_the_minimum_and_fc_time_only_grows(model: DelayModel):
    trace = simulate(model, 1, 60.0)
    assert min(delays(trace)) >= MIN_DELAY_S - 1e-9
    assert all(b > a for a, b in itertools.pairwise(trace.fc_time_us))
    assert all(b >= a for a, b in itertools.pairwise(trace.arrival))  # the UART is FIFO
    sent = 60.0 * 1e6 / PACKET_PERIOD_US
    expected = sent * (1 - model.dropout_s / 60.0)
    assert len(trace.arrival) == pytest.approx(expected, rel=0.01)
    assert abs(trace.truth.skew_ppm) <= 100.0


def test_truth_is_the_skewed_drifting_line():
    trace = simulate(MODEL["exponential"], 2, 60.0)
    truth = trace.truth
    for start_s in (0, 60):  # the mean rate over one second: skew, drifted to mid-second
        start = truth.fc_origin_us + start_s * 1_000_000
        one_s_later = truth.obc_of(start + 1_000_000) - truth.obc_of(start)
        ppm = truth.skew_ppm + (start_s + 0.5) * truth.drift_ppm_per_s
        assert one_s_later == pytest.approx(1 + ppm * 1e-6, abs=1e-11)
    assert abs(truth.drift_ppm_per_s) == pytest.approx(1.0 / 60)


@pytest.mark.parametrize(("model", "period_s"), [("reads 1 ms", 1e-3), ("reads 16 ms", 16e-3)])
def test_reads_stamp_every_packet_with_the_read_time(model: str, period_s: float):
    trace = simulate(MODEL[model], 3, 30.0)
    reads = sorted(set(trace.arrival))
    gaps = [b - a for a, b in itertools.pairwise(reads)]
    assert all(abs(g / period_s - round(g / period_s)) < 1e-6 for g in gaps)
    assert len(reads) < len(trace.arrival) / (1 if period_s < 1.9e-3 else 5)


def test_dropout_and_wrap():
    trace = simulate(MODEL["all, 16 ms"], 4, 120.0)
    gaps = [b - a for a, b in itertools.pairwise(trace.arrival)]
    assert max(gaps) == pytest.approx(5.0, abs=0.05)
    assert trace.wraps == 1
    assert trace.fc_time_us[0] < U32 < trace.fc_time_us[-1]  # unwrapped through the wrap


def test_bursts_add_late_packets():
    late = {}
    for name in ("exponential", "bursts"):
        trace = simulate(MODEL[name], 5, 120.0)
        late[name] = sum(d > MIN_DELAY_S + 1e-3 for d in delays(trace)) / len(trace.arrival)
    # An exponential of mean 0.3 ms exceeds 1 ms in e^(-1/0.3) ≈ 3.6 % of packets; bursts
    # (3 % of packets, each 1–8 ms late) add about three points more.
    assert late["exponential"] == pytest.approx(math.exp(-1 / 0.3), abs=0.005)
    assert late["bursts"] - late["exponential"] == pytest.approx(0.03, abs=0.01)


class _Oracle:
    """Knows the truth: its error against the envelope is exactly `bias_s`."""

    def __init__(self, trace: ClockTrace, bias_s: float) -> None:
        self._truth, self._bias = trace.truth, bias_s
        self.state = ClockState(True, 0.0, 0.0, 0.0, 1, 0)

    def observe(self, fc_time_us: int, obc_time: float) -> None:
        pass

    def to_obc(self, fc_time_us: int) -> float:
        return self._truth.obc_of(fc_time_us) + MIN_DELAY_S + self._bias

    def reset(self) -> None:
        pass


def test_score_measures_the_error_it_is_given(monkeypatch: pytest.MonkeyPatch):
    trace = simulate(MODEL["u32 wrap"], 6, 20.0)
    for bias in (0.0, 25e-6):
        oracle = _Oracle(trace, bias)
        monkeypatch.setitem(estimators._FACTORIES, "oracle", lambda oracle=oracle: oracle)
        figures = score("oracle", trace)
        assert figures.envelope_rms_s == pytest.approx(bias, abs=1e-9)
        assert figures.envelope_p99_s == pytest.approx(bias, abs=1e-9)
        assert figures.absolute_rms_s == pytest.approx(MIN_DELAY_S + bias, abs=1e-9)
        assert (figures.lock_time_s, figures.locked_share) == (0.0, 1.0)
        assert figures.observations_per_s > 0


def test_bench_compares_every_estimator_on_the_same_traces():
    models = (MODEL["exponential"], MODEL["reads 1 ms"])
    result = run_clock_bench(("envelope", "kalman"), models, seeds=(1, 2), seconds=30.0)
    assert [(s.estimator, s.model) for s in result.summaries] == [
        ("envelope", "exponential"), ("kalman", "exponential"),
        ("envelope", "reads 1 ms"), ("kalman", "reads 1 ms"),
    ]  # fmt: skip
    for summary in result.summaries:
        assert [run.seed for run in summary.runs] == [1, 2]
        assert summary.envelope_rms_s == max(run.envelope_rms_s for run in summary.runs)
        assert math.isfinite(summary.lock_time_s)
    envelope = result.find("envelope", "reads 1 ms")
    kalman = result.find("kalman", "reads 1 ms")
    assert envelope is not None and kalman is not None
    assert result.rms_ratio(envelope) == min(
        k.envelope_rms_s / e.envelope_rms_s for e, k in zip(envelope.runs, kalman.runs)
    )
    missed = {(s.estimator, s.model) for s in result.goal_misses()}
    for summary in result.summaries:
        if summary.estimator != "kalman":
            ok = summary.envelope_rms_s <= 50e-6 and result.rms_ratio(summary) >= 10
            assert ((summary.estimator, summary.model) in missed) is not ok


def test_bench_clock_command_prints_every_model(capsys: pytest.CaptureFixture[str]):
    code, out, err = run_cli(capsys, "bench", "clock", "--seconds", "15", "--seeds", "1")
    assert (code, err) == (0, "")
    for model in MODELS:
        assert model.name in out
    assert "x the observations/s of kalman" in out
    assert "goal (RMS <= 50 µs and >= 10x better than kalman)" in out
