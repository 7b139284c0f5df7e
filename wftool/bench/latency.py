"""`wftool bench latency`: true clock error and true latency on the virtual FC, judged against
the SITL's own clock (`wftool.sitl.truth`; docs/bench.md).
"""

from __future__ import annotations

import math
import random
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from wftool.bench.clock import _p99_abs, _rms
from wftool.fsp import CommandPacket, FspReader, StateDecoder
from wftool.fsp.clock import EnvelopeClockEstimator
from wftool.fsp.estimators import ESTIMATORS
from wftool.fsp.schedule import DEFAULT_RATE_HZ
from wftool.fsp.twoway import RoundTrip, TwoWayClockEstimator
from wftool.sitl.session import VirtualFcSession
from wftool.sitl.truth import TrueClock
from wftool.stats import Distribution, quantile

COMMAND = (1500, 1500, 1500, 1000, 1000, 1000)
READ_TIMEOUT_S = 0.05
STEP_SETTLE_S = (EnvelopeClockEstimator.STEP_READS + 1) * EnvelopeClockEstimator.BUCKET_S
"""FC time after a re-anchor whose frames are not scored: the virtual FC's clock stood still
while the host caught up (a board's never does), and the envelope takes a step for a delay
until STEP_READS buckets after the one it fell in."""


@dataclass(frozen=True)
class EstimatorError:
    """One estimator's true error over the frames decoded once it was locked."""

    name: str
    lock_s: float
    """From the first packet to lock (NaN: never locked)."""
    frames: int
    rms_s: float
    """Against the true sample instant."""
    p99_s: float
    envelope_rms_s: float
    """One-way: against the true instant plus the true minimum delay (NaN for two-way)."""
    within_uncertainty: float | None = None
    """Two-way: the share of frames whose true error is within the reported uncertainty."""
    uncertainty_s: float | None = None
    """Two-way: the median uncertainty it reported."""
    settling_frames: int = 0
    """Frames after lock within STEP_SETTLE_S of a re-anchor: in none of the figures above."""


@dataclass(frozen=True)
class LatencyBenchResult:
    seconds: float
    rate_hz: int
    time_reply: bool
    packets: int
    frames: int
    errors: int
    lost_frames: int
    min_delay_s: float
    """The fastest packet: true send instant to read."""
    sample_to_frame: Distribution | None
    """True sample instant → decoded frame available."""
    send_to_frame: Distribution | None
    """True packet send instant (`tx_time_us`) → decoded frame available."""
    decode: Distribution | None
    """Read returned → its frames decoded."""
    estimators: tuple[EstimatorError, ...]
    round_trips: int
    rtt: Distribution | None
    round_trip_rejected: dict[str, int] = field(default_factory=dict)
    reanchors: int = 0
    """Times the SITL fell more than 50 ms behind the host clock and re-anchored."""


T = TypeVar("T")


@dataclass
class _Capture:
    """What the live run saw: its events in order, and each read's packets' FC times."""

    events: list[tuple[float, bytes | CommandPacket]] = field(default_factory=list)
    """(read time, the bytes read) and (OBC stamp, the command sent)."""
    reads: list[tuple[float, float, list[int], list[int]]] = field(default_factory=list)
    """(read time, decoded time, packet send FC times, frame FC times) per read."""


def _capture(
    url: str, seconds: float, decoder: StateDecoder, command_rate_hz: float | None
) -> _Capture:
    capture = _Capture()
    now = time.monotonic
    rng = random.Random(1)
    with FspReader(url, decoder=decoder) as reader:
        end = now() + seconds
        next_command = now()
        while (t := now()) < end:
            if command_rate_hz and t >= next_command:
                packet = reader.send_command(COMMAND, now=t)
                capture.events.append((t, packet))
                # a random phase: an OBC whose commands kept a fixed phase to the FC's FSP task
                # (only a SITL, sharing the host's clock, does) would always wait as long for it
                next_command = max(next_command + rng.uniform(0.5, 1.5) / command_rate_hz, t)
            data = reader.read_bytes(min(READ_TIMEOUT_S, max(0.0, next_command - now())))
            if not data:
                continue
            read_at = now()
            packets = decoder.feed(data, read_at)
            decoded_at = now()
            capture.events.append((read_at, data))
            if packets:
                sends = [_decoded(p.time_us) for p in packets]
                frames = [_decoded(f.time_us) for p in packets for f in p.frames]
                capture.reads.append((read_at, decoded_at, sends, frames))
    return capture


def _decoded(value: T | None) -> T:
    """A time the decoder sets on every packet and frame it delivers (with arrival times)."""
    assert value is not None
    return value


