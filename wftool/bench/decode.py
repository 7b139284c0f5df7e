"""Decoder throughput: bytes in → frames out on one core, and memory over a long replay.

The stream is a synthetic flight (E1 on, moving values) written once to a capture file;
each replay reads that file in chunks, as `wftool replay` or an OBC reading a UART would,
and feeds them with real-time arrival stamps. Reading, `StateDecoder.feed` and walking
the frames are timed; memory is sampled along the way (the replay holds one chunk).
"""

from __future__ import annotations

import math
import resource
import time
from dataclasses import dataclass
from pathlib import Path

from wftool.fsp import SensorFrame, StateDecoder, StatePacket
from wftool.fsp.encoder import encode_state

REALTIME_PACKETS_PER_S = 525  # 1049 Hz of frames, two per packet (spec §7)
FRAME_PERIOD_US = 953


@dataclass(frozen=True)
class DecodeBenchResult:
    packets: int
    frames: int
    bytes: int
    seconds: float
    rss_kib: tuple[int, ...]
    """Peak RSS sampled at 0 %, 25 %, 50 %, 75 % and 100 % of the replay."""
    errors: int
    lost_frames: int

    @property
    def packets_per_s(self) -> float:
        return self.packets / self.seconds

    @property
    def realtime_factor(self) -> float:
        return self.packets_per_s / REALTIME_PACKETS_PER_S


def _frame(t_us: int) -> SensorFrame:
    phase = t_us * 1e-6
    s, c = math.sin(phase * 6.0), math.cos(phase * 6.0)
    return SensorFrame(
        t_us % 2**32,
        (int(300 * s), int(-200 * c), 2048 + int(50 * s)),
        2048,
        0.0609756,
        (int(1000 * c), int(-800 * s), int(120 * s)),
        (int(32767 * c), int(20000 * s), 0, 0),
        (1500 + int(400 * s), 1500, 1500, 1300, 1000, 2000),
        (21000 + int(900 * s), 21500, 20900, 21300),
        1587,
    )


def write_capture(path: Path, packets: int, tunnel: bool) -> None:
    """A capture file of `packets` consecutive state packets of a steady stream."""
    mavlink = bytes(64) if tunnel else None
    t_us = 4_000_000_000  # wraps after ~5 min, so a 10 min replay crosses it
    with path.open("wb") as capture:
        for seq in range(packets):
            frames = (_frame(t_us), _frame(t_us + FRAME_PERIOD_US))
            tx = (t_us + FRAME_PERIOD_US + 120) % 2**32
            capture.write(encode_state(StatePacket(tx, frames, seq % 2**24, True, 0, mavlink)))
            t_us += 2 * FRAME_PERIOD_US


def _rss_kib() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def run_decode_bench(capture: Path, chunk_bytes: int) -> DecodeBenchResult:
    """Replay `capture` once through a fresh decoder."""
    size = capture.stat().st_size
    checkpoints = [size * q // 4 for q in range(1, 4)]
    decoder = StateDecoder()
    rss = [_rss_kib()]
    frames = 0
    clock = time.perf_counter
    arrival_step = chunk_bytes / (REALTIME_PACKETS_PER_S * 118)  # real-time arrival stamps
    arrival = 0.0
    with capture.open("rb", buffering=0) as stream:
        start = clock()
        while chunk := stream.read(chunk_bytes):
            arrival += arrival_step
            for packet in decoder.feed(chunk, arrival):
                for _frame_out in packet.frames:
                    frames += 1
            if checkpoints and decoder.stats.bytes >= checkpoints[0]:
                checkpoints.pop(0)
                rss.append(_rss_kib())
        elapsed = clock() - start
    rss.append(_rss_kib())
    stats = decoder.stats
    return DecodeBenchResult(
        packets=stats.packets,
        frames=frames,
        bytes=stats.bytes,
        seconds=elapsed,
        rss_kib=tuple(rss),
        errors=stats.errors,
        lost_frames=stats.lost_frames,
    )
