"""Recordings of a verify run: ROS 2 or JSON MCAP (Foxglove, PlotJuggler) and CSV.

Two MCAP formats, both read by `wftool replay`:

- `ros2` (default): a rosbag2 directory that ROS 2 plays; see `wftool.verify.rosbag`.
- `json`: one MCAP file with two JSON-schema channels: `/fsp/frame`, one message per decoded
  frame stamped with its corrected OBC time, and `/fsp/events`, the raw byte chunks and
  connection and command events.

Either way `/fsp/events` holds what the monitor saw, exactly, so `wftool replay` reproduces
the run's statistics. Files are finished on close, also when the run is interrupted, and
when the disk fills up (`wftool.verify.mcapfile`).
"""

from __future__ import annotations

import base64
import csv
import json
import math
import struct
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from mcap.exceptions import McapError
from mcap.reader import make_reader

from wftool import __version__
from wftool.errors import UsageError
from wftool.extras import require
from wftool.fsp import ESTIMATORS, SensorFrame, StatePacket
from wftool.verify.mcapfile import McapFile, indexed_messages
from wftool.verify.monitor import StreamMonitor
from wftool.verify.ros2 import StreamHealth, decode_event
from wftool.verify.rosbag import RosbagWriter, bag_file
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
        self._writer: McapFile | None = None
        self._bag: RosbagWriter | None = None
        self._csv_file: TextIO | None = None
        if record_format not in RECORD_FORMATS:
            raise UsageError(f"unknown recording format {record_format!r}: ros2 or json")
        try:
            if mcap_path is not None and record_format == "ros2":
                self._bag = RosbagWriter(mcap_path, METADATA_NAME, metadata)
            elif mcap_path is not None:
                self._writer = McapFile(mcap_path, "", f"wftool {__version__}")
                self._writer.add_metadata(METADATA_NAME, {**metadata, "wftool": __version__})
                self._frame_channel = self._channel(FRAME_TOPIC, FRAME_SCHEMA)
                self._event_channel = self._channel(EVENT_TOPIC, EVENT_SCHEMA)
            if csv_path is not None:
                self._csv_file = open(csv_path, "w", newline="")  # noqa: SIM115 - closed in close()
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


def read_recording(path: Path) -> tuple[dict[str, str], Iterator[Event]]:
    """The run's metadata and its events in recorded order (either format)."""
    path = bag_file(path)
    try:
        handle = open(path, "rb")  # noqa: SIM115 - closed by the generator
        reader = make_reader(handle)
        metadata: dict[str, str] = {}
        for record in reader.iter_metadata():
            if record.name == METADATA_NAME:
                metadata = dict(record.metadata)
    except (OSError, McapError, ValueError) as exc:
        raise UsageError(f"cannot read recording {path}: {exc}") from None

    def payloads() -> Iterator[tuple[str, bytes]]:
        """(encoding, data) of each event: through the indexes if the file has them."""
        indexed = indexed_messages(handle, reader.get_summary(), EVENT_TOPIC)
        if indexed is not None:
            encoding, messages = indexed
            for data in messages:
                yield encoding, data
            return
        for _, channel, message in reader.iter_messages(topics=[EVENT_TOPIC], log_time_order=False):
            yield channel.message_encoding, message.data

    def events() -> Iterator[Event]:
        with handle:
            try:
                for encoding, data in payloads():
                    if encoding == "cdr":
                        yield Event(*decode_event(data))
                        continue
                    raw = json.loads(data)
                    yield Event(
                        raw["kind"],
                        raw["t"],
                        base64.b64decode(raw.get("data", "")),
                        tuple(raw.get("rc", ())),
                    )
            except (McapError, ValueError, KeyError, struct.error) as exc:
                raise UsageError(f"recording {path} is damaged: {exc}") from None

    return metadata, events()


def recording_columns(path: Path, clock: str | None = None) -> list[StateColumns]:
    """The recorded bytes decoded into columns (needs NumPy), one `StateColumns` per
    connection: each had its own decoder, and each agrees with it exactly. `clock` None
    takes the recorded run's estimator."""
    from wftool.fsp import columns

    # Before reading anything: a missing extra is one line, not a late traceback.
    require("analysis", "numpy", what=columns.WHAT)
    metadata, events = read_recording(path)
    clock = clock or metadata.get("clock") or ESTIMATORS[0]
    connections: list[tuple[list[bytes], list[float]]] = []
    current: tuple[list[bytes], list[float]] | None = None
    for event in events:
        if event.kind == "connected":
            current = ([], [])
            connections.append(current)
        elif event.kind == "disconnected":
            current = None
        elif event.kind == "bytes":
            if current is None:
                raise UsageError(f"recording {path} is damaged: bytes outside a connection")
            current[0].append(event.data)
            current[1].append(event.t)
    return [
        columns.decode_columns(b"".join(chunks), list(map(len, chunks)), times, clock=clock)
        for chunks, times in connections
    ]


def replay_recording(
    path: Path, expected_rate_hz: float | None = None, clock: str | None = None
) -> StreamMonitor:
    """A monitor that has seen exactly what the recorded run saw; `clock` None takes the
    recorded run's estimator."""
    metadata, events = read_recording(path)
    if expected_rate_hz is None and metadata.get("expected_rate_hz"):
        expected_rate_hz = float(metadata["expected_rate_hz"])
    uplink = UplinkTracker() if metadata.get("uplink_rate_hz") else None
    clock = clock or metadata.get("clock") or ESTIMATORS[0]
    monitor = StreamMonitor(
        metadata.get("port", str(path)), expected_rate_hz, uplink=uplink, clock=clock
    )
    for event in events:
        if event.kind == "connected":
            monitor.connected(event.t)
        elif event.kind == "disconnected":
            monitor.disconnected(event.t)
        elif event.kind == "bytes":
            monitor.feed(event.data, event.t)
        elif event.kind == "command":
            monitor.command_sent(event.rc, event.t)
    return monitor
