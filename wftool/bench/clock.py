"""`wftool bench clock`: the clock estimators against known truth, on a simulated FC → OBC link
(delay models, skew, wraps); the envelope and the absolute error (docs/bench.md).
"""

from __future__ import annotations

import math
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from wftool.bench.decode import FRAME_PERIOD_US
from wftool.fsp.clock import U32, ClockEstimator, FcClock
from wftool.fsp.estimators import make_estimator
from wftool.stats import median, quantile

PACKET_PERIOD_US = 2 * FRAME_PERIOD_US
"""Two frames per packet at 1049 Hz: ~525 packets/s (spec §7)."""
TX_AFTER_SAMPLE_US = 120
"""A packet leaves this long after its second frame's sample."""
MIN_DELAY_S = 0.7e-3
"""Fixed transport delay: 118 bytes at 2 Mbaud (0.59 ms) and the USB/driver floor."""
SERIAL_S = 0.59e-3
"""The UART is FIFO: a packet arrives at least one packet's wire time after the one before."""


@dataclass(frozen=True)
class DelayModel:
    """How the link delays and stamps packets, on top of MIN_DELAY_S."""

    name: str
    exponential_mean_s: float = 0.3e-3
    burst_fraction: float = 0.0
    """Share of packets inside late bursts, each burst adding 1–8 ms to ~10 packets."""
    read_period_s: float = 0.0
    """Bytes reach the program in reads on this grid (0: each packet stamped as it arrives)."""
    dropout_s: float = 0.0
    """Nothing arrives for this long, half-way through."""
    wrap: bool = False
    """Start the FC's u32 `micros()` a minute before it wraps."""


MODELS: tuple[DelayModel, ...] = (
    DelayModel("exponential"),
    DelayModel("bursts", burst_fraction=0.03),
    DelayModel("reads 1 ms", burst_fraction=0.03, read_period_s=1e-3),
    DelayModel("reads 16 ms", burst_fraction=0.03, read_period_s=16e-3),
    DelayModel("dropout 5 s", burst_fraction=0.03, read_period_s=1e-3, dropout_s=5.0),
    DelayModel("u32 wrap", burst_fraction=0.03, read_period_s=1e-3, wrap=True),
    DelayModel("all, 16 ms", burst_fraction=0.03, read_period_s=16e-3, dropout_s=5.0, wrap=True),
)

BURST_EXTRA_S = (1e-3, 8e-3)
BURST_PACKETS = (5, 15)


@dataclass(frozen=True)
class ClockTruth:
    """t_obc(t_fc) for an FC clock whose rate against the OBC drifts linearly."""

    fc_origin_us: int
    obc_origin_s: float
    skew_ppm: float
    """At the origin: how much faster the OBC clock runs than the FC clock."""
    drift_ppm_per_s: float

    def obc_of(self, fc_time_us: int) -> float:
        t = (fc_time_us - self.fc_origin_us) * 1e-6
        return self.obc_origin_s + t + (self.skew_ppm + 0.5 * self.drift_ppm_per_s * t) * t * 1e-6


@dataclass
class ClockTrace:
    """What a decoder sees (unwrapped FC send times, OBC read times) and the truth."""

    model: str
    truth: ClockTruth
    fc_time_us: list[int]
    arrival: list[float]
    true_obc: list[float]
    """OBC time at each packet's FC send instant."""
    min_delay_s: float
    wraps: int = 0


