"""ROS 2 recordings: a rosbag2 directory with one MCAP file (`ros2` profile, CDR messages), or
that MCAP file alone, which `ros2 bag play`, rosbags, Foxglove and PlotJuggler open as is.

`BagFile` is the container for any topics; `RosbagWriter` records the FSP stream's
(`/fsp/imu`, `/fsp/rpm`, `/fsp/rc`, `/fsp/battery`, `/fsp/health`, `/fsp/uplink_status`,
`/fsp/events`). Layout,
topics and rates: docs/recording.md.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Sequence
from pathlib import Path

from wftool import __version__
from wftool.errors import RecordingError, UsageError
from wftool.fsp import SensorFrame, StatePacket
from wftool.recording import ros2msg
from wftool.recording.events import EVENT_TOPIC, Event, StreamHealth, new_uplink
from wftool.recording.mcapprocess import McapProcess
from wftool.recording.ros2msg import (
    BATTERY_TOPIC,
    HEALTH_TOPIC,
    IMU_TOPIC,
    RC_TOPIC,
    RPM_TOPIC,
    SLOW_PERIOD_NS,
    UPLINK_STATUS_TOPIC,
    FrameEncoder,
    MessageType,
    Throttle,
)

TOPICS: dict[str, MessageType] = {
    IMU_TOPIC: ros2msg.IMU,
    RPM_TOPIC: ros2msg.MOTOR_RPM,
    RC_TOPIC: ros2msg.RC_CHANNELS,
    BATTERY_TOPIC: ros2msg.BATTERY_STATE,
    HEALTH_TOPIC: ros2msg.STREAM_HEALTH,
    UPLINK_STATUS_TOPIC: ros2msg.UPLINK_STATUS,
    EVENT_TOPIC: ros2msg.STREAM_EVENTS,
}
METADATA_VERSION = 8
CLOSED_KEY = "closed"
"""A recording's metadata says whether it was closed: "false" from its start, "true" once
it is (written again at its end): one whose run was killed says "false" (cut short)."""
EVENT_BATCH_S = 0.5
"""Events go into one `StreamEvents` message until it spans this long (OBC time)."""


def bag_file(path: Path) -> Path:
    """The MCAP file of a recording: `path` itself, or the one in a rosbag2 directory."""
    if not path.is_dir():
        return path
    files = sorted(path.glob("*.mcap"))
    if len(files) != 1:
        found = ", ".join(f.name for f in files) or "none"
        raise UsageError(f"{path} is no wftool recording: expected one .mcap file, found {found}")
    return files[0]


class BagFile:
    """A recording's container: the rosbag2 directory `path` (which must not exist, or be
    empty), or, for a `path` ending in `.mcap`, that one MCAP file (which must not exist),
    with one CDR channel per topic of `topics` and `custom` as its metadata.

    `channels` maps each topic to the channel id `add` takes. `custom` may grow until
    `close()`, which writes it again, closed (`CLOSED_KEY`), into the MCAP file and into
    metadata.yaml with the message counts.
    """

    def __init__(
        self,
        path: Path,
        topics: dict[str, MessageType],
        metadata_name: str,
        custom: dict[str, str],
    ) -> None:
        if path.exists() and not (path.is_dir() and not any(path.iterdir())):
            raise UsageError(f"cannot write the recording: {path} already exists")
        if path.suffix == ".mcap":
            if path.is_dir():
                raise UsageError(f"cannot write the recording: {path} is a directory")
            self.directory, self.mcap_path = None, path
            self.metadata_path: Path | None = None
        else:
            self.directory, self.mcap_path = path, path / f"{path.name}_0.mcap"
            self.metadata_path = path / "metadata.yaml"
        self.topics = topics
        self.metadata_name = metadata_name
        self.custom = custom
        custom[CLOSED_KEY] = "false"
        created = False
        try:
            if self.directory is not None:
                self.directory.mkdir()
                created = True
        except FileExistsError:
            pass  # empty, as checked; the MCAP file (created exclusively) is what claims it
        except OSError as exc:
            raise UsageError(f"cannot write the recording: {exc}") from None
        self._created = created
        self._out: McapProcess | None = None
        try:
            self._out = McapProcess(self.mcap_path, "ros2", f"wftool {__version__}")
            self.channels = {
                topic: self._out.register_channel(
                    topic, "cdr", self._out.register_schema(kind.name, "ros2msg", kind.schema_bytes)
                )
                for topic, kind in topics.items()
            }
            self._out.add_metadata(metadata_name, custom)
            self._write_metadata()  # now, so an unwritable directory shows before the run
        except (OSError, UsageError) as exc:
            self._remove(created)
            if isinstance(exc, UsageError):
                raise
            raise UsageError(f"cannot write the recording: {exc}") from None

    @property
    def _writer(self) -> McapProcess:
        """The writer process, while the recording is open."""
        if self._out is None:
            raise RuntimeError(f"the recording {self.mcap_path} is closed")
        return self._out

    def add(self, channel: int, log_ns: int, data: bytes) -> None:
        """One message on `channel` (an id of `channels`), logged at `log_ns`."""
        self._writer.add_message(channel, log_ns, data)

    def __enter__(self) -> BagFile:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A further metadata record in the MCAP file (e.g. a run's results, at its end)."""
        if self._out is not None:
            self._out.add_metadata(name, data)

    def discard(self) -> None:
        """Close and delete what was created: the run never started."""
        self._remove(self._created)
        self._out = None

    def close(self) -> None:
        """Say it was closed, finish the MCAP file and write the final metadata (also after a
        failure)."""
        if self._out is None:
            return
        out, self._out = self._out, None
        try:
            with contextlib.ExitStack() as finishing:
                finishing.callback(out.finish)
                if out.failure is None:  # a failed recording is cut short: it says "false"
                    out.add_metadata(self.metadata_name, {**self.custom, CLOSED_KEY: "true"})
        finally:
            if out.failure is None:
                self.custom[CLOSED_KEY] = "true"
            self._finish_metadata(out)

    def _finish_metadata(self, out: McapProcess) -> None:
        if self.metadata_path is None:
            return
        try:
            self._write_metadata(out)
        except OSError as exc:
            self.metadata_path.with_suffix(".yaml.tmp").unlink(missing_ok=True)
            if out.failure is None:
                raise RecordingError(
                    f"cannot update {self.metadata_path} ({exc.strerror or exc}): it still "
                    f"lists no messages; {self.mcap_path.name} is complete"
                ) from None
            # The recording already failed and said so; the metadata of the start stays.

    def _write_metadata(self, out: McapProcess | None = None) -> None:
        if self.metadata_path is None:  # one MCAP file: its own summary says it all
            return
        counts = {topic: 0 for topic in self.topics}
        start = duration = 0
        if out is not None:
            by_id = {channel: topic for topic, channel in self.channels.items()}
            for channel, count in out.message_counts.items():
                counts[by_id[channel]] = count
            if out.time_range is not None:
                start, duration = out.time_range[0], out.time_range[1] - out.time_range[0]
        types = {topic: kind.name for topic, kind in self.topics.items()}
        text = metadata_yaml(self.mcap_path.name, types, counts, start, duration, self.custom)
        write_metadata(self.metadata_path, text)

    def _remove(self, created: bool) -> None:
        """Delete what this recording wrote, and nothing of another run's at its path: the
        metadata is its own only once its MCAP file is (which another run can win)."""
        if self._out is not None:
            self._out.discard()
            if self.metadata_path is not None:
                for path in (self.metadata_path, self.metadata_path.with_suffix(".yaml.tmp")):
                    path.unlink(missing_ok=True)
        if created and self.directory is not None:
            with contextlib.suppress(OSError):  # not empty: another run records there
                self.directory.rmdir()


