"""Recordings of a verify run: ROS 2 or JSON MCAP (Foxglove, PlotJuggler) and CSV.

Two MCAP formats, both read by `wftool replay`:

- `ros2` (default): a rosbag2 directory that ROS 2 plays; see `wftool.recording.rosbag`.
- `json`: one MCAP file with two JSON-schema channels: `/fsp/frame`, one message per decoded
  frame stamped with its corrected OBC time, and `/fsp/events`, the raw byte chunks and
  connection and command events.

Either way `/fsp/events` holds what the monitor saw, exactly, so `wftool replay` reproduces
the run's statistics. Files are finished on close, also when the run is interrupted, and
when the disk fills up (`wftool.recording.mcapfile`); one whose writer was killed outright is
read as far as it goes (`RecordingReader`). No file is ever overwritten.
"""

from __future__ import annotations

import base64
import csv
import json
import math
import os
import struct
import time
from array import array
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, TextIO

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import MCAP0_MAGIC

from wftool import __version__
from wftool.errors import UsageError
from wftool.extras import require
from wftool.fsp import ESTIMATORS, SensorFrame, StatePacket
from wftool.recording import ros2msg
from wftool.recording.mcapfile import Cut, LinearReader, indexed_messages
from wftool.recording.mcapprocess import McapProcess
from wftool.recording.ros2msg import StreamHealth, decode_event, decode_events
from wftool.recording.rosbag import RosbagWriter, bag_file
from wftool.verify.monitor import StreamMonitor
from wftool.verify.uplink import UplinkTracker

if TYPE_CHECKING:
    from wftool.fsp.columns import StateColumns

FRAME_TOPIC = "/fsp/frame"
EVENT_TOPIC = "/fsp/events"
METADATA_NAME = "wftool.verify"
RECORD_FORMATS = ("ros2", "json")