def simulate(
    model: DelayModel, seed: int, seconds: float, drift_ppm_per_min: float = 1.0
) -> ClockTrace:
    """A run of `seconds` of FSP traffic through `model`; the skew is drawn from ±100 ppm."""
    rng = random.Random(seed)
    expovariate, uniform = rng.expovariate, rng.uniform
    skew = uniform(-100.0, 100.0)
    drift = math.copysign(drift_ppm_per_min / 60.0, uniform(-1.0, 1.0))
    start_us = U32 - 60_000_000 if model.wrap else rng.randrange(10**6, 10**9)
    truth = ClockTruth(start_us, uniform(100.0, 10_000.0), skew, drift)
    read, phase = model.read_period_s, uniform(0.0, model.read_period_s or 1.0)
    dropout_from = start_us + int(seconds * 5e5)
    dropout_to = dropout_from + int(model.dropout_s * 1e6)
    burst_start = model.burst_fraction / (sum(BURST_PACKETS) / 2) / (1 - model.burst_fraction)
    rate = 1.0 / model.exponential_mean_s
    fc_clock = FcClock()
    trace = ClockTrace(model.name, truth, [], [], [], MIN_DELAY_S)
    burst_left, burst_extra, last_arrival = 0, 0.0, -math.inf
    for n in range(int(seconds * 1e6 / PACKET_PERIOD_US)):
        fc_us = start_us + n * PACKET_PERIOD_US + TX_AFTER_SAMPLE_US
        true_obc = truth.obc_of(fc_us)
        if burst_left:
            burst_left -= 1
        elif rng.random() < burst_start:
            burst_left, burst_extra = rng.randint(*BURST_PACKETS), uniform(*BURST_EXTRA_S)
        arrival = true_obc + MIN_DELAY_S + expovariate(rate) + (burst_extra if burst_left else 0)
        arrival = max(arrival, last_arrival + SERIAL_S)
        if dropout_from <= fc_us < dropout_to:
            continue
        last_arrival = arrival
        if read:
            arrival = phase + math.ceil((arrival - phase) / read) * read
        unwrapped, _ = fc_clock.unwrap(fc_us % U32, arrival)
        trace.fc_time_us.append(unwrapped)
        trace.arrival.append(arrival)
        trace.true_obc.append(true_obc)
    trace.wraps = fc_clock.wraps
    return trace


@dataclass(frozen=True)
class ClockFigures:
    """One estimator on one trace. Errors in seconds, over the packets seen while locked."""

    estimator: str
    model: str
    seed: int
    envelope_rms_s: float
    """Against the true capture instant + d_min: what one-way timing can identify."""
    envelope_p99_s: float
    absolute_rms_s: float
    """Against the true capture instant: includes d_min."""
    absolute_p99_s: float
    lock_time_s: float
    """OBC seconds from the first packet to the first locked estimate (NaN: never)."""
    locked_share: float
    steps: int
    observations_per_s: float


def _rms(values: Sequence[float]) -> float:
    return math.sqrt(math.fsum(v * v for v in values) / len(values)) if values else math.nan


def _p99_abs(values: Sequence[float]) -> float:
    return quantile(sorted(abs(v) for v in values), 0.99) if values else math.nan


def observations_per_s(factory: Callable[[], ClockEstimator], trace: ClockTrace) -> float:
    """Packets per second through observe + to_obc, as the decoder uses the estimator."""
    estimator = factory()
    observe, to_obc = estimator.observe, estimator.to_obc
    clock = time.perf_counter
    start = clock()
    for fc_us, arrival in zip(trace.fc_time_us, trace.arrival):
        observe(fc_us, arrival)
        to_obc(fc_us)
    return len(trace.fc_time_us) / (clock() - start)


def score(name: str, trace: ClockTrace, seed: int = 0, repeat: int = 1) -> ClockFigures:
    """Run estimator `name` causally over `trace`: each packet's OBC time right after it."""
    estimator = make_estimator(name)
    envelope: list[float] = []
    absolute: list[float] = []
    lock_time = math.nan
    first_arrival = trace.arrival[0] if trace.arrival else math.nan
    for fc_us, arrival, true_obc in zip(trace.fc_time_us, trace.arrival, trace.true_obc):
        estimator.observe(fc_us, arrival)
        if not estimator.state.locked:
            continue
        if math.isnan(lock_time):
            lock_time = arrival - first_arrival
        error = estimator.to_obc(fc_us) - true_obc  # type: ignore[operator]
        absolute.append(error)
        envelope.append(error - trace.min_delay_s)
    speed = max(observations_per_s(lambda: make_estimator(name), trace) for _ in range(repeat))
    return ClockFigures(
        estimator=name,
        model=trace.model,
        seed=seed,
        envelope_rms_s=_rms(envelope),
        envelope_p99_s=_p99_abs(envelope),
        absolute_rms_s=_rms(absolute),
        absolute_p99_s=_p99_abs(absolute),
        lock_time_s=lock_time,
        locked_share=len(envelope) / len(trace.fc_time_us) if trace.fc_time_us else 0.0,
        steps=estimator.state.steps,
        observations_per_s=speed,
    )


