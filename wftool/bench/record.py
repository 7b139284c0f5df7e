"""What recording costs: bytes and CPU per frame of the JSON and ROS 2 MCAP formats.

The synthetic flight of `bench decode` (E1 on, moving values, ~1049 frames/s) is fed
through the real verify path, as the live loop feeds it: one read per `chunk_bytes` with
real-time arrival stamps, each read recorded as an event, its packets decoded by a
`StreamMonitor` and recorded with a health snapshot every 100 ms. The same replay without
a recorder is the reference: a format's CPU is its run's process time minus the
reference's, so it counts the recorder alone (encoding, MCAP chunks, zstd, file writes).
Sizes are the files on disk after chunk compression, metadata.yaml included.

Reading back is timed too, in frames/s: `replay` (the recorded events through the
per-frame decoder and the monitor) and `recording_columns` (the events into NumPy columns,
with OBC times; needs the analysis extra).
"""

from __future__ import annotations

import importlib.util
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from wftool.bench.decode import REALTIME_PACKETS_PER_S, write_capture
from wftool.verify.monitor import StreamMonitor
from wftool.verify.recording import (
    RECORD_FORMATS,
    Event,
    Recorder,
    recording_columns,
    replay_recording,
)
from wftool.verify.ros2 import HealthSampler

PACKET_BYTES = 118  # a 116-byte state packet, COBS-framed


@dataclass(frozen=True)
class FormatFigures:
    name: str
    frames: int
    bytes: int
    cpu_s: float
    """Process CPU time of the recorder alone (the run minus the reference run)."""
    replay_frames_per_s: float
    columns_frames_per_s: float | None
    """None without NumPy."""

    @property
    def bytes_per_frame(self) -> float:
        return self.bytes / self.frames

    @property
    def cpu_us_per_frame(self) -> float:
        return 1e6 * self.cpu_s / self.frames

    @property
    def core_percent_at_1khz(self) -> float:
        """Share of one core spent recording 1000 frames/s."""
        return self.cpu_us_per_frame * 1000 / 1e6 * 100


@dataclass(frozen=True)
class RecordBenchResult:
    seconds: float
    chunk_bytes: int
    frames: int
    reference_cpu_s: float
    """Decoding and monitoring alone: the part every format shares."""
    formats: tuple[FormatFigures, ...]

    def format(self, name: str) -> FormatFigures:
        return next(f for f in self.formats if f.name == name)


def _replay(capture: bytes, chunk_bytes: int, recorder: Recorder | None) -> tuple[float, int]:
    """Process CPU time of one replay, and the frames decoded."""
    monitor = StreamMonitor("bench")
    sampler = HealthSampler(monitor)
    step = chunk_bytes / (REALTIME_PACKETS_PER_S * PACKET_BYTES)
    t = 1000.0
    start = time.process_time()
    monitor.connected(t)
    if recorder is not None:
        recorder.event(Event("connected", t))
    for offset in range(0, len(capture), chunk_bytes):
        t += step
        data = capture[offset : offset + chunk_bytes]
        if recorder is None:
            monitor.feed(data, t)
            continue
        recorder.event(Event("bytes", t, data))
        packets = monitor.feed(data, t)
        recorder.packets(packets, sampler.sample(packets, t))
    monitor.disconnected(t)
    if recorder is not None:
        recorder.event(Event("disconnected", t))
        recorder.close()
    return time.process_time() - start, monitor.summary().frames


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.iterdir())
    return path.stat().st_size


def _read_back(path: Path, frames: int, numpy: bool) -> tuple[float, float | None]:
    """Frames/s of replaying the recording and of reading it into columns."""
    start = time.perf_counter()
    replay_recording(path)
    replayed = time.perf_counter()
    if not numpy:
        return frames / (replayed - start), None
    recording_columns(path)
    return frames / (replayed - start), frames / (time.perf_counter() - replayed)


def run_record_bench(seconds: float, chunk_bytes: int, repeat: int) -> RecordBenchResult:
    """Each format `repeat` times, interleaved with the reference; the least CPU counts,
    and the fastest read-back."""
    with tempfile.TemporaryDirectory(prefix="wftool-bench-") as scratch_name:
        scratch = Path(scratch_name)
        capture_path = scratch / "capture.fsp"
        write_capture(capture_path, round(seconds * REALTIME_PACKETS_PER_S), tunnel=False)
        capture = capture_path.read_bytes()
        reference = float("inf")
        cpu = dict.fromkeys(RECORD_FORMATS, float("inf"))
        replay_rate = dict.fromkeys(RECORD_FORMATS, 0.0)
        columns_rate: dict[str, float | None] = dict.fromkeys(RECORD_FORMATS, 0.0)
        numpy = importlib.util.find_spec("numpy") is not None
        sizes: dict[str, int] = {}
        frames = 0
        for _ in range(repeat):
            reference = min(reference, _replay(capture, chunk_bytes, None)[0])
            for name in RECORD_FORMATS:
                path = scratch / f"run-{name}"
                shutil.rmtree(path, ignore_errors=True)
                path.unlink(missing_ok=True)
                recorder = Recorder(path, None, {"port": "bench"}, record_format=name)
                spent, frames = _replay(capture, chunk_bytes, recorder)
                cpu[name] = min(cpu[name], spent)
                sizes[name] = _size(path)
                replayed, columns = _read_back(path, frames, numpy)
                replay_rate[name] = max(replay_rate[name], replayed)
                columns_rate[name] = None if columns is None else max(columns_rate[name], columns)
    return RecordBenchResult(
        seconds=seconds,
        chunk_bytes=chunk_bytes,
        frames=frames,
        reference_cpu_s=reference,
        formats=tuple(
            FormatFigures(
                name,
                frames,
                sizes[name],
                max(0.0, cpu[name] - reference),
                replay_rate[name],
                columns_rate[name],
            )
            for name in RECORD_FORMATS
        ),
    )
