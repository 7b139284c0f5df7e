"""Clock alignment on simulated clocks: known skew and offset, noisy one-way delay.

The FC stream is simulated at the packet level (525 packets/s, 953 µs frame period) and
decoded through the real decoder, so unwrapping, reset detection and the estimator are
tested together as the OBC uses them — with each estimator. The envelope estimator is also
run on the bench's known-truth traces (`wftool.bench.clock.simulate`) with steps, stalls,
outliers and bad input spliced in.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import random
from collections import deque
from dataclasses import dataclass, field

import pytest

from tests.fsp.test_decoder import frame as blank_frame
from wftool.bench.clock import MODELS, ClockTrace, simulate
from wftool.errors import UsageError
from wftool.fsp import (
    ESTIMATORS,
    ONE_WAY_ESTIMATORS,
    ClockState,
    EnvelopeClockEstimator,
    FcClock,
    KalmanClockEstimator,
    StateDecoder,
    StatePacket,
    make_estimator,
)
from wftool.fsp.clock import SlidingLowerHull
from wftool.fsp.encoder import encode_state

PERIOD_US = 953
MIN_DELAY_S = 0.0006
JITTER_S = 0.0003  # mean of the exponential part of the one-way delay


@dataclass
class SimulatedLink:
    """An FC whose clock runs `skew_ppm` slow against the OBC, seen through a noisy link."""

    skew_ppm: float = 80.0
    offset_s: float = 1234.5
    fc_us: int = 5_000_000
    seed: int = 1
    clock: str = ESTIMATORS[0]
    decoder: StateDecoder = field(init=False)
    errors: list[float] = field(default_factory=list)
    seq: int = 0
    obc_shift_s: float = 0.0  # moves the FC→OBC mapping, e.g. at a reboot

    def __post_init__(self) -> None:
        self.random = random.Random(self.seed)
        self.decoder = StateDecoder(self.clock)

    def obc_of(self, fc_us: int) -> float:
        return (1 + self.skew_ppm * 1e-6) * fc_us * 1e-6 + self.offset_s + self.obc_shift_s

    def run(self, seconds: float) -> None:
        for _ in range(int(seconds * 1e6 / (2 * PERIOD_US))):
            f0, f1 = self.fc_us, self.fc_us + PERIOD_US
            tx = f1 + 150
            arrival = self.obc_of(tx) + MIN_DELAY_S + self.random.expovariate(1 / JITTER_S)
            packet = StatePacket(
                tx % 2**32, (blank_frame(f0), blank_frame(f1)), self.seq % 2**24, True
            )
            (decoded,) = self.decoder.feed(encode_state(packet), arrival)
            self.last = decoded
            for frame, true_fc in zip(decoded.frames, (f0, f1)):
                truth = self.obc_of(true_fc) + MIN_DELAY_S + JITTER_S
                self.errors.append(frame.obc_time - truth)
            self.fc_us += 2 * PERIOD_US
            self.seq += 1

    def worst_error_since(self, index: int) -> float:
        return max(abs(e) for e in self.errors[index:])


@pytest.fixture(params=ONE_WAY_ESTIMATORS)
def clock(request: pytest.FixtureRequest) -> str:
    return request.param


def test_converges_to_skew_and_tracks_ground_truth(clock: str):
    link = SimulatedLink(skew_ppm=80.0, clock=clock)
    link.run(30)
    settled = len(link.errors)
    link.run(60)
    state = link.decoder.clock_state
    assert state.locked and state.reinits == 0
    assert state.rate_ppm == pytest.approx(80.0, abs=10.0)
    assert link.worst_error_since(settled) < 0.0015


def test_negative_skew_and_large_offset(clock: str):
    link = SimulatedLink(skew_ppm=-150.0, offset_s=-50_000.0, seed=7, clock=clock)
    link.run(60)
    assert link.decoder.clock_state.rate_ppm == pytest.approx(-150.0, abs=20.0)
    assert link.worst_error_since(len(link.errors) // 2) < 0.0015


def test_u32_wrap_is_not_a_reset(clock: str):
    link = SimulatedLink(fc_us=2**32 - 20_000_000, clock=clock)  # wraps 20 s in
    link.run(15)
    settled = len(link.errors)
    link.run(30)
    stats = link.decoder.stats
    assert (stats.wraps, stats.resets, stats.lost_packets) == (1, 0, 0)
    assert link.decoder.clock_state.reinits == 0
    assert link.worst_error_since(settled) < 0.0015


def test_reboot_reinitialises_and_tracks_again(clock: str):
    link = SimulatedLink(clock=clock)
    link.run(20)
    # The FC reboots: 3 s of silence, then its clock restarts near zero.
    link.obc_shift_s = link.obc_of(link.fc_us) + 3.0 - link.obc_of(1_500_000)
    link.fc_us, link.seq = 1_500_000, 0
    before = len(link.errors)
    link.run(20)
    stats = link.decoder.stats
    assert (stats.resets, stats.wraps, stats.lost_packets) == (1, 0, 0)
    assert link.last.epoch == 1
    assert link.worst_error_since(before + 4000) < 0.0015


def test_reboot_just_before_a_wrap_is_still_a_reset():
    """Seen modulo 2^32 the new clock is 'ahead'; only the OBC clock can tell."""
    link = SimulatedLink(fc_us=2**32 - 5_000_000)
    link.run(4)  # stops ~1 s before the wrap
    link.obc_shift_s = link.obc_of(link.fc_us) + 0.5 - link.obc_of(2_000_000)
    link.fc_us = 2_000_000
    link.run(5)
    assert (link.decoder.stats.resets, link.decoder.stats.wraps) == (1, 0)


def test_paused_fc_clock_reinitialises_the_estimator(clock: str):
    link = SimulatedLink(clock=clock)
    link.run(30)
    link.obc_shift_s += 2.0  # the FC clock stood still for 2 s (e.g. calibration)
    link.run(10)
    assert link.decoder.stats.resets == 0
    assert link.decoder.clock_state.reinits == link.decoder.clock_state.steps == 1
    assert link.worst_error_since(len(link.errors) - 2000) < 0.0015


def test_fc_clock_standing_still_while_learning_the_rate_is_learnt_past():
    """A virtual FC re-anchors its lockstep clock (its clock stands still 0.3 s) before the
    envelope knows the rate: the window the first rate comes from spans the step, so that
    rate is not kept through the step it then sees; the estimator locks again and tracks."""
    link = SimulatedLink(clock="envelope")
    link.run(2)
    link.obc_shift_s += 0.3
    link.run(20)
    state = link.decoder.clock_state
    assert state.locked and state.steps == 1
    assert abs(state.rate_ppm - link.skew_ppm) < 20
    assert link.worst_error_since(len(link.errors) - 10000) < 0.0015


@pytest.mark.parametrize(
    "steps",
    [
        ((2.0, 0.3), (5.0, 0.054)),  # the second in the window the rate is learnt again from
        ((3.0, 0.054),),  # in the window the first rate comes from, after its middle
        ((3.8, 0.054),),  # a bucket before the rate is known: the lock waits for the run
    ],
)
def test_fc_clock_steps_while_learning_the_rate_never_lock_a_wrong_line(
    steps: tuple[tuple[float, float], ...],
):
    """A loaded host re-anchors the virtual FC's lockstep clock (it stands still: `steps`,
    (at s, for s)) while the envelope learns the rate, and the OBC reads late now and then:
    each step is seen and learnt past, and no packet mapped while locked is off by a step."""
    rng = random.Random(1)
    estimator = EnvelopeClockEstimator()
    packet_us, skew = 2 * PERIOD_US, 80e-6
    worst, host_free = 0.0, 0.0
    for n in range(int(16e6 / packet_us)):
        fc_us, t = 5_000_000 + n * packet_us, n * packet_us * 1e-6
        true = 1000.0 + t * (1 + skew) + sum(step for at, step in steps if t >= at)
        arrival = true + MIN_DELAY_S + rng.expovariate(1 / JITTER_S)
        if arrival > host_free and rng.random() < 0.01:  # the reader descheduled 5–50 ms
            host_free = arrival + rng.uniform(5e-3, 50e-3)
        estimator.observe(fc_us, max(arrival, host_free))
        if estimator.state.locked:
            mapped = estimator.to_obc(fc_us)
            assert mapped is not None
            worst = max(worst, abs(mapped - true - MIN_DELAY_S))
    state = estimator.state
    assert state.locked and state.steps == len(steps)
    assert abs(state.rate_ppm - skew * 1e6) < 20
    assert worst < 0.0015


def test_fc_clock_without_obc_times_uses_half_range_rule():
    clock = FcClock()
    assert clock.unwrap(2**32 - 10) == (2**32 - 10, False)
    assert clock.unwrap(5) == (2**32 + 5, False)
    assert clock.wraps == 1
    assert clock.unwrap(2**31 + 100) == (2**31 + 100, True)  # backwards by > half: reset
    assert clock.resets == 1


def test_long_gap_spanning_several_wraps():
    clock = FcClock()
    clock.unwrap(1000, obc_time=0.0)
    three_wraps_later = 3 * 2**32 + 500_000
    time_us, reset = clock.unwrap(three_wraps_later % 2**32, obc_time=three_wraps_later * 1e-6)
    assert (time_us, reset, clock.wraps) == (three_wraps_later, False, 3)


def test_estimator_updates_every_hundredth_packet():
    estimator = KalmanClockEstimator()
    for i in range(250):
        estimator.observe(i * 2000, 10.0 + i * 0.002)
    assert estimator.state.updates == 2
    assert estimator.to_obc(250 * 2000) == pytest.approx(10.5, abs=1e-6)


# --- The envelope estimator on known-truth traces -------------------------------------------

MODEL = {model.name: model for model in MODELS}


def envelope_errors(
    estimator: EnvelopeClockEstimator, trace: ClockTrace, start: int = 0, end: int | None = None
) -> list[float]:
    """Feed packets [start, end) of `trace`; each one's error against the envelope (µs)."""
    errors = []
    window = slice(start, end)  # (not the zipped trace sliced: a window at a time is linear)
    for fc_us, arrival, truth in zip(
        trace.fc_time_us[window], trace.arrival[window], trace.true_obc[window]
    ):
        estimator.observe(fc_us, arrival)
        errors.append((estimator.to_obc(fc_us) - truth - trace.min_delay_s) * 1e6)
    return errors


def rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


def true_rate_ppm(trace: ClockTrace, index: int) -> float:
    elapsed = (trace.fc_time_us[index] - trace.truth.fc_origin_us) * 1e-6
    return trace.truth.skew_ppm + trace.truth.drift_ppm_per_s * elapsed


@pytest.mark.parametrize(
    ("model", "rms_us", "rate_ppm"),
    [("exponential", 2.0, 0.5), ("reads 1 ms", 25.0, 1.5), ("reads 16 ms", 60.0, 3.0)],
)
@pytest.mark.parametrize("seed", [11, 12])
def test_envelope_recovers_rate_and_line(model: str, rms_us: float, rate_ppm: float, seed: int):
    trace = simulate(MODEL[model], seed, 180.0)
    estimator = EnvelopeClockEstimator()
    locked = []
    for fc_us, arrival, truth in zip(trace.fc_time_us, trace.arrival, trace.true_obc):
        estimator.observe(fc_us, arrival)
        if estimator.state.locked:
            locked.append((estimator.to_obc(fc_us) - truth - trace.min_delay_s) * 1e6)
    state = estimator.state
    assert len(locked) > 0.8 * len(trace.arrival)
    assert rms(locked) < rms_us
    assert state.rate_ppm == pytest.approx(true_rate_ppm(trace, -1), abs=rate_ppm)
    assert (state.steps, state.reinits, state.rejected) == (0, 0, 0)
    assert state.lock_time_s >= EnvelopeClockEstimator.LOCK_SPAN_S
    assert 0 < state.uncertainty_s < 2 * rms_us * 1e-6


