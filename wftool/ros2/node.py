"""The live ROS 2 node: the FSP stream published as it is decoded, commands taken from ROS 2
(topics, QoS, who may reach it: docs/ros2.md).

    bridge = Ros2Bridge(Ros2Options(accept_commands=True))
    VerifySession(url, sinks=[bridge], commander=bridge).run()     # wftool.verify.session
"""

from __future__ import annotations

import importlib
import math
import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wftool.errors import Ros2Error, UsageError
from wftool.extras import require
from wftool.fsp import ArmingAction, StatePacket, UplinkFlag, UplinkStatus
from wftool.recording import ros2msg as msgs
from wftool.recording.events import Event, StreamHealth, UplinkReport, new_uplink
from wftool.recording.ros2msg import AUTHORITY_UNKNOWN, FrameEncoder, Throttle
from wftool.ros2.commands import DEFAULT_MAX_AGE_NS, CommandCounts, CommandGate

NODE_NAME = "wftool"
COMMAND_TOPIC = "fsp/command"
COMMAND_STATUS_TOPIC = "fsp/command_status"
DEFAULT_DEPTH = 1000
"""Messages a publisher keeps per topic for a reliable subscriber that falls behind (1 s at
1 kHz; ~0.4 MB a topic); beyond that the oldest are dropped, and the loop never waits."""
STATUS_DEPTH = 10
"""Messages a publisher keeps per status topic (1 s at 10 Hz) to repeat to a reliable
subscriber that missed them, and to send a late joiner (the newest last): the same second
of slack as the per-frame topics'."""
DISCOVERY_RANGE = "ROS_AUTOMATIC_DISCOVERY_RANGE"
FAST_DDS = "rmw_fastrtps_cpp"
FAST_DDS_PROFILES = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
THIS_HOST_PROFILE = Path(__file__).with_name("this_host.xml")
PUBLICATION_MODE = "RMW_FASTRTPS_PUBLICATION_MODE"
PUBLISH_BACKLOG = 1000
"""Reads the publishing thread may be behind by (~1 s of a 1 kHz stream) before the live loop
waits for it."""
SPIN_TIMEOUT_S = 0.1
"""How long the command thread waits for a command before it looks whether to stop."""
ARMING_REQUESTS = {1: ArmingAction.ARM, 2: ArmingAction.DISARM}
"""`RcCommand.arming` (ARMING_ARM, ARMING_DISARM) as what the FC is asked; 0 asks nothing."""
_COUNTS = (
    "received", "sent", "stale", "out_of_range", "unstamped", "not_newer", "superseded",
    "foreign", "links", "arming_sent", "arming_refused",
)  # fmt: skip
"""The `CommandCounts` fields `CommandStatus` carries, under the same names."""


def _relative(topic: str) -> str:
    return topic.lstrip("/")  # under the node's namespace


@dataclass(frozen=True)
class Ros2Options:
    namespace: str = "/"
    """The node's namespace: topics are `<namespace>/fsp/...`."""
    frame_id: str = msgs.FRAME_ID
    accept_commands: bool = False
    command_max_age_ns: int = DEFAULT_MAX_AGE_NS
    depth: int = DEFAULT_DEPTH
    domain_id: int | None = None
    """The DDS domain; None: ROS_DOMAIN_ID, or 0."""

    def __post_init__(self) -> None:
        if not self.namespace.startswith("/"):
            raise UsageError(f"a namespace starts with '/': {self.namespace!r}")
        if not self.frame_id or not self.frame_id.isprintable() or len(self.frame_id) > 255:
            raise UsageError(f"a frame id is 1-255 printable characters: {self.frame_id!r}")
        if self.command_max_age_ns <= 0:
            raise UsageError("the command age limit must be positive")
        if self.depth < 1:
            raise UsageError("the queue depth must be at least 1")


