"""Reads a recording back, either format: the run's metadata, its events as the live loop saw
them, or its reads decoded into NumPy columns. A file cut short is read as far as it goes.

    recording = RecordingReader(Path("run"))
    for event in recording.events():   # Event("connected", t), Event("bytes", t, data), …
        ...
    columns = recording_columns(Path("run"))   # needs the analysis extra
"""

from __future__ import annotations

import base64
import json
import math
import struct
from array import array
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema

from wftool.errors import UsageError
from wftool.extras import require
from wftool.fsp import ESTIMATORS
from wftool.recording import ros2msg
from wftool.recording.events import EVENT_KINDS, EVENT_TOPIC, METADATA_NAME, PLANNED_KEY, Event
from wftool.recording.mcapfile import Cut, LinearReader, ends_whole, indexed_messages
from wftool.recording.ros2msg import decode_event, decode_events
from wftool.recording.rosbag import CLOSED_KEY, bag_file

REPAIR = "`wftool record repair`"
"""The command that repairs a recording cut short (`wftool.recording.repair`)."""

if TYPE_CHECKING:
    from wftool.fsp.columns import StateColumns


class RecordingReader:
    """A recording opened for reading, either format: the run's `metadata`, then its
    `events()` in recorded order. A file whose writer was killed (no summary, no footer)
    is read as far as it goes (`mcapfile.LinearReader`); once the events are read, `cut`
    says how far. `closed` says whether the recording was closed, and `cut_short` what is
    missing if it was not. Anything that is not a recording, or not one as wftool writes
    them, is a `UsageError` naming the file and what is wrong.

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
            self._finished = ends_whole(self._handle)
            self.metadata = self._metadata()
            self.topics = self._topics()
        except (McapError, ValueError, EOFError, struct.error) as exc:
            self._handle.close()
            reason = str(exc) or type(exc).__name__
            raise UsageError(f"cannot read recording {path}: {reason}") from None
        if topic is not None and topic not in self.topics:
            self._handle.close()
            raise UsageError(f"{path} has no {topic} topic: not a recording this command reads")

    @property
    def closed(self) -> bool | None:
        """Whether the recording was closed when its run ended (`closed_in`)."""
        return closed_in(self.metadata)

    @property
    def planned_s(self) -> float | None:
        """How long the recorded run was to last (`planned_in`)."""
        return planned_in(self.metadata)

    def cut_short(self, recorded_s: float) -> str | None:
        """What is missing of a recording that was not closed (its run killed, its writer
        failed) or whose file has no ending, `recorded_s` into its run (from its first event
        to its last, as read); None for one closed as it should be. After `events()`."""
        if self.closed is not False and self.cut is None:
            return None
        planned = self.planned_s
        said = f"cut short at {recorded_s:.1f} s"
        if planned is not None:
            said += f" (of {planned:g} planned)"
        if self.cut is not None:
            return f"{said}: {self.path.name} was {self.cut.describe()}"
        return (
            f"{said}: it was never closed (its run was killed, or its writer failed); read "
            f"as far as it goes ({REPAIR} rebuilds a bag's metadata.yaml from it)"
        )

    def expected_rate_hz(self) -> float | None:
        """The frame rate the recorded run expected (its metadata); None if it had none."""
        text = self.metadata.get("expected_rate_hz")
        if not text:
            return None
        try:
            rate = float(text)
        except ValueError:
            rate = math.nan
        if not (math.isfinite(rate) and rate > 0):
            raise UsageError(
                f"recording {self.path} is damaged: its expected rate {text!r} is no rate"
            )
        return rate

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
        for found in LinearReader(self._handle).records():  # written before any message
            if isinstance(found, Message):
                break
            if isinstance(found, Metadata) and found.name == self.metadata_name:
                metadata = dict(found.metadata)
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
        handle, topic = self._handle, self.topic
        assert topic is not None, "a recording opened only to look has no events to read"
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
                    if channel is not None and channel.topic == topic:
                        yield _codec(channel, schemas.get(channel.schema_id, "")), record.data
            self.cut = linear.cut
            return
        reader = self._reader
        summary = reader.get_summary()
        indexed = indexed_messages(handle, summary, topic)
        if indexed is not None and summary is not None:
            channel, messages = indexed
            schema = summary.schemas.get(channel.schema_id)
            codec = _codec(channel, schema.name if schema is not None else "")
            for data in messages:
                yield codec, data
            return
        for schema, channel, message in reader.iter_messages(topics=[topic], log_time_order=False):
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
_BYTES = EVENT_KINDS.index("bytes")


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


def closed_in(metadata: dict[str, str]) -> bool | None:
    """Whether a run's metadata says its recording was closed (`rosbag.CLOSED_KEY`): False
    if the run was killed (or its writer failed) first; None for a recording made before
    recordings said so."""
    said = metadata.get(CLOSED_KEY)
    return None if said is None else said == "true"


def planned_in(metadata: dict[str, str]) -> float | None:
    """How long a recorded run was to last by its metadata, s (None: until stopped, or not
    said)."""
    try:
        planned = float(metadata.get(PLANNED_KEY) or "nan")
    except ValueError:
        return None
    return planned if math.isfinite(planned) and planned > 0 else None


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