_VECTOR = {"type": "array", "items": {"type": ["number", "null"]}}
FRAME_SCHEMA = {
    "title": "wftool.fsp.Frame",
    "type": "object",
    "properties": {
        "seq": {"type": "integer", "description": "E1 sequence number of the packet"},
        "epoch": {"type": "integer", "description": "FC resets seen before this frame"},
        "fc_time_us": {"type": "integer", "description": "FC capture time, unwrapped"},
        "obc_time": {"type": "number", "description": "capture time on the OBC clock, Unix s"},
        "sample_time_us": {"type": "integer", "description": "raw u32 FC capture time"},
        "acc_g": _VECTOR,
        "gyro_dps": _VECTOR,
        "quaternion": _VECTOR,
        "euler_deg": _VECTOR,
        "rc": _VECTOR,
        "rpm": _VECTOR,
        "vbat_v": {"type": "number"},
        "acc_raw": _VECTOR,
        "acc_1g": {"type": "integer"},
        "gyro_raw": _VECTOR,
        "gyro_scale": {"type": "number"},
    },
}
EVENT_SCHEMA = {
    "title": "wftool.verify.Event",
    "type": "object",
    "properties": {
        "kind": {"enum": ["connected", "disconnected", "bytes", "command"]},
        "t": {"type": "number", "description": "OBC monotonic clock, s"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "rc": _VECTOR,
    },
}
CSV_COLUMNS = (
    ["obc_time", "fc_time_us", "seq", "epoch"]
    + [f"acc_{a}_g" for a in "xyz"]
    + [f"gyro_{a}_dps" for a in "xyz"]
    + [f"q{c}" for c in "wxyz"]
    + ["roll_deg", "pitch_deg", "yaw_deg"]
    + ["rc_roll", "rc_pitch", "rc_yaw", "rc_throttle", "rc_aux3", "rc_aux4"]
    + [f"rpm_{m}" for m in range(1, 5)]
    + ["vbat_v"]
)


def run_metadata(
    port: str,
    baudrate: int,
    expected_rate_hz: float | None,
    uplink_rate_hz: float | None,
    clock: str = ESTIMATORS[0],
) -> dict[str, str]:
    """What a recording keeps about its run, for `replay_recording` to set up the same monitor."""
    return {
        "port": port,
        "baud": str(baudrate),
        "expected_rate_hz": str(expected_rate_hz or ""),
        "uplink_rate_hz": str(uplink_rate_hz or ""),
        "clock": clock,
    }


def _finite(values: Sequence[float]) -> list[float | None]:
    return [None if math.isnan(v) else v for v in values]


@dataclass(frozen=True)
class Event:
    kind: str
    t: float
    data: bytes = b""
    rc: tuple[int, ...] = ()


class Recorder:
    """Writes what a run sees to MCAP and/or CSV; call `close()` (or use `with`).

    With `record_format="ros2"`, `mcap_path` names the rosbag2 directory to create.
    """

    def __init__(
        self,
        mcap_path: Path | None,
        csv_path: Path | None,
        metadata: dict[str, str],
        record_format: str = "ros2",
    ) -> None:
        # Monotonic OBC times become Unix times in the file, for tools that show dates.
        self._wall_offset = time.time() - time.monotonic()
        self._writer: McapProcess | None = None
        self._bag: RosbagWriter | None = None
        self._csv_file: TextIO | None = None
        if record_format not in RECORD_FORMATS:
            raise UsageError(f"unknown recording format {record_format!r}: ros2 or json")
        for path in (csv_path, mcap_path if record_format == "json" else None):
            if path is not None and path.exists():  # a recording is never overwritten
                raise UsageError(f"cannot write the recording: {path} already exists")
        try:
            if mcap_path is not None and record_format == "ros2":
                self._bag = RosbagWriter(mcap_path, METADATA_NAME, metadata)
            elif mcap_path is not None:
                self._writer = McapProcess(mcap_path, "", f"wftool {__version__}")
                self._writer.add_metadata(METADATA_NAME, {**metadata, "wftool": __version__})
                self._frame_channel = self._channel(FRAME_TOPIC, FRAME_SCHEMA)
                self._event_channel = self._channel(EVENT_TOPIC, EVENT_SCHEMA)
            if csv_path is not None:
                self._csv_file = open(csv_path, "x", newline="")  # noqa: SIM115 - closed in close()
                self._csv = csv.writer(self._csv_file)
                self._csv.writerow(CSV_COLUMNS)
        except OSError as exc:
            self.close()
            raise UsageError(f"cannot write the recording: {exc}") from None

    def _channel(self, topic: str, schema: dict[str, Any]) -> int:
        schema_id = self._writer.register_schema(
            name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode()
        )
        return self._writer.register_channel(topic, message_encoding="json", schema_id=schema_id)

    def _ns(self, t: float) -> int:
        return int((t + self._wall_offset) * 1e9)

    def event(self, event: Event) -> None:
        if self._bag is not None:
            self._bag.event(event.kind, event.t, event.data, event.rc)
        if self._writer is None:
            return
        message: dict[str, Any] = {"kind": event.kind, "t": event.t}
        if event.data:
            message["data"] = base64.b64encode(event.data).decode()
        if event.rc:
            message["rc"] = list(event.rc)
        ns = self._ns(event.t)
        self._writer.add_message(
            self._event_channel, log_time=ns, publish_time=ns, data=json.dumps(message).encode()
        )

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None = None) -> None:
        """The frames of `packets`; `health`, a new snapshot or the last one (ROS 2 only)."""
        if self._bag is not None:
            self._bag.packets(packets, health)
        if self._writer is None and self._csv_file is None:
            return
        for packet in packets:
            for frame in packet.frames:
                self._frame(packet, frame)

    def _frame(self, packet: StatePacket, frame: SensorFrame) -> None:
        obc_time = frame.obc_time + self._wall_offset if frame.obc_time is not None else None
        if self._writer is not None:
            ns = int(obc_time * 1e9) if obc_time is not None else self._ns(packet.arrival_time)
            message = {
                "seq": packet.seq,
                "epoch": packet.epoch,
                "fc_time_us": frame.time_us,
                "obc_time": obc_time,
                "sample_time_us": frame.sample_time_us,
                "acc_g": _finite(frame.acc_g),
                "gyro_dps": list(frame.gyro_dps),
                "quaternion": list(frame.quaternion),
                "euler_deg": _finite(frame.euler_deg),
                "rc": list(frame.rc),
                "rpm": list(frame.rpm),
                "vbat_v": frame.vbat_v,
                "acc_raw": list(frame.acc),
                "acc_1g": frame.acc_1g,
                "gyro_raw": list(frame.gyro),
                "gyro_scale": frame.gyro_scale,
            }
            self._writer.add_message(
                self._frame_channel, log_time=ns, publish_time=ns, data=json.dumps(message).encode()
            )
        if self._csv_file is not None:
            self._csv.writerow(
                [
                    obc_time, frame.time_us, packet.seq, packet.epoch,
                    *frame.acc_g, *frame.gyro_dps, *frame.quaternion, *frame.euler_deg,
                    *frame.rc, *frame.rpm, frame.vbat_v,
                ]
            )  # fmt: skip

    def close(self) -> None:
        writer, bag, csv_file = self._writer, self._bag, self._csv_file
        self._writer = self._bag = self._csv_file = None
        try:
            if bag is not None:
                bag.close()
            if writer is not None:
                writer.finish()
        finally:
            if csv_file is not None:
                csv_file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class RecordingReader:
    """A recording opened for reading, either format: the run's `metadata`, then its
    `events()` in recorded order. A file whose writer was killed (no summary, no footer)
    is read as far as it goes (`mcapfile.LinearReader`); once the events are read, `cut`
    says how far. Anything that is not a recording, or not one as wftool writes them, is a
    `UsageError` naming the file and what is wrong.

    The FSP stream's events and metadata by default; another recording's by `topic` and
    `metadata_name` (the MSP baseline's, `wftool.recording.msp`). A file without
    `topic` is refused: it is a recording of another kind. `topic` None opens it only to
    look (`topics`, `metadata`; `recording_topics`)."""

    def __init__(
        self, path: Path, topic: str | None = EVENT_TOPIC, metadata_name: str = METADATA_NAME
    ) -> None:
        self.path = path = bag_file(path)
        self.topic, self.metadata_name = topic, metadata_name
        self.cut: Cut | None = None
        try:
            self._handle = open(path, "rb")  # noqa: SIM115 - closed by events()
        except OSError as exc:
            raise UsageError(f"cannot read recording {path}: {exc.strerror or exc}") from None
        try:
            self._finished = _ends_whole(self._handle)
            self.metadata = self._metadata()
            self.topics = self._topics()
        except (McapError, ValueError, EOFError, struct.error) as exc:
            self._handle.close()
            reason = str(exc) or type(exc).__name__
            raise UsageError(f"cannot read recording {path}: {reason}") from None
        if topic is not None and topic not in self.topics:
            self._handle.close()
            raise UsageError(f"{path} has no {topic} topic: not a recording this command reads")

    def close(self) -> None:
        """Close the file without reading the events (`events()` closes it when done)."""
        self._handle.close()

    def _topics(self) -> set[str]:
        """The topics the file has channels for: from its summary, else from the channels
        written before its first message (wftool registers every channel at the start)."""
        if self._finished:
            summary = self._reader.get_summary()
            if summary is not None:
                return {channel.topic for channel in summary.channels.values()}
        topics = set()
        for record in LinearReader(self._handle).records():
            if isinstance(record, Message):
                break
            if isinstance(record, Channel):
                topics.add(record.topic)
        return topics

    def _metadata(self) -> dict[str, str]:
        metadata: dict[str, str] = {}
        if self._finished:
            self._reader = make_reader(self._handle)  # it keeps the summary it reads
            for record in self._reader.iter_metadata():
                if record.name == self.metadata_name:
                    metadata = dict(record.metadata)
            return metadata
        for record in LinearReader(self._handle).records():  # written before any message
            if isinstance(record, Message):
                break
            if isinstance(record, Metadata) and record.name == self.metadata_name:
                metadata = dict(record.metadata)
        return metadata

    def events(self) -> Iterator[Event]:
        """The events, checked: a kind, a finite time, bytes inside a connection."""
        connected = False
        with self._handle, self._damage():
            for codec, data in self._payloads():
                for event in _events(codec, data):
                    connected = _connected_after(event, connected)
                    yield event

    def reads(self) -> Reads:
        """What the run's decoder was fed, checked as `events` checks it: for
        `recording_columns`, which needs no object per read. A batch of reads alone (the
        most of a recording) is taken whole."""
        connected = False
        data: list[bytes] = []
        sizes, times = array("I"), array("d")
        connections: list[int] = []
        with self._handle, self._damage():
            for codec, payload in self._payloads():
                if codec == _EVENTS_CDR:
                    batch = decode_events(payload)
                    if (
                        connected
                        and batch.kind.count(_BYTES) == len(batch.kind)
                        and all(map(math.isfinite, batch.t))
                    ):
                        data.append(batch.data)
                        sizes.extend(batch.size)
                        times.extend(batch.t)
                        continue
                for event in _events(codec, payload):
                    connected = _connected_after(event, connected)
                    if event.kind == "connected" and sizes:
                        connections.append(len(sizes))
                    elif event.kind == "bytes":
                        data.append(event.data)
                        sizes.append(len(event.data))
                        times.append(event.t)
        return Reads(b"".join(data), sizes, times, connections)

    @contextmanager
    def _damage(self) -> Iterator[None]:
        """Anything wrong inside the file, as a one-line `UsageError` naming it."""
        try:
            yield
        except (McapError, ValueError, KeyError, IndexError, EOFError, struct.error) as exc:
            reason = str(exc) or type(exc).__name__
            raise UsageError(f"recording {self.path} is damaged: {reason}") from None

    def _payloads(self) -> Iterator[tuple[str, bytes]]:
        """(codec, data) of each event message: through the indexes if the file has them."""
        handle = self._handle
        if not self._finished:
            linear = LinearReader(handle)
            schemas: dict[int, str] = {}
            channels: dict[int, Channel] = {}
            for record in linear.records():
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    channel = channels.get(record.channel_id)
                    if channel is not None and channel.topic == self.topic:
                        yield _codec(channel, schemas.get(channel.schema_id, "")), record.data
            self.cut = linear.cut
            return
        reader = self._reader
        summary = reader.get_summary()
        indexed = indexed_messages(handle, summary, self.topic)
        if indexed is not None:
            channel, messages = indexed
            schema = summary.schemas.get(channel.schema_id)
            codec = _codec(channel, schema.name if schema is not None else "")
            for data in messages:
                yield codec, data
            return
        for schema, channel, message in reader.iter_messages(
            topics=[self.topic], log_time_order=False
        ):
            yield _codec(channel, schema.name if schema is not None else ""), message.data