def _replay(
    name: str,
    capture: _Capture,
    true_obc: Callable[[int], float],
    min_delay_s: float,
    time_reply: bool,
    steps_us: Sequence[int] = (),
    on_round_trip: Callable[[RoundTrip], None] | None = None,
) -> EstimatorError:
    """The run's bytes and commands through a decoder with estimator `name`, scored but for
    the frames within STEP_SETTLE_S after the FC times `steps_us` (the re-anchors)."""
    decoder = StateDecoder(name, time_replies=time_reply)
    matcher = decoder.round_trips
    if matcher is not None:
        matcher.on_round_trip = on_round_trip
    clock = decoder.clock
    two_way = clock if isinstance(clock, TwoWayClockEstimator) else None
    errors: list[float] = []
    covered = 0
    uncertainties: list[float] = []
    first = lock = math.nan
    settle_us = STEP_SETTLE_S * 1e6
    settling = 0
    for t, payload in capture.events:
        if isinstance(payload, CommandPacket):
            if matcher is not None:
                matcher.sent(payload.seq, payload.tx_time_us, t)
            continue
        packets = decoder.feed(payload, t)
        if not packets:
            continue
        if first != first:
            first = t
        state = clock.state
        if not state.locked or (two_way is not None and not two_way.two_way.active):
            continue
        if lock != lock:
            lock = t - first
        for packet in packets:
            for frame in packet.frames:
                fc_us = _decoded(frame.time_us)
                if any(0 <= fc_us - step < settle_us for step in steps_us):
                    settling += 1
                    continue
                error = _decoded(frame.obc_time) - true_obc(fc_us)
                errors.append(error)
                if two_way is not None:
                    covered += abs(error) <= state.uncertainty_s
        if two_way is not None:
            uncertainties.append(state.uncertainty_s)
    return EstimatorError(
        name=name,
        lock_s=lock,
        frames=len(errors),
        rms_s=_rms(errors),
        p99_s=_p99_abs(errors),
        envelope_rms_s=math.nan if two_way else _rms([e - min_delay_s for e in errors]),
        within_uncertainty=covered / len(errors) if two_way and errors else None,
        uncertainty_s=quantile(sorted(uncertainties), 0.5) if uncertainties else None,
        settling_frames=settling,
    )


def _us(values_s: Sequence[float]) -> Distribution | None:
    return Distribution.of(1e6 * value for value in values_s)


def run_latency_bench(
    binary: Path,
    seconds: float = 60.0,
    rate_hz: int = DEFAULT_RATE_HZ,
    time_reply: bool = True,
    command_rate_hz: float = 50.0,
) -> LatencyBenchResult:
    """Stream from a fresh virtual FC for `seconds` (what it measures: docs/bench.md)."""
    with tempfile.TemporaryDirectory(prefix="wftool-bench-") as scratch:
        session = VirtualFcSession(
            binary, Path(scratch) / "fc", rate_hz=rate_hz, port_base=None,
            time_reply=time_reply,
        )  # fmt: skip
        with session:
            truth = TrueClock(session.fc.log_path)
            live = StateDecoder("twoway" if time_reply else None)
            capture = _capture(session.fsp_url, seconds, live, command_rate_hz)
            truth.refresh()
    end = time.monotonic()

    def true_obc(fc_time_us: int) -> float:
        return truth.instant(fc_time_us, end)

    sample_to_frame, send_to_frame, decode, delays = [], [], [], []
    for read_at, decoded_at, sends, frames in capture.reads:
        decode.append(decoded_at - read_at)
        for fc_us in sends:
            send_to_frame.append(decoded_at - true_obc(fc_us))
            delays.append(read_at - true_obc(fc_us))
        sample_to_frame += [decoded_at - true_obc(fc_us) for fc_us in frames]
    min_delay = min(delays, default=math.nan)
    rtts: list[float] = []
    names = [n for n in ESTIMATORS if time_reply or n != "twoway"]

    def collect(trip: RoundTrip) -> None:
        rtts.append(trip.rtt_s)

    steps = [anchor.fc_us for anchor in truth.anchors if anchor.reason != "start"]
    scored = tuple(
        _replay(name, capture, true_obc, min_delay, time_reply, steps, collect if two else None)
        for name in names
        for two in [name == "twoway"]
    )
    stats = live.stats
    rejected = {}
    if live.round_trips is not None and isinstance(live.clock, TwoWayClockEstimator):
        causes = {**live.round_trips.rejected}
        for cause, count in live.clock.rejected.items():
            causes[cause] += count
        rejected = {cause.value: count for cause, count in causes.items() if count}
    return LatencyBenchResult(
        seconds=seconds,
        rate_hz=rate_hz,
        time_reply=time_reply,
        packets=stats.packets,
        frames=stats.frames,
        errors=stats.errors,
        lost_frames=stats.lost_frames,
        min_delay_s=min_delay,
        sample_to_frame=_us(sample_to_frame),
        send_to_frame=_us(send_to_frame),
        decode=_us(decode),
        estimators=scored,
        round_trips=len(rtts),
        rtt=_us(rtts),
        round_trip_rejected=rejected,
        reanchors=len(steps),
    )