def discovery_scope() -> str:
    """Keep the node on this host unless the user chose otherwise; what it is, in words. Call
    before the node starts (it sets the environment the middleware reads).

    On this host: ROS 2's automatic discovery range LOCALHOST, and (unless the user has a Fast
    DDS profile of their own) `this_host.xml`, which puts Fast DDS on the loopback interface
    and shared memory alone: the discovery range keeps discovery in, the profile keeps
    everyone else out, even a peer that addresses this host directly."""
    chosen = os.environ.get(DISCOVERY_RANGE, "").strip().upper()
    if chosen not in ("", "LOCALHOST"):
        scope = {
            "SUBNET": "the local network",
            "OFF": "no automatic discovery: static peers only",
            "SYSTEM_DEFAULT": "the middleware's default",
        }.get(chosen, chosen)
        return f"{scope} ({DISCOVERY_RANGE}={chosen}, as set){_peers()}"
    os.environ[DISCOVERY_RANGE] = "LOCALHOST"
    scope = "this host only"
    if not chosen:
        scope += f" ({DISCOVERY_RANGE}=LOCALHOST; set it to SUBNET to widen)"
    rmw = os.environ.get("RMW_IMPLEMENTATION", FAST_DDS)
    own = [os.environ[name] for name in FAST_DDS_PROFILES if os.environ.get(name)]
    if rmw != FAST_DDS:
        scope += f"; {rmw}'s transports are not restricted by wftool"
    elif own:
        scope += f"; transports as your Fast DDS profile {own[0]} says"
    else:
        os.environ[FAST_DDS_PROFILES[0]] = str(THIS_HOST_PROFILE)
        scope += "; Fast DDS on loopback and shared memory"
    return scope + _peers()


def _peers() -> str:
    peers = os.environ.get("ROS_STATIC_PEERS", "").strip()
    return f"; static peers {peers}" if peers else ""