@dataclass(frozen=True)
class Reads:
    """The reads of a recorded run, as its decoder was fed them."""

    data: bytes
    """All bytes read, in order."""
    sizes: array
    """Bytes per read."""
    times: array
    """OBC time (s) per read."""
    connections: list[int]
    """The reads that began a new connection after the first (`decode_columns`)."""


_EVENTS_CDR = "cdr: " + ros2msg.STREAM_EVENTS.name
_EVENT_CDR = "cdr: " + ros2msg.STREAM_EVENT.name
_BYTES = ros2msg.EVENT_KINDS.index("bytes")


def _codec(channel: Channel, schema_name: str) -> str:
    """How the event messages of `channel` are encoded: JSON, or one of the CDR types."""
    if channel.message_encoding != "cdr":
        return channel.message_encoding
    return _EVENTS_CDR if schema_name == ros2msg.STREAM_EVENTS.name else _EVENT_CDR


def _connected_after(event: Event, connected: bool) -> bool:
    """Whether the run is connected after `event`; bytes outside a connection are damage."""
    if event.kind in ("connected", "disconnected"):
        return event.kind == "connected"
    if event.kind == "bytes" and not connected:
        raise ValueError("bytes outside a connection")
    return connected


def _ends_whole(handle: IO[bytes]) -> bool:
    """Whether the file ends as a finished MCAP does (else it is read linearly)."""
    handle.seek(0, os.SEEK_END)
    size = handle.tell()
    if size == 0:
        raise ValueError("the file is empty")
    handle.seek(0)
    if handle.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
        raise ValueError("not an MCAP file")
    handle.seek(max(0, size - len(MCAP0_MAGIC)))
    whole = size >= 2 * len(MCAP0_MAGIC) and handle.read() == MCAP0_MAGIC
    handle.seek(0)
    return whole