@dataclass(frozen=True)
class ModelSummary:
    """All seeds of one estimator on one model: the worst seed's errors, median speed."""

    estimator: str
    model: str
    runs: tuple[ClockFigures, ...]

    @property
    def envelope_rms_s(self) -> float:
        return max(run.envelope_rms_s for run in self.runs)

    @property
    def envelope_p99_s(self) -> float:
        return max(run.envelope_p99_s for run in self.runs)

    @property
    def absolute_rms_s(self) -> float:
        return max(run.absolute_rms_s for run in self.runs)

    @property
    def absolute_p99_s(self) -> float:
        return max(run.absolute_p99_s for run in self.runs)

    @property
    def lock_time_s(self) -> float:
        return max(run.lock_time_s for run in self.runs)

    @property
    def observations_per_s(self) -> float:
        return median(run.observations_per_s for run in self.runs)


GOAL_RMS_S = 50e-6
GOAL_RATIO = 10.0
"""The envelope estimator's goal: RMS ≤ 50 µs and ≤ 1/10 of the reference's, on every model."""
REFERENCE = "kalman"


@dataclass(frozen=True)
class ClockBenchResult:
    seconds: float
    seeds: tuple[int, ...]
    drift_ppm_per_min: float
    summaries: tuple[ModelSummary, ...]

    def find(self, estimator: str, model: str) -> ModelSummary | None:
        for summary in self.summaries:
            if (summary.estimator, summary.model) == (estimator, model):
                return summary
        return None

    def rms_ratio(self, summary: ModelSummary) -> float:
        """How many times smaller this envelope RMS is than the reference's on the same
        trace: the least over the seeds."""
        reference = self.find(REFERENCE, summary.model)
        if reference is None:
            return math.nan
        pairs = zip(reference.runs, summary.runs)
        return min(theirs.envelope_rms_s / mine.envelope_rms_s for theirs, mine in pairs)

    def speed_ratio(self, estimator: str) -> float:
        """Median observations/s over all models against the reference's, same run."""
        mine = [s.observations_per_s for s in self.summaries if s.estimator == estimator]
        theirs = [s.observations_per_s for s in self.summaries if s.estimator == REFERENCE]
        if not mine or not theirs:
            return math.nan
        return median(mine) / median(theirs)

    def goal_misses(self) -> list[ModelSummary]:
        """Estimators other than the reference that miss the goal, by model."""
        return [
            s
            for s in self.summaries
            if s.estimator != REFERENCE
            and not (s.envelope_rms_s <= GOAL_RMS_S and self.rms_ratio(s) >= GOAL_RATIO)
        ]


def run_clock_bench(
    estimators: Sequence[str],
    models: Sequence[DelayModel] = MODELS,
    seeds: Sequence[int] = (1, 2, 3),
    seconds: float = 300.0,
    drift_ppm_per_min: float = 1.0,
    repeat: int = 1,
) -> ClockBenchResult:
    """Every estimator on every model over every seed (the same traces for all estimators)."""
    runs: dict[tuple[str, str], list[ClockFigures]] = {}
    for model in models:
        for seed in seeds:
            trace = simulate(model, seed, seconds, drift_ppm_per_min)
            for name in estimators:
                runs.setdefault((name, model.name), []).append(score(name, trace, seed, repeat))
    summaries = tuple(ModelSummary(name, model, tuple(f)) for (name, model), f in runs.items())
    return ClockBenchResult(seconds, tuple(seeds), drift_ppm_per_min, summaries)