@pytest.mark.parametrize("model", ["exponential", "reads 1 ms"])
def test_state_is_a_pure_read(model: str, clock: str):
    """A dashboard asks for the state four times a second; a replay of the same packets asks
    once at the end. Both must see the same state (verify's recording replays identically)."""
    trace = simulate(MODEL[model], 3, 30.0, drift_ppm_per_min=30.0)
    watched, unwatched = make_estimator(clock), make_estimator(clock)
    for index, (fc_us, arrival) in enumerate(zip(trace.fc_time_us, trace.arrival)):
        watched.observe(fc_us, arrival)
        unwatched.observe(fc_us, arrival)
        seen = watched.state
        if index % 7 == 0:
            fresh = copy.deepcopy(unwatched).state
            assert same(fresh, seen), (index, fresh, seen)


def same(a: ClockState, b: ClockState) -> bool:
    """Equal field by field, NaN equal to NaN."""
    return all(
        x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))
        for x, y in zip(dataclasses.astuple(a), dataclasses.astuple(b))
    )


def test_envelope_state_before_any_packet():
    state = EnvelopeClockEstimator().state
    assert not state.locked and math.isnan(state.offset_s) and state.updates == 0
    assert EnvelopeClockEstimator().to_obc(123) is None


def test_envelope_reset_starts_over_on_the_new_epoch():
    first = simulate(MODEL["reads 1 ms"], 3, 30.0)
    estimator = EnvelopeClockEstimator()
    envelope_errors(estimator, first)
    assert estimator.state.locked
    estimator.reset()  # the FC rebooted: its clock restarts, the mapping is another
    assert not estimator.state.locked and estimator.to_obc(0) is None
    second = simulate(MODEL["reads 1 ms"], 4, 60.0)
    errors = envelope_errors(estimator, second)
    state = estimator.state
    assert state.locked and state.steps == 0
    assert state.rate_ppm == pytest.approx(true_rate_ppm(second, -1), abs=1.5)
    assert rms(errors[-10_000:]) < 25.0