def _events(codec: str, data: bytes) -> list[Event]:
    """The events of one message as recorded (a CDR batch or single event, or JSON), or
    ValueError saying what is wrong."""
    if codec == _EVENTS_CDR:
        return [_event(*event) for event in decode_events(data).events()]
    if codec == _EVENT_CDR:
        return [_event(*decode_event(data))]
    raw = json.loads(data)
    if not isinstance(raw, dict):
        raise ValueError(f"an event is a JSON {type(raw).__name__}, not an object")
    kind, t, encoded, rc = raw.get("kind"), raw.get("t"), raw.get("data", ""), raw.get("rc", [])
    if not isinstance(encoded, str):
        raise ValueError(f"an event's data is {encoded!r}, not base64 text")
    payload = base64.b64decode(encoded, validate=True)
    if not isinstance(rc, list):
        raise ValueError(f"an event's rc is {rc!r}, not a list")
    return [_event(kind, t, payload, rc)]


def _event(kind: object, t: object, payload: bytes, rc: Sequence[object]) -> Event:
    """An event, checked: a kind, a finite time, whole RC values."""
    if not isinstance(kind, str):
        raise ValueError(f"an event's kind is {kind!r}")
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
        raise ValueError(f"an event's time is {t!r}, not a number of seconds")
    if any(isinstance(v, bool) or not isinstance(v, int) for v in rc):
        raise ValueError(f"an event's rc is {rc!r}, not whole numbers")
    return Event(kind, float(t), payload, tuple(rc))  # type: ignore[arg-type]