class Ros2Bridge:
    """A ROS 2 node publishing a live FSP stream (a sink of the live loop) and, with
    `accept_commands`, the gate for commands from `fsp/command`. `close()` ends it."""

    def __init__(self, options: Ros2Options, *, encoder: FrameEncoder | None = None) -> None:
        require("ros2", what="the ROS 2 node")
        try:
            from wftool_msgs.msg import CommandStatus, RcCommand
        except ImportError:
            raise Ros2Error(
                "the ROS 2 node needs wftool_msgs' type support: wftool ros2 --build-msgs "
                "(cmake and g++), or a sourced workspace where wftool_msgs is built"
            ) from None
        import rclpy
        from rclpy.context import Context
        from rclpy.impl.implementation_singleton import rclpy_implementation
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        self.options = options
        self.discovery = discovery_scope()
        # Fast DDS sends from the publishing thread instead of handing each message to a
        # thread of its own: at 1 kHz half the CPU and a fraction of the P99 latency.
        os.environ.setdefault(PUBLICATION_MODE, "SYNCHRONOUS")
        self._context = context = Context()
        rclpy.init(
            args=[],
            context=context,
            domain_id=options.domain_id,
            signal_handler_options=SignalHandlerOptions.NO,  # wftool's own handlers end a run
        )
        try:
            self._node = node = rclpy.create_node(
                NODE_NAME,
                namespace=options.namespace,
                context=context,
                start_parameter_services=False,
                enable_rosout=False,
            )
        except Exception as exc:  # rclpy's own errors: a bad namespace, no middleware
            rclpy.shutdown(context=context)
            raise Ros2Error(f"the ROS 2 node did not start: {exc}") from None
        self.name = node.get_fully_qualified_name()
        self.domain_id = context.get_domain_id()
        self._clock = node.get_clock()
        self._encoder = encoder or FrameEncoder(
            self.ros_now_ns() - time.monotonic_ns(), options.frame_id
        )
        stream = QoSProfile(
            depth=options.depth,
            history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        latest = QoSProfile(  # a late subscriber gets the latest at once
            depth=STATUS_DEPTH,
            history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        encoder = self._encoder
        refused: type[Exception] = rclpy_implementation.RCLError
        self.unpublished = 0
        """Messages the middleware refused (a reliable writer that waited its longest for a
        stalled reader): a live stream drops them and goes on."""

        def publishing(publisher: Any) -> Callable[[Any], None]:
            def publish(message: Any) -> None:
                try:
                    publisher.publish(message)
                except refused:
                    self.unpublished += 1

            return publish

        def publisher(topic: str, kind: msgs.MessageType, qos: Any) -> Callable[[Any], None]:
            created: Any = node.create_publisher(_message_class(kind.name), _relative(topic), qos)
            return publishing(created)

        self._per_frame = [
            (publisher(topic, kind, stream), getattr(encoder, method))
            for topic, kind, method in msgs.LIVE_PER_FRAME
        ]
        self._battery = publisher(msgs.BATTERY_TOPIC, msgs.BATTERY_STATE, latest)
        self._health = publisher(msgs.HEALTH_TOPIC, msgs.STREAM_HEALTH, latest)
        self._uplink_status = publisher(msgs.UPLINK_STATUS_TOPIC, msgs.UPLINK_STATUS, latest)
        self._publish_status = publishing(
            node.create_publisher(CommandStatus, COMMAND_STATUS_TOPIC, latest)
        )
        self._status_type = CommandStatus
        self._battery_throttle = Throttle()
        self._status_throttle = Throttle()
        self._last_health: StreamHealth | None = None
        self.fc_status: UplinkStatus | None = None
        """The FC's newest uplink status the node was given (who flies, its pulse range)."""
        self._arming: ArmingAction | None = None
        # Publishing on a thread of its own: the live loop, which sends the commands, never
        # waits for the middleware (a loaded host's backlog of frames superseded commands).
        self._backlog: queue.Queue[_Published | None] = queue.Queue(PUBLISH_BACKLOG)
        self._publish_error: BaseException | None = None
        self._publisher = threading.Thread(
            target=self._publishing, name="ros2-publish", daemon=True
        )
        self.gate: CommandGate | None = None
        self._executor: Any = None
        self._spinner: threading.Thread | None = None
        self._stopping = threading.Event()
        if options.accept_commands:
            self.gate = CommandGate(options.command_max_age_ns)
            commands = QoSProfile(  # any publisher matches; the newest commands count
                depth=10, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT
            )
            node.create_subscription(RcCommand, COMMAND_TOPIC, self._on_command, commands)
            self._start_executor()
        self.topics = self._topic_names()
        """Every topic the node publishes or subscribes to, by full name."""
        self._publisher.start()

    def _topic_names(self) -> list[str]:
        names = [p.topic_name for p in self._node.publishers]
        if self.options.accept_commands:
            names += [s.topic_name for s in self._node.subscriptions]
        return sorted(names)

    def _start_executor(self) -> None:
        # Not rclpy's EventsExecutor: it fails a callback that takes the message info
        # ("SystemError: null argument to internal routine", Kilted), which carries the
        # publisher's GID the gate latches.
        from rclpy.executors import SingleThreadedExecutor

        self._executor = executor = SingleThreadedExecutor(context=self._context)
        executor.add_node(self._node)
        stopping = self._stopping

        def spin() -> None:
            while not stopping.is_set():
                executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)

        self._spinner = threading.Thread(target=spin, name="ros2-commands", daemon=True)
        self._spinner.start()

    def ros_now_ns(self) -> int:
        """Now on the node's ROS clock, ns."""
        return self._clock.now().nanoseconds

    @property
    def encoder(self) -> FrameEncoder:
        return self._encoder

    # The live loop's sink.

    def event(self, event: Event) -> None:
        """Events (reads, connects) are the recording's business; the node publishes frames."""

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None = None) -> None:
        """Hand every frame of `packets` (and `health`, and the FC's uplink status in it, if
        new) to the publishing thread; what the FC says of who flies and of its pulse range
        holds at once, for the commands."""
        if self._publish_error is not None:
            raise self._publish_error
        uplink = None
        if health is not None and health is not self._last_health:
            before, self._last_health = self._last_health, health
            uplink = new_uplink(health, before)
            if uplink is not None:
                self.fc_status = uplink.status
                if self.gate is not None:
                    self.gate.pulse_range = uplink.status.pulse_range
        else:
            health = None
        self._backlog.put(_Published(packets, health, uplink))

    def flush(self) -> None:
        """Return once everything handed to `packets` so far is published (or refused)."""
        self._backlog.join()

    def _publishing(self) -> None:
        """The publishing thread: each read's frames, in order, until `close`; after an
        error it only empties the backlog (`packets` raises it in the loop)."""
        while (item := self._backlog.get()) is not None:
            try:
                if self._publish_error is None:
                    self._publish(item)
            except BaseException as exc:  # raised in the loop's thread, by `packets`
                self._publish_error = exc
            finally:
                self._backlog.task_done()
        self._backlog.task_done()

    def _publish(self, item: _Published) -> None:
        encoder = self._encoder
        stamp = 0
        for packet in item.packets:
            arrival = packet.arrival_time
            for frame in packet.frames:
                stamp = encoder.frame_stamp_ns(frame, arrival)
                for publish, encode in self._per_frame:
                    publish(encode(frame, stamp))
                if self._battery_throttle.due(stamp):
                    self._battery(encoder.battery(frame, stamp))
        if item.health is not None:
            self._health(encoder.health(item.health))
        if item.uplink is not None:
            self._uplink_status(encoder.uplink_status(item.uplink))
        if stamp and self._status_throttle.due(stamp):
            self.publish_command_status(stamp)

    def close(self) -> None:
        import rclpy

        self._stopping.set()
        if self._publisher.is_alive():
            self._backlog.put(None)
            self._publisher.join()
        if self._spinner is not None:
            self._spinner.join()
            self._spinner = None
        if self._executor is not None:
            self._executor.shutdown()
            self._executor = None
        if self._context.ok():
            self._node.destroy_node()
            rclpy.shutdown(context=self._context)

    # Commands.

    def _on_command(self, message: Any, info: Any) -> None:
        """A command from `fsp/command`: its publisher (the GID in the message info) and
        its arrival on the node's monotonic clock go to the gate with it. It arrived when the
        middleware received it (the message info's `received_timestamp`, on the wall clock),
        not when the executor came to it: a command that waited in the reader's queue has
        used up that much of its age limit."""
        assert self.gate is not None
        arrived_ns = time.monotonic_ns() - _waited_ns(info)
        rc: tuple[int, ...] = (
            message.roll,
            message.pitch,
            message.yaw,
            message.throttle,
            message.aux3,
            message.aux4,
        )
        if message.arming and message.arming not in ARMING_REQUESTS:
            rc = ()  # an undefined request: not what a command may carry
        gid = info.get("publisher_gid") if isinstance(info, dict) else None
        publisher = bytes(gid["data"]) if gid else None
        stamp = message.header.stamp
        self.gate.offer(
            rc,
            stamp.sec * 1_000_000_000 + stamp.nanosec,
            publisher,
            arrived_ns,
            ARMING_REQUESTS.get(message.arming),
        )

    @property
    def due(self) -> float:
        """When the live loop should ask for a command (a `live.Commander`): now if one is
        waiting, else whenever it reads anyway."""
        return 0.0 if self.gate is not None and self.gate.pending else math.inf

    def command(self, t: float = 0.0) -> tuple[int, ...] | None:
        """The command to send now (fresh, in range, not sent before, of the publisher
        latched), if there is one."""
        self._arming = None
        if self.gate is None or not self.gate.pending:
            return None
        taken = self.gate.take(time.monotonic_ns())
        if taken is None:
            return None
        self._arming = taken.arming
        return taken.rc

    def sent(self, t: float = 0.0) -> None:
        """The port took the command `command` gave."""
        if self.gate is not None:
            self.gate.sent()

    def arming(self, t: float = 0.0) -> ArmingAction | None:
        """The arming request to send after the command `command` gave, if its publisher
        asked for one and the FC said its receiver is the OBC (spec §14: under a safety
        pilot arming is the pilot's, and the FC would refuse it and disengage the OBC)."""
        action, self._arming = self._arming, None
        if action is None or self.gate is None:
            return None
        status = self.fc_status
        forwarded = status is not None and status.has(UplinkFlag.OBC_RECEIVER)
        self.gate.arming(forwarded)
        return action if forwarded else None

    @property
    def command_counts(self) -> CommandCounts:
        return self.gate.counts if self.gate is not None else CommandCounts()

    def publish_command_status(self, stamp_ns: int | None = None) -> None:
        counts = self.command_counts
        status = self._status_type()
        stamp_ns = self.ros_now_ns() if stamp_ns is None else stamp_ns
        status.header.stamp.sec, status.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        status.header.frame_id = self.options.frame_id
        status.accepting = self.gate is not None
        status.max_age_s = self.options.command_max_age_ns / 1e9
        for name in _COUNTS:
            setattr(status, name, getattr(counts, name))
        publisher = self.gate.latched(time.monotonic_ns()) if self.gate is not None else None
        status.publisher = publisher.hex() if publisher is not None else ""
        fc = self.fc_status
        authority = fc.authority if fc is not None else None
        status.authority = AUTHORITY_UNKNOWN if authority is None else int(authority)
        status.steering = authority is not None and authority.steers
        self._publish_status(status)


@dataclass(frozen=True)
class _Published:
    """One read's worth for the publishing thread: its packets, and the health snapshot and
    uplink status that are new with it (None: none)."""

    packets: Sequence[StatePacket]
    health: StreamHealth | None
    uplink: UplinkReport | None


def _waited_ns(info: Any) -> int:
    """How long a message waited between the middleware's receipt (`received_timestamp` of
    its message info, the wall clock) and now; 0 if the middleware did not say, or if the wall
    clock stepped back meanwhile (a step forward makes it older: dropped sooner, never
    sent later)."""
    received = info.get("received_timestamp") if isinstance(info, dict) else None
    if not received:
        return 0
    return max(0, time.time_ns() - int(received))


def _message_class(name: str) -> type:
    package, kind, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), type_name)
