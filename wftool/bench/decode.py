"""`wftool bench decode`: decoder throughput (bytes in, frames out, on one core) and memory
over a long replay, per-frame and columnar, against pymavlink (docs/bench.md).
"""

from __future__ import annotations

import itertools
import math
import random
import struct
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import UsageError
from wftool.fsp import SensorFrame, StateDecoder, StatePacket, StreamStats
from wftool.fsp.encoder import encode_state
from wftool.fsp.packets import rc_values
from wftool.stats import median

REALTIME_PACKETS_PER_S = 525  # 1049 Hz of frames, two per packet (spec §7)
FRAME_PERIOD_US = 953


@dataclass(frozen=True)
class DecodeBenchResult:
    packets: int
    frames: int
    bytes: int
    seconds: float
    errors: int
    lost_frames: int
    stats: StreamStats | None = None
    """The decoder's totals (FSP paths), to show that the paths agree."""
    result_bytes: int = 0
    """What the decoded result holds (columnar: the arrays)."""

    @property
    def packets_per_s(self) -> float:
        return self.packets / self.seconds

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.seconds

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


GYRO_SCALE = 0.0609756
"""°/s per count at ±2000 °/s."""
ACC_1G = 2048
"""Counts per g at ±16 g."""
GYRO_NOISE = 2.6
"""Counts RMS: the BMI270's 0.007 °/s/√Hz over the ~500 Hz the stream carries."""
ACC_NOISE = 7.4
"""Counts RMS: the BMI270's 160 µg/√Hz over ~500 Hz."""
RPM_NOISE = 40.0
"""RPM RMS: one step of bidirectional DShot's period (1 µs of ~480 µs at 18,000 RPM)."""
RC_STEPS_PER_S = 50.0
"""How often a stick moves by a count or two (an RC link's update rate, roughly)."""


class RealisticFlight:
    """Frames as a hovering, gently manoeuvring quadrotor sends them: the virtual FC's
    motion (`sitl.session.Motion`: roll, pitch and yaw) with the BMI270's datasheet noise on
    gyro and accelerometer, four motors near 18,000 RPM following the manoeuvre with
    DShot's RPM jitter, sticks that move now and then, and a slowly sagging battery.

    The other stream (`_frame`, "sweeping") moves every value, the RC channels included,
    by hundreds of counts every second, smoothly and without noise.
    """

    def __init__(self, seed: int = 1) -> None:
        from wftool.sitl.session import Motion

        self._state = Motion().state
        self._random = random.Random(seed)
        self._rc = [1500, 1500, 1500, 1300, 1000, 2000]

    def frame(self, t_us: int) -> SensorFrame:
        gauss, t = self._random.gauss, t_us * 1e-6
        values = struct.unpack("<18d", self._state(t, t))
        rates, accel, quaternion = values[1:4], values[4:7], values[7:11]
        gyro = [round(math.degrees(r) / GYRO_SCALE + gauss(0, GYRO_NOISE)) for r in rates]
        acc = [round(-a / 9.80665 * ACC_1G + gauss(0, ACC_NOISE)) for a in accel]
        attitude = [max(-32768, min(32767, round(q * 32767))) for q in quaternion]
        if self._random.random() < RC_STEPS_PER_S * FRAME_PERIOD_US * 1e-6:
            stick = self._random.randrange(4)
            step = self._random.choice((-2, -1, 1, 2))
            self._rc[stick] = max(1000, min(2000, self._rc[stick] + step))
        swing = 3000 * math.sin(2 * math.pi * 0.4 * t)  # the roll manoeuvre, felt by motors
        rpm = [round(18000 + swing * (-1) ** m + gauss(0, RPM_NOISE)) for m in range(4)]
        vbat = round(1620 - 0.05 * t + gauss(0, 0.7))
        (ax, ay, az), (gx, gy, gz), (qw, qx, qy, qz) = acc, gyro, attitude
        m1, m2, m3, m4 = rpm
        return SensorFrame(
            t_us % 2**32, (ax, ay, az), ACC_1G, GYRO_SCALE, (gx, gy, gz), (qw, qx, qy, qz),
            rc_values(self._rc), (m1, m2, m3, m4), vbat,
        )  # fmt: skip


STREAMS = ("realistic", "sweeping")
"""The bench streams: `RealisticFlight`, and `_frame` (every value sweeping, no noise)."""


def write_capture(path: Path, packets: int, tunnel: bool, stream: str = "sweeping") -> None:
    """A capture file of `packets` consecutive state packets of a steady stream."""
    mavlink = bytes(64) if tunnel else None
    frame = RealisticFlight().frame if stream == "realistic" else _frame
    t_us = 4_000_000_000  # wraps after ~5 min, so a 10 min replay crosses it
    with path.open("wb") as capture:
        for seq in range(packets):
            frames = (frame(t_us), frame(t_us + FRAME_PERIOD_US))
            tx = (t_us + FRAME_PERIOD_US + 120) % 2**32
            capture.write(encode_state(StatePacket(tx, frames, seq % 2**24, True, 0, mavlink)))
            t_us += 2 * FRAME_PERIOD_US


