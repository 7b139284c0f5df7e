"""Decoder throughput: bytes in → frames out on one core, and memory over a long replay.

The stream is a synthetic flight (E1 on, moving values, real-time arrival stamps) produced
chunk by chunk outside the timed region, so only `StateDecoder.feed` and walking its
frames are measured, and the replay never holds more than one chunk.
"""

from __future__ import annotations

import math
import resource
import time
from collections.abc import Iterator
from dataclasses import dataclass

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


def synthetic_stream(packets: int, chunk_bytes: int, tunnel: bool) -> Iterator[tuple[bytes, float]]:
    """(chunk, OBC arrival time) pairs of a steady stream, as a UART read would return them."""
    pending = bytearray()
    mavlink = bytes(64) if tunnel else None
    t_us = 4_000_000_000  # wraps after ~5 min, so a 10 min replay crosses it
    for seq in range(packets):
        tx = t_us + FRAME_PERIOD_US + 120
        packet = StatePacket(
            tx % 2**32,
            (_frame(t_us), _frame(t_us + FRAME_PERIOD_US)),
            seq % 2**24,
            True,
            0,
            mavlink,
        )
        pending += encode_state(packet)
        t_us += 2 * FRAME_PERIOD_US
        if len(pending) >= chunk_bytes:
            yield bytes(pending), tx * 1e-6 + 0.001
            pending.clear()
    if pending:
        yield bytes(pending), t_us * 1e-6


def _rss_kib() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def run_decode_bench(minutes: float, chunk_bytes: int, tunnel: bool) -> DecodeBenchResult:
    packets = int(minutes * 60 * REALTIME_PACKETS_PER_S)
    checkpoints = {int(packets * q / 4) for q in range(1, 4)}
    decoder = StateDecoder()
    rss = [_rss_kib()]
    elapsed = 0.0
    frames = 0
    clock = time.perf_counter
    for chunk, arrival in synthetic_stream(packets, chunk_bytes, tunnel):
        start = clock()
        for packet in decoder.feed(chunk, arrival):
            for _frame_out in packet.frames:
                frames += 1
        elapsed += clock() - start
        done = decoder.stats.packets
        if checkpoints and done >= min(checkpoints):
            checkpoints.discard(min(checkpoints))
            rss.append(_rss_kib())
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