def splice_step(trace: ClockTrace, at: int, step_s: float) -> None:
    """The OBC clock jumps by `step_s` before packet `at`: arrivals and truth both move."""
    for i in range(at, len(trace.arrival)):
        trace.arrival[i] += step_s
        trace.true_obc[i] += step_s


STEPS_1MS = [(-0.05, 0.06), (-0.0005, 0.2), (0.05, 1.2), (0.001, 1.2), (2.0, 1.2)]
STEPS_16MS = [(-0.05, 0.1), (-0.002, 0.2), (0.05, 1.2), (0.003, 1.2), (2.0, 1.2)]
"""(step, detected within): backward after a few reads, forward after STEP_READS buckets;
the smaller steps are just above the thresholds, which scale with the link's scatter."""


@pytest.mark.parametrize(
    ("model", "step_s", "within_s", "scatter_us", "rate_ppm"),
    [("exponential", -0.0003, 0.05, 50.0, 1.0)]  # without reads, even this small a step
    + [("reads 1 ms", *step, 500.0, 2.0) for step in STEPS_1MS]
    + [("reads 16 ms", *step, 2000.0, 5.0) for step in STEPS_16MS],
)
def test_obc_step_is_counted_and_leaves_no_wrong_offset(
    model: str, step_s: float, within_s: float, scatter_us: float, rate_ppm: float
):
    trace = simulate(MODEL[model], 5, 150.0)
    at = len(trace.arrival) // 2
    splice_step(trace, at, step_s)
    estimator = EnvelopeClockEstimator()
    envelope_errors(estimator, trace, 0, at)
    assert estimator.state.locked
    after, rate_errors = [], []
    for start in range(at, len(trace.arrival), 2000):  # the rate is kept through the step
        after += envelope_errors(estimator, trace, start, start + 2000)
        last = min(start + 1999, len(trace.arrival) - 1)
        rate_errors.append(estimator.state.rate_ppm - true_rate_ppm(trace, last))
    assert max(map(abs, rate_errors)) < rate_ppm
    state = estimator.state
    assert (state.steps, state.reinits) == (1, 1)
    # Packets before the step is certain carry the old mapping; none after it does: the
    # offset restarts within the link's scatter and settles as if nothing happened.
    detected = next(i for i, e in enumerate(after) if abs(e) < abs(step_s) * 1e6 / 2)
    assert trace.arrival[at + detected] - trace.arrival[at] <= within_s
    assert max(abs(e) for e in after[detected:]) < scatter_us
    assert rms(after[-20_000:]) < scatter_us / 20


def test_step_below_the_thresholds_passes_as_a_change_of_delay():
    trace = simulate(MODEL["reads 16 ms"], 5, 150.0)
    at = len(trace.arrival) // 2
    splice_step(trace, at, 0.001)  # under 8 × the median height of 16 ms reads
    estimator = EnvelopeClockEstimator()
    envelope_errors(estimator, trace, 0, at)
    after = envelope_errors(estimator, trace, at)
    assert estimator.state.steps == 0
    assert max(abs(e) for e in after) < 1000.0 + 150.0  # never off by more than the step
    assert rms(after[-10_000:]) < 100.0  # and followed within a window


