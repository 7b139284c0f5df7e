"""The live stream for Foxglove: a WebSocket server (the Foxglove SDK, extra
`wftool[foxglove]`) publishing the recording's ROS 2 messages as they decode; a `Sink` of
the live loop that never waits for a viewer (how: docs/ros2.md).

    with FoxgloveLive(8765) as view:   # ws://127.0.0.1:8765
        view.packets(packets, health)
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import os
import queue
import socket
import threading
from collections.abc import Sequence
from typing import Any

from wftool.display import printable
from wftool.errors import UsageError
from wftool.extras import require
from wftool.fsp import SensorFrame, StatePacket
from wftool.recording import ros2msg
from wftool.recording.events import Event, StreamHealth, new_uplink
from wftool.recording.ros2msg import (
    BATTERY_TOPIC,
    HEALTH_TOPIC,
    LIVE_PER_FRAME,
    UPLINK_STATUS_TOPIC,
    FrameEncoder,
    MessageType,
    Throttle,
)
from wftool.verify.viewer_gate import GateLimits, ViewerGate

DEFAULT_PORT = 8765
DEFAULT_HOST = "127.0.0.1"
BACKLOG = 1024
"""Messages queued per client before its oldest are dropped (the SDK's default)."""
TOPICS: dict[str, MessageType] = {
    **{topic: kind for topic, kind, _ in LIVE_PER_FRAME},
    BATTERY_TOPIC: ros2msg.BATTERY_STATE,
    HEALTH_TOPIC: ros2msg.STREAM_HEALTH,
    UPLINK_STATUS_TOPIC: ros2msg.UPLINK_STATUS,
}


def beyond_localhost(host: str) -> bool:
    """Whether a server bound to `host` is reachable from other machines: any address it
    names that is not loopback (0.0.0.0 and :: are all of them)."""
    try:
        found = socket.getaddrinfo(host or None, None, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError):
        return True  # not known here: binding will say so
    addresses = {str(info[4][0]).split("%")[0] for info in found}  # without an IPv6 scope
    return not all(ipaddress.ip_address(address).is_loopback for address in addresses)


def exposure_warning(host: str, port: int) -> str | None:
    """What to tell the user before serving on `host`, if it reaches beyond this machine."""
    if not beyond_localhost(host):
        return None
    return (
        f"warning: the Foxglove view on {host}:{port} serves the live stream to anyone who "
        "can reach this machine, without authentication"
    )


class FoxgloveLive:
    """A Foxglove WebSocket server on `host:port` (port 0: any free one); `close()` stops it.

    Viewers reach the SDK's server (on 127.0.0.1, a free port) through a `ViewerGate`,
    which bounds what each may cost (`limits`).
    """

    def __init__(
        self,
        port: int = DEFAULT_PORT,
        host: str = DEFAULT_HOST,
        *,
        backlog: int = BACKLOG,
        encoder: FrameEncoder | None = None,
        limits: GateLimits | None = None,
    ) -> None:
        require("foxglove", what="the live Foxglove view")
        import foxglove

        _log_sdk_without_blocking()
        self._encoder = encoder or FrameEncoder()
        self._context = context = foxglove.Context()  # channels and server live as long as it
        try:
            self._server = foxglove.start_server(
                name="wftool",
                host="127.0.0.1",
                port=0,
                context=context,
                message_backlog_size=backlog,
            )
        except RuntimeError as exc:  # the SDK's FoxgloveError
            reason = str(exc).removeprefix("FoxgloveError: ")
            raise UsageError(f"cannot serve Foxglove: {reason}") from None
        try:
            self._gate = ViewerGate(host, port, self._server.port, limits or GateLimits())
        except BaseException:
            self._server.stop()
            raise
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
        self._uplink_status = channels[UPLINK_STATUS_TOPIC]
        self._channels = channels
        self._battery_throttle = Throttle()
        self._last_health: StreamHealth | None = None

    @property
    def port(self) -> int:
        return self._gate.port

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
        """Queue `frame`'s messages (and `health`, and the FC's uplink status in it, if new)
        for the viewers; never blocks."""
        stamp = self._encoder.frame_stamp_ns(frame, arrival_time)
        for channel, encode in self._per_frame:
            if channel.has_sinks():
                channel.log(encode(frame, stamp), log_time=stamp)
        if self._battery_throttle.due(stamp) and self._battery.has_sinks():
            self._battery.log(self._encoder.battery(frame, stamp), log_time=stamp)
        if health is not None and health is not self._last_health:
            before, self._last_health = self._last_health, health
            encoder = self._encoder
            if self._health.has_sinks():
                self._health.log(encoder.health(health), log_time=encoder.stamp_ns(health.t))
            uplink = new_uplink(health, before)
            if uplink is not None and self._uplink_status.has_sinks():
                self._uplink_status.log(
                    encoder.uplink_status(uplink), log_time=encoder.stamp_ns(uplink.t)
                )

    def event(self, event: Event) -> None:
        """Nothing: a viewer sees the frames, not the reads they came in."""

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None = None) -> None:
        """`publish` every frame of `packets`: the call verify's live loop makes per read."""
        for packet in packets:
            for frame in packet.frames:
                self.publish(frame, health, packet.arrival_time)

    def close(self) -> None:
        self._gate.close()
        for channel in self._channels.values():
            channel.close()
        self._channels = {}
        self._server.stop()

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class _LogBehind(logging.Handler):
    """Hands log records to a thread that writes them to stderr, through a bounded queue;
    what does not fit is dropped (and counted): a stderr nobody reads blocks that thread
    only, never the one that logs."""

    def __init__(self, capacity: int = 256) -> None:
        super().__init__(logging.WARNING)
        self._lines: queue.Queue[str] = queue.Queue(capacity)
        self.dropped = 0
        threading.Thread(target=self._write, name="foxglove log", daemon=True).start()

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._lines.put_nowait(f"foxglove: {printable(record.getMessage())}\n")
        except queue.Full:
            self.dropped += 1

    def _write(self) -> None:
        while True:
            line = self._lines.get().encode("utf-8", "replace")
            with contextlib.suppress(OSError):  # no stderr: nothing to say it on
                os.write(2, line)  # not sys.stderr: its lock would be held while it blocks


def _log_sdk_without_blocking() -> None:
    """The SDK logs into Python's logging from its own threads (a failed handshake, a
    dropped viewer). With no handler configured, logging's last resort writes to stderr from
    those threads, and on a pipe nobody reads that write blocks: the server stops. Unless
    the program set up logging itself, the SDK's records go through `_LogBehind`."""
    logger = logging.getLogger("foxglove")
    if logger.handlers or logging.getLogger().handlers:
        return
    logger.addHandler(_LogBehind())
    logger.propagate = False