def recording_topics(path: Path) -> set[str]:
    """The topics a recording (a bag directory or an MCAP file) has channels for: its kind."""
    recording = RecordingReader(path, topic=None)
    recording.close()
    return recording.topics


def read_recording(path: Path) -> tuple[dict[str, str], Iterator[Event]]:
    """The run's metadata and its events in recorded order (either format)."""
    recording = RecordingReader(path)
    return recording.metadata, recording.events()


def recording_columns(path: Path | RecordingReader, clock: str | None = None) -> StateColumns:
    """The recorded bytes decoded into columns (needs NumPy): what the run's decoder saw,
    exactly, across its reconnects. `clock` None takes the recorded run's estimator."""
    from wftool.fsp import columns

    # Before reading anything: a missing extra is one line, not a late traceback.
    require("analysis", "numpy", what=columns.WHAT)
    recording = path if isinstance(path, RecordingReader) else RecordingReader(path)
    clock = clock or recording.metadata.get("clock") or ESTIMATORS[0]
    reads = recording.reads()
    return columns.decode_columns(
        reads.data, reads.sizes, reads.times, clock=clock, connections=reads.connections
    )


def replay_recording(
    path: Path | RecordingReader, expected_rate_hz: float | None = None, clock: str | None = None
) -> StreamMonitor:
    """A monitor that has seen exactly what the recorded run saw; `clock` None takes the
    recorded run's estimator."""
    recording = path if isinstance(path, RecordingReader) else RecordingReader(path)
    metadata = recording.metadata
    if expected_rate_hz is None and metadata.get("expected_rate_hz"):
        expected_rate_hz = _rate(recording.path, metadata["expected_rate_hz"])
    uplink = UplinkTracker() if metadata.get("uplink_rate_hz") else None
    clock = clock or metadata.get("clock") or ESTIMATORS[0]
    monitor = StreamMonitor(
        metadata.get("port", str(recording.path)), expected_rate_hz, uplink=uplink, clock=clock
    )
    for event in recording.events():
        if event.kind == "connected":
            monitor.connected(event.t)
        elif event.kind == "disconnected":
            monitor.disconnected(event.t)
        elif event.kind == "bytes":
            monitor.feed(event.data, event.t)
        elif event.kind == "command":
            monitor.command_sent(event.rc, event.t)
    return monitor


def _rate(path: Path, text: str) -> float:
    try:
        rate = float(text)
    except ValueError:
        rate = math.nan
    if not (math.isfinite(rate) and rate > 0):
        raise UsageError(f"recording {path} is damaged: its expected rate {text!r} is no rate")
    return rate