def run_decode_bench(
    capture: Path, chunk_bytes: int, aligned: bool = True, kept: list[StatePacket] | None = None
) -> DecodeBenchResult:
    """Replay `capture` once through a fresh decoder; `aligned` stamps the reads, so OBC
    times are estimated too; every packet goes into `kept` if given, as an analysis that
    wanted them all would keep them (for the memory figure)."""
    decoder = StateDecoder()
    frames = 0
    clock = time.perf_counter
    _, arrivals = _reads(capture.stat().st_size, chunk_bytes)
    with capture.open("rb", buffering=0) as stream:
        start = clock()
        for arrival in arrivals:
            packets = decoder.feed(stream.read(chunk_bytes), arrival if aligned else None)
            for packet in packets:
                for _frame_out in packet.frames:
                    frames += 1
            if kept is not None:
                kept += packets
        elapsed = clock() - start
    stats = decoder.stats
    return DecodeBenchResult(
        packets=stats.packets,
        frames=frames,
        bytes=stats.bytes,
        seconds=elapsed,
        errors=stats.errors,
        lost_frames=stats.lost_frames,
        stats=stats,
    )


def _reads(size: int, chunk_bytes: int) -> tuple[list[int], list[float]]:
    """The read sizes and arrival stamps `run_decode_bench` uses for a file of `size` bytes."""
    sizes = [chunk_bytes] * (size // chunk_bytes) + (
        [size % chunk_bytes] if size % chunk_bytes else []
    )
    step = chunk_bytes / (REALTIME_PACKETS_PER_S * 118)  # real-time arrival stamps
    arrivals = list(itertools.accumulate([step] * len(sizes)))
    return sizes, arrivals


def run_columnar_bench(capture: Path, chunk_bytes: int, aligned: bool) -> DecodeBenchResult:
    """Read `capture` and decode it into columns, with the reads `run_decode_bench` makes;
    `aligned` passes their arrival stamps, so OBC times are estimated too."""
    from wftool.fsp.columns import decode_columns

    sizes, arrivals = _reads(capture.stat().st_size, chunk_bytes)
    clock = time.perf_counter
    start = clock()
    columns = decode_columns(capture.read_bytes(), sizes, arrivals if aligned else None)
    elapsed = clock() - start
    stats = columns.stats
    return DecodeBenchResult(
        packets=stats.packets,
        frames=len(columns),
        bytes=stats.bytes,
        seconds=elapsed,
        errors=stats.errors,
        lost_frames=stats.lost_frames,
        stats=stats,
        result_bytes=columns.nbytes,
    )


def write_mavlink_stream(path: Path, samples: int) -> None:
    """`samples` MAVLink 2 HIGHRES_IMU messages of the synthetic flight, by pymavlink."""
    try:
        from pymavlink.dialects.v20 import common as mavlink2
    except ImportError:
        raise UsageError(
            "bench decode compares with pymavlink: pip install 'wftool[mavlink]'"
        ) from None
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    t_us = 4_000_000_000
    with path.open("wb") as stream:
        for _ in range(samples):
            f = _frame(t_us)
            message = mav.highres_imu_encode(
                t_us, *(a / 2048 * 9.80665 for a in f.acc), *(math.radians(g) for g in f.gyro_dps),
                0.0, 0.0, 0.0, 1013.25, 0.0, 0.0, 25.0, 0x3F,
            )  # fmt: skip
            stream.write(message.pack(mav))
            t_us += FRAME_PERIOD_US


def run_mavlink_bench(stream_path: Path, chunk_bytes: int) -> DecodeBenchResult:
    """pymavlink's parser over `stream_path` in reads of `chunk_bytes`: messages out."""
    from pymavlink.dialects.v20 import common as mavlink2

    parser = mavlink2.MAVLink(None)
    messages = 0
    clock = time.perf_counter
    with stream_path.open("rb", buffering=0) as stream:
        start = clock()
        while chunk := stream.read(chunk_bytes):
            for message in parser.parse_buffer(chunk) or ():
                if message.get_type() == "HIGHRES_IMU":
                    messages += 1
        elapsed = clock() - start
    return DecodeBenchResult(
        packets=messages,
        frames=messages,
        bytes=stream_path.stat().st_size,
        seconds=elapsed,
        errors=parser.total_receive_errors,
        lost_frames=0,
    )