class RosbagWriter(BagFile):
    """The FSP stream's recording (the `/fsp/...` topics), in a `BagFile` at `path`."""

    def __init__(self, path: Path, metadata_name: str, metadata: dict[str, str]) -> None:
        self._encoder = FrameEncoder()
        custom = {
            **metadata,
            "wftool": __version__,
            "wall_offset_ns": str(self._encoder.wall_offset_ns),  # Unix minus OBC monotonic time
        }
        super().__init__(path, TOPICS, metadata_name, custom)
        self._writer.before_chunk = self._write_events  # a chunk's frames bring their bytes
        ids = self.channels
        self._imu, self._rpm, self._rc = ids[IMU_TOPIC], ids[RPM_TOPIC], ids[RC_TOPIC]
        self._battery, self._health = ids[BATTERY_TOPIC], ids[HEALTH_TOPIC]
        self._uplink_status = ids[UPLINK_STATUS_TOPIC]
        self._events = ids[EVENT_TOPIC]
        self._battery_throttle = Throttle()
        self._rc_sent: tuple | None = None  # values of the last RC message
        self._rc_sent_ns = 0  # its stamp
        self._rc_previous: tuple = ()  # (frame, stamp) of the latest frame seen
        self._last_health: StreamHealth | None = None
        self._log_ns = 0
        self._event_batch: list[Event] = []

    @property
    def wall_offset_ns(self) -> int:
        """Unix time minus OBC monotonic time, ns: how the stamps were made."""
        return self._encoder.wall_offset_ns

    def event(self, event: Event) -> None:
        """A connect, disconnect, read or command, for `/fsp/events`."""
        t = event.t
        self._log_ns = self._encoder.stamp_ns(t)
        batch = self._event_batch
        if batch and not 0 <= t - batch[0].t < EVENT_BATCH_S:
            self._write_events()
        self._event_batch.append(event)

    def _write_events(self) -> None:
        batch, self._event_batch = self._event_batch, []
        if batch:
            log_ns = self._encoder.stamp_ns(batch[0].t)
            self._writer.add_message(self._events, log_ns, ros2msg.encode_events(batch), apart=True)

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None = None) -> None:
        """The frames of `packets`, and `health` if it is a new snapshot (with the FC's
        uplink status, if that is new too)."""
        add, encoder = self._writer.add_message, self._encoder
        imu_id, rpm_id = self._imu, self._rpm
        imu, rpm = encoder.imu, encoder.rpm
        log_ns = self._log_ns
        for packet in packets:
            arrival = packet.arrival_time
            log_ns = encoder.stamp_ns(arrival) if arrival is not None else time.time_ns()
            for frame in packet.frames:
                stamp = encoder.frame_stamp_ns(frame, arrival)
                add(imu_id, log_ns, imu(frame, stamp))
                add(rpm_id, log_ns, rpm(frame, stamp))
                rc = frame.values[13:19]
                if rc != self._rc_sent or not 0 <= stamp - self._rc_sent_ns < SLOW_PERIOD_NS:
                    self._rc_message(frame, stamp, log_ns, rc)
                self._rc_previous = (frame, stamp)
                if self._battery_throttle.due(stamp):
                    add(self._battery, log_ns, encoder.battery(frame, stamp))
        self._log_ns = log_ns
        if health is not None and health is not self._last_health:
            before, self._last_health = self._last_health, health
            add(self._health, log_ns, encoder.health(health))
            uplink = new_uplink(health, before)
            if uplink is not None:
                add(self._uplink_status, log_ns, encoder.uplink_status(uplink))

    def _rc_message(self, frame: SensorFrame, stamp: int, log_ns: int, rc: tuple) -> None:
        add, encode = self._writer.add_message, self._encoder.rc
        if rc != self._rc_sent and self._rc_previous:
            previous, previous_stamp = self._rc_previous
            if previous_stamp != self._rc_sent_ns:  # the old value's last frame: a step
                add(self._rc, log_ns, encode(previous, previous_stamp))
        add(self._rc, log_ns, encode(frame, stamp))
        self._rc_sent, self._rc_sent_ns = rc, stamp

    def close(self) -> None:
        """Hand the last events over, then finish as any `BagFile` (also after a failure)."""
        out = self._out
        if out is None:
            return
        try:
            self._write_events()
        finally:
            out.before_chunk = None
            super().close()


