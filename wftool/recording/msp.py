"""The MSP baseline's recording: what `wftool record msp` polled, as ROS 2 messages in the
same kind of bag as the FSP stream's, stamped on reception (MSP carries no FC time).

    result = record_msp("socket://127.0.0.1:5761", Path("msp"), duration_s=30)
    replies, connections = msp_replies(RecordingReader(path, EVENT_TOPIC, METADATA_NAME))

Topics and metadata: docs/recording.md.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from wftool import __version__
from wftool.errors import MspError
from wftool.fc.msp import (
    Cmd,
    FrameReader,
    MspVersion,
    parse_analog,
    parse_attitude,
    parse_raw_imu,
    parse_rc,
)
from wftool.fc.msp_poller import (
    DEFAULT_WINDOW,
    PAPER_SCHEDULE,
    MspPoller,
    MspReply,
    PollRate,
    PollResult,
    check_poll,
    describe,
)
from wftool.link.transport import open_port
from wftool.progress import Log, quiet
from wftool.recording import ros2msg
from wftool.recording.events import PLANNED_KEY, Event, EventKind
from wftool.recording.reader import RecordingReader
from wftool.recording.rosbag import BagFile

IMU_TOPIC = "/msp/imu"
ATTITUDE_TOPIC = "/msp/attitude"
RC_TOPIC = "/msp/rc"
BATTERY_TOPIC = "/msp/battery"
EVENT_TOPIC = "/msp/events"
METADATA_NAME = "wftool.msp"
TOPICS: dict[str, ros2msg.MessageType] = {
    IMU_TOPIC: ros2msg.IMU,
    ATTITUDE_TOPIC: ros2msg.ATTITUDE,
    RC_TOPIC: ros2msg.MSP_RC,
    BATTERY_TOPIC: ros2msg.BATTERY_STATE,
    EVENT_TOPIC: ros2msg.STREAM_EVENT,
}
_DEG = math.pi / 180.0


def poll_metadata(
    port: str,
    schedule: Sequence[PollRate],
    window: int,
    version: int,
    serial_update_rate_hz: int | None = None,
    duration_s: float | None = None,
) -> dict[str, str]:
    """What an MSP recording keeps about its run (how long it was to last, too)."""
    imu = [rate.rate_hz for rate in schedule if rate.cmd == Cmd.RAW_IMU]
    return {
        "port": port,
        "schedule": ",".join(f"{rate.name}={rate.rate_hz:g}" for rate in schedule),
        "window": str(window),
        "msp_version": str(version),
        "expected_rate_hz": f"{imu[0]:g}" if imu else "",
        "serial_update_rate_hz": str(serial_update_rate_hz or ""),
        PLANNED_KEY: "" if duration_s is None else f"{duration_s:g}",
    }


class MspRecorder(BagFile):
    """Records a poll (it is the poller's `PollObserver`) to `path`; `close()` it."""

    def __init__(self, path: Path, metadata: dict[str, str], acc_1g: int | None = None) -> None:
        self.wall_offset_ns = time.time_ns() - time.monotonic_ns()
        """Unix time minus OBC monotonic time, ns: how the stamps were made."""
        self._acc_scale = ros2msg.STANDARD_GRAVITY / acc_1g if acc_1g else None
        custom = {
            **metadata,
            "acc_1g": str(acc_1g or ""),
            "wftool": __version__,
            "wall_offset_ns": str(self.wall_offset_ns),
        }
        super().__init__(path, TOPICS, METADATA_NAME, custom)
        ids = self.channels
        self._events = ids[EVENT_TOPIC]
        self._sensors: dict[int, tuple[int, Callable[[int, bytes], bytes]]] = {
            Cmd.RAW_IMU: (ids[IMU_TOPIC], self._imu),
            Cmd.ATTITUDE: (ids[ATTITUDE_TOPIC], _attitude),
            Cmd.RC: (ids[RC_TOPIC], _rc),
            Cmd.ANALOG: (ids[BATTERY_TOPIC], _battery),
        }

    def _stamp_ns(self, t: float) -> int:
        return self.wall_offset_ns + int(t * 1e9)

    def _event(self, kind: EventKind, t: float, data: bytes = b"") -> None:
        self.add(self._events, self._stamp_ns(t), ros2msg.encode_event(Event(kind, t, data)))

    def connected(self, t: float) -> None:
        self._event("connected", t)

    def disconnected(self, t: float) -> None:
        self._event("disconnected", t)

    def request(self, t: float, wire: bytes) -> None:
        self._event("command", t, wire)

    def read(self, t: float, data: bytes) -> None:
        self._event("bytes", t, data)

    def reply(self, reply: MspReply) -> None:
        """The reply's sensor message (the raw bytes are in the read's event already)."""
        sensor = self._sensors.get(reply.cmd)
        if sensor is None or reply.error:
            return
        channel, encode = sensor
        stamp = self._stamp_ns(reply.t)
        try:
            message = encode(stamp, reply.payload)
        except MspError:
            return  # a short reply: it stays in /msp/events, as received
        self.add(channel, stamp, message)

    def _imu(self, stamp_ns: int, payload: bytes) -> bytes:
        imu = parse_raw_imu(payload)
        scale = self._acc_scale
        acc = None if scale is None else tuple(value * scale for value in imu.acc)
        return ros2msg.imu_message(stamp_ns, [value * _DEG for value in imu.gyro], acc)

    def finish(self, result: PollResult) -> None:
        """Keep the poll's counts (in the MCAP metadata and metadata.yaml)."""
        self.custom["result"] = json.dumps(result.as_json())
        self.add_metadata(METADATA_NAME, self.custom)


def _attitude(stamp_ns: int, payload: bytes) -> bytes:
    attitude = parse_attitude(payload)
    return ros2msg.attitude_message(
        stamp_ns, attitude.roll_deg, attitude.pitch_deg, attitude.yaw_deg
    )


def _rc(stamp_ns: int, payload: bytes) -> bytes:
    return ros2msg.msp_rc_message(stamp_ns, parse_rc(payload))


def _battery(stamp_ns: int, payload: bytes) -> bytes:
    analog = parse_analog(payload)
    return ros2msg.battery_message(stamp_ns, analog.voltage_v, analog.current_a)


def msp_replies(path: Path | RecordingReader) -> tuple[dict[str, str], list[list[MspReply]]]:
    """The recording's metadata and its replies, one list per connection, decoded again
    from the raw bytes and stamped with the time of the read that completed each (as the
    poller stamped them; `requested_at` is not recovered). A recording whose writer was
    killed is read as far as it goes (`RecordingReader.cut` says how far)."""
    recording = (
        path
        if isinstance(path, RecordingReader)
        else RecordingReader(path, EVENT_TOPIC, METADATA_NAME)
    )
    connections: list[list[MspReply]] = []
    reader = FrameReader()
    for event in recording.events():  # bytes come inside connections (RecordingReader)
        if event.kind == "connected":
            reader = FrameReader()
            connections.append([])
        elif event.kind == "bytes":
            connections[-1].extend(
                MspReply(frame.cmd, frame.payload, event.t, frame.error)
                for frame in reader.feed(event.data)
            )
    return recording.metadata, connections


def record_msp(
    url: str,
    path: Path,
    duration_s: float | None,
    *,
    schedule: Sequence[PollRate] = PAPER_SCHEDULE,
    window: int = DEFAULT_WINDOW,
    version: MspVersion = MspVersion.V1,
    baudrate: int = 115200,
    acc_1g: int | None = None,
    serial_update_rate_hz: int | None = None,
    stop: threading.Event | None = None,
    log: Log = quiet,
) -> PollResult:
    """Poll the FC's MSP port `url` and record it to `path` (docs/recording.md,
    `wftool.fc.msp_poller`); the recording is finished however the run ends. A port that
    cannot be opened leaves no recording behind."""
    check_poll(schedule, window)
    metadata = poll_metadata(url, schedule, window, int(version), serial_update_rate_hz, duration_s)
    recorder = MspRecorder(path, metadata, acc_1g)  # an unwritable path fails before the run
    try:
        link = open_port(url, baudrate, timeout=0)
    except BaseException:
        recorder.discard()
        raise
    try:
        try:
            log(f"polling {url}: {describe(schedule, window)}")
            poller = MspPoller(link, schedule, window=window, version=version)
            result = poller.run(duration_s, recorder, stop)
        finally:
            link.close()
        recorder.finish(result)
    finally:
        recorder.close()
    return result