def traced_peak_bytes(run: Callable[[], object]) -> int:
    """The most memory Python and NumPy held at once during `run()` (tracemalloc), above
    what was held before. Tracing slows allocation: time runs without it."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before, _ = tracemalloc.get_traced_memory()
        run()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak - before


PER_FRAME = "per-frame API: FC times only"
PER_FRAME_ALIGNED = "per-frame API: + OBC clock alignment"
COLUMNAR = "columnar: FC times only"
COLUMNAR_ALIGNED = "columnar: + OBC clock alignment"
MAVLINK = "pymavlink: HIGHRES_IMU, 1 sample each"
LIKE_FOR_LIKE = {
    PER_FRAME: PER_FRAME,
    PER_FRAME_ALIGNED: PER_FRAME_ALIGNED,
    COLUMNAR: PER_FRAME,
    COLUMNAR_ALIGNED: PER_FRAME_ALIGNED,
    MAVLINK: PER_FRAME,
}
"""Each path's per-frame reference: the one that works out the same times."""


@dataclass(frozen=True)
class DecodeComparison:
    """Every path's runs over the same stream, and their memory."""

    frames: int
    capture_bytes: int
    runs: dict[str, list[DecodeBenchResult]]
    """Path → its runs; the paths took turns, so noise hits them alike."""
    memory: dict[str, int]
    """What ran → tracemalloc peak (bytes) of one run of its own."""
    same_times: bool
    """Whether the columns' FC and OBC times are exactly the per-frame decoder's."""

    def best(self, path: str) -> float:
        return max(r.frames_per_s for r in self.runs[path])

    def median(self, path: str) -> float:
        return median(r.frames_per_s for r in self.runs[path])

    @property
    def agree(self) -> bool:
        """Whether every FSP run ended with the same decoder totals."""
        totals = [r.stats for runs in self.runs.values() for r in runs if r.stats is not None]
        return all(stats == totals[0] for stats in totals)


def compare_decoders(
    minutes: float, chunk_bytes: int, tunnel: bool, repeat: int
) -> DecodeComparison:
    """Write the synthetic stream as FSP and as MAVLink, then time each path `repeat` times,
    in turns, and measure the memory of the FSP paths."""
    from wftool.extras import require
    from wftool.fsp.columns import WHAT

    # The columnar path needs the analysis extra: say so before minutes of setup.
    require("analysis", "numpy", what=WHAT)
    packets = int(minutes * 60 * REALTIME_PACKETS_PER_S)
    with tempfile.TemporaryDirectory(prefix="wftool-bench-") as scratch:
        capture, imu = Path(scratch) / "capture.fsp", Path(scratch) / "imu.mavlink"
        write_mavlink_stream(imu, 2 * packets)
        write_capture(capture, packets, tunnel)
        paths: dict[str, Callable[[], DecodeBenchResult]] = {
            PER_FRAME: lambda: run_decode_bench(capture, chunk_bytes, aligned=False),
            PER_FRAME_ALIGNED: lambda: run_decode_bench(capture, chunk_bytes),
            COLUMNAR: lambda: run_columnar_bench(capture, chunk_bytes, aligned=False),
            COLUMNAR_ALIGNED: lambda: run_columnar_bench(capture, chunk_bytes, aligned=True),
            MAVLINK: lambda: run_mavlink_bench(imu, chunk_bytes),
        }
        runs: dict[str, list[DecodeBenchResult]] = {path: [] for path in paths}
        for _ in range(repeat):
            for path, run in paths.items():
                runs[path].append(run())
        memory = {
            "per-frame API, frames walked, none kept": traced_peak_bytes(paths[PER_FRAME_ALIGNED]),
            "per-frame API, every packet kept": traced_peak_bytes(
                lambda: run_decode_bench(capture, chunk_bytes, kept=[])
            ),
            "columnar, + OBC clock alignment": traced_peak_bytes(paths[COLUMNAR_ALIGNED]),
        }
        return DecodeComparison(
            2 * packets, capture.stat().st_size, runs, memory, _same_times(capture, chunk_bytes)
        )


def _same_times(capture: Path, chunk_bytes: int) -> bool:
    """Whether the columns hold exactly the FC and OBC times the per-frame decoder gives."""
    import numpy as np

    from wftool.fsp.columns import decode_columns

    kept: list[StatePacket] = []
    run_decode_bench(capture, chunk_bytes, kept=kept)
    frames = [frame for packet in kept for frame in packet.frames]
    sizes, arrivals = _reads(capture.stat().st_size, chunk_bytes)
    columns = decode_columns(capture.read_bytes(), sizes, arrivals)
    obc_time = np.array([math.nan if f.obc_time is None else f.obc_time for f in frames])
    return columns.time_us.tolist() == [f.time_us for f in frames] and np.array_equal(
        columns.obc_time, obc_time, equal_nan=True
    )
