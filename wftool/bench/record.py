"""`wftool bench record`: what recording costs (bytes and CPU per frame of each format, how
fast it reads back) and the stalls it gives the reading thread (docs/bench.md).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader

from wftool.bench.decode import REALTIME_PACKETS_PER_S, STREAMS, write_capture
from wftool.recording.events import Event
from wftool.recording.mcapfile import McapFile
from wftool.recording.mcapprocess import McapProcess
from wftool.recording.reader import recording_columns
from wftool.recording.recorder import RECORD_FORMATS, Recorder
from wftool.recording.rosbag import bag_file
from wftool.stats import quantile
from wftool.verify.live import Dispatcher
from wftool.verify.monitor import StreamMonitor
from wftool.verify.session import replay_recording

PACKET_BYTES = 118  # a 116-byte state packet, COBS-framed
STALL_SPEED = 4.0
"""The stall replay's pace, times real time (either writer keeps up with it)."""
STALL_WRITERS: dict[str, type[McapProcess] | type[McapFile]] = {
    "writer process": McapProcess,
    "in-process McapFile": McapFile,
}


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
class StallFigures:
    """The reading thread's stalls while one writer records."""

    name: str
    reads: int
    worst_s: float
    p999_s: float
    """99.9th percentile."""
    over_1ms: int
    """Reads stalled longer than 1 ms."""
    chunks: int
    """Chunks the file holds (each a stall in the in-process writer)."""


@dataclass(frozen=True)
class RecordBenchResult:
    stream: str
    seconds: float
    chunk_bytes: int
    frames: int
    reference_cpu_s: float
    """Decoding and monitoring alone: the part every format shares."""
    formats: tuple[FormatFigures, ...]
    stalls: tuple[StallFigures, ...]

    def format(self, name: str) -> FormatFigures:
        return next(f for f in self.formats if f.name == name)


def _replay(capture: bytes, chunk_bytes: int, recorder: Recorder | None) -> tuple[float, int]:
    """CPU time of one replay (its writer process's included), and the frames decoded."""
    monitor = StreamMonitor("bench")
    dispatch = Dispatcher(monitor, [recorder] if recorder is not None else []).event
    step = chunk_bytes / (REALTIME_PACKETS_PER_S * PACKET_BYTES)
    t = 1000.0
    start = _cpu_s()
    dispatch(Event("connected", t))
    for offset in range(0, len(capture), chunk_bytes):
        t += step
        dispatch(Event("bytes", t, capture[offset : offset + chunk_bytes]))
    dispatch(Event("disconnected", t))
    if recorder is not None:
        recorder.close()
    return _cpu_s() - start, monitor.summary().frames


def _cpu_s() -> float:
    """CPU time of this process and of the children it waited for (recording writers)."""
    times = os.times()
    return time.process_time() + times.children_user + times.children_system


def _reads(recording: Path) -> tuple[list[tuple[str, str, bytes, str, str]], list[list]]:
    """The channels of an MCAP file (schema name, encoding, data, topic, message encoding)
    and its messages, (channel index, log time, data), grouped into reads (one log time)."""
    with open(recording, "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None  # wftool's writers end a file with its summary
        ids = sorted(summary.channels)
        channels = []
        for channel_id in ids:
            channel = summary.channels[channel_id]
            schema = summary.schemas[channel.schema_id]
            channels.append(
                (schema.name, schema.encoding, schema.data, channel.topic, channel.message_encoding)
            )
        index = {channel_id: position for position, channel_id in enumerate(ids)}
        reads: list[list] = []
        for _, channel, message in reader.iter_messages(log_time_order=False):
            entry = (index[channel.id], message.log_time, message.data)
            if reads and reads[-1][0][1] == message.log_time:
                reads[-1].append(entry)
            else:
                reads.append([entry])
    return channels, reads


def _stalls(
    writer_type: type[McapFile | McapProcess],
    path: Path,
    channels: list[tuple[str, str, bytes, str, str]],
    reads: list[list],
) -> list[float]:
    """Each read's stall (s) while `writer_type` records `reads` to `path`, paced."""
    writer = writer_type(path, "ros2", "wftool bench")
    ids = [
        writer.register_channel(topic, encoding, writer.register_schema(name, schema_type, data))
        for name, schema_type, data, topic, encoding in channels
    ]
    stalls = []
    first_log = reads[0][0][1]
    start = time.monotonic()
    for read in reads:
        due = start + (read[0][1] - first_log) / 1e9 / STALL_SPEED
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        woke = time.monotonic()
        for channel, log_time, data in read:
            writer.add_message(ids[channel], log_time, data)
        stalls.append(time.monotonic() - woke)
    writer.finish()
    return stalls


def _stall_figures(name: str, stalls: list[float], path: Path) -> StallFigures:
    ordered = sorted(stalls)
    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None  # both writers end a file with its summary
    chunks = len(summary.chunk_indexes)
    return StallFigures(
        name,
        len(ordered),
        ordered[-1],
        quantile(ordered, 0.999),
        sum(1 for stall in ordered if stall > 1e-3),
        chunks,
    )


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


def run_record_bench(
    seconds: float, chunk_bytes: int, repeat: int, stream: str = STREAMS[0]
) -> RecordBenchResult:
    """Each format `repeat` times on `stream`, interleaved with the reference; the least
    CPU counts, and the fastest read-back."""
    with tempfile.TemporaryDirectory(prefix="wftool-bench-") as scratch_name:
        scratch = Path(scratch_name)
        capture_path = scratch / "capture.fsp"
        packets = round(seconds * REALTIME_PACKETS_PER_S)
        write_capture(capture_path, packets, tunnel=False, stream=stream)
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
                best = columns_rate[name] or 0.0
                columns_rate[name] = None if columns is None else max(best, columns)
        channels, reads = _reads(bag_file(scratch / "run-ros2"))
        stalls: dict[str, StallFigures] = {}
        for run in range(repeat):
            for kind, (name, writer_type) in enumerate(STALL_WRITERS.items()):
                path = scratch / f"stalls-{run}-{kind}.mcap"
                figures = _stall_figures(name, _stalls(writer_type, path, channels, reads), path)
                if name not in stalls or figures.worst_s < stalls[name].worst_s:
                    stalls[name] = figures
    return RecordBenchResult(
        stream=stream,
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
        stalls=tuple(stalls[name] for name in STALL_WRITERS),
    )