def _quoted(value: str) -> str:
    return json.dumps(value)  # a JSON string is a YAML double-quoted scalar


def write_metadata(path: Path, text: str) -> None:
    """metadata.yaml replaced by `text` at once (never half written)."""
    temporary = path.with_suffix(".yaml.tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


def metadata_yaml(
    file_name: str,
    topics: dict[str, str],
    counts: dict[str, int],
    start_ns: int,
    duration_ns: int,
    custom: dict,
) -> str:
    """rosbag2's metadata.yaml (version 8) of the MCAP file `file_name`, its topics by type
    name: the fields every reader back to Humble needs."""
    total = sum(counts.values())
    lines = [
        "rosbag2_bagfile_information:",
        f"  version: {METADATA_VERSION}",
        "  storage_identifier: mcap",
        f"  duration:\n    nanoseconds: {duration_ns}",
        f"  starting_time:\n    nanoseconds_since_epoch: {start_ns}",
        f"  message_count: {total}",
        "  topics_with_message_count:",
    ]
    for topic, type_name in topics.items():
        lines += [
            "    - topic_metadata:",
            f"        name: {_quoted(topic)}",
            f"        type: {_quoted(type_name)}",
            "        serialization_format: cdr",
            '        offered_qos_profiles: ""',
            '        type_description_hash: ""',
            f"      message_count: {counts[topic]}",
        ]
    lines += [
        '  compression_format: ""',
        '  compression_mode: ""',
        f"  relative_file_paths:\n    - {_quoted(file_name)}",
        "  files:",
        f"    - path: {_quoted(file_name)}",
        f"      starting_time:\n        nanoseconds_since_epoch: {start_ns}",
        f"      duration:\n        nanoseconds: {duration_ns}",
        f"      message_count: {total}",
        "  custom_data:",
        *(f"    {_quoted(key)}: {_quoted(str(value))}" for key, value in custom.items()),
        '  ros_distro: ""',
    ]
    return "\n".join(lines) + "\n"
