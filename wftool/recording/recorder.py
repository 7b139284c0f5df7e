"""Writes a live run as it happens: a ROS 2 bag (the default) or a JSON MCAP file, and CSV
beside either; a `Sink` of the live loop. No file is ever overwritten.

    with Recorder(Path("run"), None, run_metadata(url, baud, None, None)) as recorder:
        recorder.event(Event("bytes", t, data))
        recorder.packets(decoder.feed(data, t), None)
"""

from __future__ import annotations

import base64
import csv
import json
import math
import time
from collections.abc import Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any, TextIO

from wftool import __version__
from wftool.errors import UsageError
from wftool.fsp import SensorFrame, StatePacket
from wftool.recording.events import EVENT_TOPIC, METADATA_NAME, Event, StreamHealth
from wftool.recording.mcapprocess import McapProcess
from wftool.recording.rosbag import CLOSED_KEY, RosbagWriter

FRAME_TOPIC = "/fsp/frame"
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


def _finite(values: Sequence[float]) -> list[float | None]:
    return [None if math.isnan(v) else v for v in values]


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
                self._writer = writer = McapProcess(mcap_path, "", f"wftool {__version__}")
                self._metadata = {**metadata, "wftool": __version__, CLOSED_KEY: "false"}
                writer.add_metadata(METADATA_NAME, self._metadata)
                self._frame_channel = _channel(writer, FRAME_TOPIC, FRAME_SCHEMA)
                self._event_channel = _channel(writer, EVENT_TOPIC, EVENT_SCHEMA)
            if csv_path is not None:
                self._csv_file = open(csv_path, "x", newline="")  # noqa: SIM115 - closed in close()
                self._csv = csv.writer(self._csv_file)
                self._csv.writerow(CSV_COLUMNS)
        except OSError as exc:
            self.close()
            raise UsageError(f"cannot write the recording: {exc}") from None

    def _ns(self, t: float) -> int:
        return int((t + self._wall_offset) * 1e9)

    def event(self, event: Event) -> None:
        if self._bag is not None:
            self._bag.event(event)
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
            if obc_time is not None:
                ns = int(obc_time * 1e9)
            elif packet.arrival_time is not None:
                ns = self._ns(packet.arrival_time)
            else:  # decoded without arrival times: stamped now, as the ROS 2 format does
                ns = time.time_ns()
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
                with ExitStack() as finishing:
                    finishing.callback(writer.finish)
                    if writer.failure is None:  # one that failed is cut short: "false"
                        writer.add_metadata(METADATA_NAME, {**self._metadata, CLOSED_KEY: "true"})
        finally:
            if csv_file is not None:
                csv_file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _channel(writer: McapProcess, topic: str, schema: dict[str, Any]) -> int:
    schema_id = writer.register_schema(
        name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode()
    )
    return writer.register_channel(topic, message_encoding="json", schema_id=schema_id)
