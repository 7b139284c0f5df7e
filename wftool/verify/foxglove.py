"""The live stream for Foxglove: a WebSocket server (the Foxglove SDK, extra
`wftool[foxglove]`) publishing the recording's ROS 2 messages as they decode; a `Sink` of
the live loop that never waits for a viewer (how: docs/ros2.md).

    with FoxgloveLive(8765) as view:   # ws://127.0.0.1:8765
        view.packets(packets, health)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from wftool.errors import UsageError
from wftool.extras import require
from wftool.fsp import SensorFrame, StatePacket
from wftool.recording import ros2msg
from wftool.recording.events import Event, StreamHealth
from wftool.recording.ros2msg import (
    BATTERY_TOPIC,
    HEALTH_TOPIC,
    LIVE_PER_FRAME,
    FrameEncoder,
    MessageType,
    Throttle,
)

DEFAULT_PORT = 8765
DEFAULT_HOST = "127.0.0.1"
BACKLOG = 1024
"""Messages queued per client before its oldest are dropped (the SDK's default)."""
TOPICS: dict[str, MessageType] = {
    **{topic: kind for topic, kind, _ in LIVE_PER_FRAME},
    BATTERY_TOPIC: ros2msg.BATTERY_STATE,
    HEALTH_TOPIC: ros2msg.STREAM_HEALTH,
}


class FoxgloveLive:
    """A Foxglove WebSocket server on `host:port` (port 0: any free one); `close()` stops it."""

    def __init__(
        self,
        port: int = DEFAULT_PORT,
        host: str = DEFAULT_HOST,
        *,
        backlog: int = BACKLOG,
        encoder: FrameEncoder | None = None,
    ) -> None:
        require("foxglove", what="the live Foxglove view")
        import foxglove

        self._encoder = encoder or FrameEncoder()
        self._context = context = foxglove.Context()  # channels and server live as long as it
        try:
            self._server = foxglove.start_server(
                name="wftool", host=host, port=port, context=context, message_backlog_size=backlog
            )
        except RuntimeError as exc:  # the SDK's FoxgloveError
            reason = str(exc).removeprefix("FoxgloveError: ")
            raise UsageError(f"cannot serve Foxglove on {host}:{port}: {reason}") from None
        self.host = host
        channels: dict[str, Any] = {
            topic: foxglove.Channel(
                topic,
                schema=foxglove.Schema(name=kind.name, encoding="ros2msg", data=kind.schema_bytes),
                message_encoding="cdr",
                context=context,
            )
            for topic, kind in TOPICS.items()
        }
        self._per_frame = [
            (channels[topic], getattr(self._encoder, method)) for topic, _, method in LIVE_PER_FRAME
        ]
        self._battery = channels[BATTERY_TOPIC]
        self._health = channels[HEALTH_TOPIC]
        self._channels = channels
        self._battery_throttle = Throttle()
        self._last_health: StreamHealth | None = None

    @property
    def port(self) -> int:
        return self._server.port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def subscribed_topics(self) -> set[str]:
        """The topics at least one viewer subscribed to."""
        return {topic for topic, channel in self._channels.items() if channel.has_sinks()}

    def publish(
        self,
        frame: SensorFrame,
        health: StreamHealth | None = None,
        arrival_time: float | None = None,
    ) -> None:
        """Queue `frame`'s messages (and `health`, if new) for the viewers; never blocks."""
        stamp = self._encoder.frame_stamp_ns(frame, arrival_time)
        for channel, encode in self._per_frame:
            if channel.has_sinks():
                channel.log(encode(frame, stamp), log_time=stamp)
        if self._battery_throttle.due(stamp) and self._battery.has_sinks():
            self._battery.log(self._encoder.battery(frame, stamp), log_time=stamp)
        if health is not None and health is not self._last_health:
            self._last_health = health
            if self._health.has_sinks():
                self._health.log(
                    self._encoder.health(health), log_time=self._encoder.stamp_ns(health.t)
                )

    def event(self, event: Event) -> None:
        """Nothing: a viewer sees the frames, not the reads they came in."""

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None = None) -> None:
        """`publish` every frame of `packets`: the call verify's live loop makes per read."""
        for packet in packets:
            for frame in packet.frames:
                self.publish(frame, health, packet.arrival_time)

    def close(self) -> None:
        for channel in self._channels.values():
            channel.close()
        self._channels = {}
        self._server.stop()

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