def test_obc_stall_delivering_a_second_in_one_read_is_not_a_step():
    trace = simulate(MODEL["reads 1 ms"], 6, 120.0)
    at = len(trace.arrival) // 2
    stall = range(at, at + 800)  # 1.5 s of packets wait and arrive in one read
    for i in stall:
        trace.arrival[i] = trace.arrival[stall[-1]]
    estimator = EnvelopeClockEstimator()
    errors = envelope_errors(estimator, trace)
    assert estimator.state.steps == 0
    assert max(abs(e) for e in errors[stall[-1] :]) < 100.0


def test_lone_early_arrivals_are_outliers_not_steps():
    trace = simulate(MODEL["reads 1 ms"], 7, 120.0)
    spikes = range(len(trace.arrival) // 2, len(trace.arrival), 1500)  # ~3 s apart
    for i in spikes:
        trace.arrival[i] = trace.arrival[i - 1] - 0.0002  # stamped before the one before
    estimator = EnvelopeClockEstimator()
    errors = envelope_errors(estimator, trace)
    state = estimator.state
    assert (state.steps, state.rejected) == (0, len(spikes) - 1)  # the last is still pending
    assert max(abs(e) for e in errors[spikes[0] :]) < 100.0


def test_bad_input_is_counted_and_changes_nothing():
    trace = simulate(MODEL["reads 1 ms"], 8, 20.0)
    estimator = EnvelopeClockEstimator()
    envelope_errors(estimator, trace)
    last_fc, last_arrival = trace.fc_time_us[-1], trace.arrival[-1]
    before = (estimator.to_obc(last_fc + 5000), estimator.state)
    estimator.observe(last_fc + 2000, math.nan)
    estimator.observe(last_fc + 2000, math.inf)
    estimator.observe(last_fc, last_arrival + 0.002)  # the same FC time again
    estimator.observe(last_fc - 2000, last_arrival + 0.002)  # FC time going backwards
    assert estimator.state.rejected == 4
    assert (estimator.to_obc(last_fc + 5000), estimator.state) == (
        before[0],
        dataclasses.replace(before[1], rejected=4),
    )


def test_nan_first_packet_does_not_anchor():
    estimator = EnvelopeClockEstimator()
    estimator.observe(1000, math.nan)
    assert estimator.to_obc(1000) is None and estimator.state.rejected == 1
    estimator.observe(3000, 10.0)
    assert estimator.to_obc(3000) == 10.0


def test_memory_stays_bounded_over_a_long_run():
    trace = simulate(MODEL["all, 16 ms"], 9, 1200.0)
    estimator = EnvelopeClockEstimator()
    most = 0
    for i, (fc_us, arrival) in enumerate(zip(trace.fc_time_us, trace.arrival)):
        estimator.observe(fc_us, arrival)
        if i % 500 == 0:
            most = max(most, estimator.points)
            assert len(estimator._window.hull) <= len(estimator._window)
    window_s = EnvelopeClockEstimator.WINDOW_S[1]
    bound = window_s / EnvelopeClockEstimator.BUCKET_S + 2 + EnvelopeClockEstimator._PENDING_CAP
    assert 100 < most <= bound  # the window filled, and never grew past its bound


def test_far_from_zero_clocks_keep_their_precision():
    """A year of FC uptime and an OBC clock at 1e7 s change the answer by nanoseconds."""
    trace = simulate(MODEL["reads 1 ms"], 10, 60.0)
    near = envelope_errors(EnvelopeClockEstimator(), trace)
    trace.fc_time_us = [t + 2**45 for t in trace.fc_time_us]
    trace.arrival = [t + 1e7 for t in trace.arrival]
    trace.true_obc = [t + 1e7 for t in trace.true_obc]
    far = envelope_errors(EnvelopeClockEstimator(), trace)
    assert max(abs(a - b) for a, b in zip(near, far)) < 0.05


def test_sliding_hull_matches_a_hull_built_from_scratch():
    rng = random.Random(5)
    for trial in range(100):
        window = SlidingLowerHull()
        u = 0
        for _ in range(300):
            u += rng.randint(1, 5)
            curve = 0.01 * u if trial % 2 else -2e-5 * u * u
            window.append((u, rng.random() * 10 + curve))
            if rng.random() < 0.3:
                window.drop_before(u - rng.randint(5, 200))
            assert window.hull == SlidingLowerHull(window.points).hull
            assert all(u >= window.points[0][0] for u, _ in window.hull)


def test_estimators_by_name():
    assert ESTIMATORS == (*ONE_WAY_ESTIMATORS, "twoway") == ("envelope", "kalman", "twoway")
    assert isinstance(make_estimator(), EnvelopeClockEstimator)
    assert isinstance(make_estimator("kalman"), KalmanClockEstimator)
    assert isinstance(StateDecoder().clock, EnvelopeClockEstimator)
    assert isinstance(StateDecoder("kalman").clock, KalmanClockEstimator)
    with pytest.raises(UsageError, match="unknown clock estimator 'ntp': choose one of envelope"):
        make_estimator("ntp")


def _inner(estimator: EnvelopeClockEstimator) -> dict:
    """Everything the estimator holds, hull and queues as lists."""
    held = {}
    for name, value in vars(estimator).items():
        if isinstance(value, SlidingLowerHull):
            value = (list(value.points), list(value.hull))
        elif isinstance(value, deque):
            value = list(value)
        held[name] = value
    return held


def _disturbed(model: str, seed: int, seconds: float) -> ClockTrace:
    """A trace with everything the envelope decides on spliced in: an OBC step back and
    one forward, a stall, lone early arrivals, and bad input."""
    trace = simulate(MODEL[model], seed, seconds, drift_ppm_per_min=30.0)
    count = len(trace.arrival)
    splice_step(trace, count // 3, -0.05)
    splice_step(trace, 2 * count // 3, 0.05)
    stall = range(count // 2, count // 2 + 800)
    for i in stall:
        trace.arrival[i] = trace.arrival[stall[-1]]
    for i in range(count // 4, count, 1500):
        trace.arrival[i] = trace.arrival[i - 1] - 0.0002
    for i in range(count // 5, count, 2100):
        trace.arrival[i] = math.nan
    for i in range(count // 6, count, 2500):
        trace.fc_time_us[i] = trace.fc_time_us[i - 1]  # an FC time again
    return trace


@pytest.mark.parametrize(
    ("model", "seed"), [("exponential", 20), ("reads 1 ms", 21), ("reads 16 ms", 22)]
)
def test_track_says_what_observe_and_to_obc_say(model: str, seed: int):
    """The batch path (the columnar decoder's) gives the very floats, and leaves the very
    state, of the per-point path, through steps, stalls, outliers, bad input and resets."""
    np = pytest.importorskip("numpy", reason="track takes NumPy arrays")
    trace = _disturbed(model, seed, 150.0)
    fc_us = np.array(trace.fc_time_us, np.int64)
    arrival = np.array(trace.arrival)
    at_us = np.stack([fc_us - 2 * PERIOD_US, fc_us - PERIOD_US, fc_us + 7], axis=1)
    one, batch = EnvelopeClockEstimator(), EnvelopeClockEstimator()
    expected = []
    rng = random.Random(seed)
    start = 0
    reset_at = len(fc_us) * 4 // 5
    for index, (fc, t) in enumerate(zip(fc_us.tolist(), arrival.tolist())):
        if index == reset_at:
            one.reset()
        one.observe(fc, t)
        expected.append([one.to_obc(at) for at in at_us[index].tolist()])
    got = []
    while start < len(fc_us):
        end = min(start + rng.choice([1, 2, 50, 700, 5000]), len(fc_us))
        if start < reset_at < end:
            end = reset_at
        if start == reset_at:
            batch.reset()
        got.append(batch.track(fc_us[start:end], arrival[start:end], at_us[start:end]))
        start = end
    expected_array = np.array([[math.nan if t is None else t for t in row] for row in expected])
    assert np.array_equal(np.concatenate(got), expected_array, equal_nan=True)
    assert same(one.state, batch.state) and one.state.steps >= 2
    assert _inner(one) == _inner(batch)
