"""`wftool bench stream`: the stream on the virtual FC at each rate: how fast it holds, what
verify costs, how soon a frame is out (docs/bench.md).
"""

from __future__ import annotations

import io
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from wftool.fsp import StatePacket
from wftool.sitl.session import VirtualFcSession
from wftool.stats import Distribution
from wftool.verify.dashboard import render
from wftool.verify.monitor import StreamSummary
from wftool.verify.session import VerifySession


@dataclass(frozen=True)
class RateFigures:
    rate_hz: int
    expected_frames_per_s: float
    frames_per_s: float
    lost_frames: int
    fc_drops: int
    errors: int
    fc_interval: Distribution | None
    arrival_interval: Distribution | None

    @property
    def held(self) -> bool:
        """Nothing lost, dropped or rejected."""
        return self.lost_frames == 0 and self.fc_drops == 0 and self.errors == 0


@dataclass(frozen=True)
class StreamBenchResult:
    seconds: float
    rates: tuple[RateFigures, ...]
    cpu_percent: float
    """CPU time of the verify process over wall time, at the first rate."""
    latency_ms: tuple[float, float]
    """P50 and P99 from a read returning to its frames delivered, at the first rate."""

    @property
    def highest_held(self) -> RateFigures | None:
        """The rate with the most frames/s held without loss."""
        held = [r for r in self.rates if r.held]
        return max(held, key=lambda r: r.expected_frames_per_s) if held else None


def run_stream_bench(binary: Path, rates: Sequence[int], seconds: float) -> StreamBenchResult:
    figures = []
    cpu_percent = float("nan")
    latency = (float("nan"), float("nan"))
    screen = Console(file=io.StringIO(), width=100)
    with tempfile.TemporaryDirectory(prefix="wftool-bench-") as scratch:
        for index, rate in enumerate(rates):
            workdir = Path(scratch) / f"rate-{rate}"
            with VirtualFcSession(binary, workdir, rate_hz=rate, port_base=None) as fc:
                expected = fc.expected_rate_hz
                session = VerifySession(fc.fsp_url, duration_s=seconds, expected_rate_hz=expected)
                latencies: list[float] = []

                def draw(summary: StreamSummary, session: VerifySession = session) -> None:
                    result = session.result(summary)
                    screen.print(render(result.summary, result.latest, result.verdict))
                    screen.file = io.StringIO()  # keep memory flat

                def timed(
                    _packets: Sequence[StatePacket], t: float, into: list[float] = latencies
                ) -> None:
                    into.append(time.monotonic() - t)  # a read returned at t: its frames are out

                cpu_start, wall_start = time.process_time(), time.monotonic()
                summary = session.run(on_refresh=draw, on_packets=timed).summary
                cpu = time.process_time() - cpu_start
                wall = time.monotonic() - wall_start
            figures.append(
                RateFigures(
                    rate_hz=rate,
                    expected_frames_per_s=expected,
                    frames_per_s=summary.frame_rate_hz,
                    lost_frames=summary.lost_frames,
                    fc_drops=summary.fc_drops,
                    errors=summary.errors,
                    fc_interval=summary.fc_interval,
                    arrival_interval=summary.arrival_interval,
                )
            )
            if index == 0:
                cpu_percent = 100.0 * cpu / wall
                spread = Distribution.of(1e6 * v for v in latencies)
                if spread is not None:
                    latency = (spread.p50_us / 1e3, spread.p99_us / 1e3)
    return StreamBenchResult(seconds, tuple(figures), cpu_percent, latency)
