"""The ROS 2 node's cost and latency on the virtual FC, beside `FspReader` on the same stream
(docs/bench.md).

    result = run_ros2_bench(sitl_binary, seconds=20.0)
    result.node.cpu_percent_per_khz, result.node.latency, result.hop, result.commands
"""

from __future__ import annotations

import math
import multiprocessing
import tempfile
import time
from array import array
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from wftool.fsp import FspReader, StatePacket
from wftool.fsp.schedule import DEFAULT_RATE_HZ
from wftool.recording.events import Event, StreamHealth
from wftool.ros2.commands import CommandCounts
from wftool.sitl.session import Motion, VirtualFcSession
from wftool.stats import Distribution

NAMESPACE = "/wftool_bench"
IMU_TOPIC = f"{NAMESPACE}/fsp/imu"
COMMAND_TOPIC = f"{NAMESPACE}/fsp/command"
COMMAND_RATE_HZ = 50
"""How often the subscriber's process commands the node while it measures (the rate of
tests/ros2/test_sitl.py's commander)."""
COMMAND_RC = (1500, 1500, 1500, 1000, 1000, 1000)
SETTLE_S = 3.0
"""Time the readers run before measuring: the clock estimator's first lock, discovery."""
READ_TIMEOUT_S = 0.05


@dataclass(frozen=True)
class ReaderFigures:
    name: str
    frames: int
    """Frames read and decoded over the measured time (and published, by the node)."""
    seconds: float
    cpu_s: float
    """The reader's process: user + system time over the measured time."""
    latency: Distribution | None
    """Stamp to frame in hand, µs."""

    @property
    def rate_hz(self) -> float:
        return self.frames / self.seconds if self.seconds else math.nan

    @property
    def cpu_percent(self) -> float:
        """Percent of one core."""
        return 100 * self.cpu_s / self.seconds if self.seconds else math.nan

    @property
    def cpu_percent_per_khz(self) -> float:
        return self.cpu_percent / (self.rate_hz / 1000) if self.frames else math.nan


@dataclass(frozen=True)
class Ros2Bench:
    seconds: float
    rate_hz: int
    direct: ReaderFigures
    node: ReaderFigures
    published: int
    """Frames the node published while the subscriber measured."""
    received_of_published: int
    """Of those, the ones the subscriber received."""
    hop: Distribution | None
    """Per frame: the subscriber's callback minus the node's read, µs."""
    subscriber_cpu_percent: float
    commands: CommandCounts
    """What became of the commands the subscriber's process published at `COMMAND_RATE_HZ`
    while it measured: on a loaded host the node's loop, which sends them between its reads,
    may come to one only after a newer one (superseded) or after the age limit (stale)."""

    @property
    def commands_sent_fraction(self) -> float:
        received = self.commands.received
        return self.commands.sent / received if received else math.nan


def run_ros2_bench(
    binary: Path, seconds: float, rate_hz: int = DEFAULT_RATE_HZ, *, workdir: Path | None = None
) -> Ros2Bench:
    """Stream from a fresh virtual FC: `seconds` read by `FspReader`, then `seconds` by the
    node with a subscriber."""
    spawn = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory(prefix="wftool-bench-ros2-") as scratch:
        fc_dir = workdir or Path(scratch) / "fc"
        with VirtualFcSession(
            binary, fc_dir, rate_hz=rate_hz, motion=Motion(), port_base=None
        ) as session:
            direct = _in_process(spawn, _read_directly, session.fsp_url, seconds)
            node_end, node_conn = spawn.Pipe()
            subscriber_end, subscriber_conn = spawn.Pipe()
            node = spawn.Process(
                target=_run_node, args=(session.fsp_url, seconds, node_conn), daemon=True
            )
            node.start()
            assert node_end.recv() == "ready"  # the node publishes: the subscriber can match
            subscriber = spawn.Process(
                target=_subscribe, args=(seconds, subscriber_conn), daemon=True
            )
            subscriber.start()
            assert subscriber_end.recv() == "measure"  # matched, and settled
            node_end.send("measure")
            received = subscriber_end.recv()
            node_end.send(("stop", received[-1]))  # with the commands the subscriber published
            published = node_end.recv()
            node.join(timeout=30)
            subscriber.join(timeout=30)
    return _figures(seconds, rate_hz, direct, received, published)


def _in_process(spawn: Any, target: Any, *args: Any) -> Any:
    ours, theirs = spawn.Pipe()
    process = spawn.Process(target=target, args=(*args, theirs), daemon=True)
    process.start()
    result = ours.recv()
    process.join(timeout=30)
    return result


def _read_directly(url: str, seconds: float, conn: Connection) -> None:
    """`FspReader` for SETTLE_S, then `seconds` measured: (frames, seconds, cpu, latencies)."""
    latencies = array("q")
    frames = 0
    with FspReader(url) as reader:
        settle_end = time.monotonic() + SETTLE_S
        while time.monotonic() < settle_end:
            reader.read(READ_TIMEOUT_S)
        cpu0, start = time.process_time(), time.monotonic()
        end = start + seconds
        while time.monotonic() < end:
            for packet in reader.read(READ_TIMEOUT_S):
                arrival = packet.arrival_time
                for frame in packet.frames:
                    frames += 1
                    if frame.obc_time is not None and arrival is not None:
                        latencies.append(int((arrival - frame.obc_time) * 1e9))
        cpu, elapsed = time.process_time() - cpu0, time.monotonic() - start
    conn.send((frames, elapsed, cpu, latencies.tobytes()))


class _Reads:
    """A sink beside the node: each frame's stamp and the wall time its read returned."""

    def __init__(self, wall_offset_ns: int) -> None:
        self.offset = wall_offset_ns
        self.stamps = array("q")
        self.reads = array("q")
        self.recording = False

    def event(self, event: Event) -> None:
        pass

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None) -> None:
        if not self.recording:
            return
        offset = self.offset
        for packet in packets:
            read_ns = offset + int((packet.arrival_time or 0.0) * 1e9)
            for frame in packet.frames:
                if frame.obc_time is not None:
                    self.stamps.append(offset + int(frame.obc_time * 1e9))
                    self.reads.append(read_ns)

    def close(self) -> None:
        pass


def _run_node(url: str, seconds: float, conn: Connection) -> None:
    """The node as `wftool ros2` runs it, until told to stop: its CPU from the subscriber's
    start (told by "measure") to "stop", and every frame's stamp and read time meanwhile."""
    import threading

    from wftool.ros2.node import Ros2Bridge, Ros2Options
    from wftool.verify.session import VerifySession

    bridge = Ros2Bridge(Ros2Options(namespace=NAMESPACE, accept_commands=True))
    reads = _Reads(bridge.encoder.wall_offset_ns)
    stop = threading.Event()
    session = VerifySession(url, sinks=[bridge, reads], commander=bridge)
    runner = threading.Thread(target=lambda: session.run(stop=stop), daemon=True)
    runner.start()
    conn.send("ready")
    assert conn.recv() == "measure"
    cpu0, start = time.process_time(), time.monotonic()
    reads.recording = True
    told, published = conn.recv()
    assert told == "stop"
    reads.recording = False
    cpu, elapsed = time.process_time() - cpu0, time.monotonic() - start
    gate = bridge.gate
    assert gate is not None
    # Every command published has reached the gate, and the loop has taken (or dropped) the
    # last: then each is in one count. The bound only ends a wait for a command never coming.
    settled = time.monotonic() + 10.0
    while (gate.counts.received < published or gate.pending) and time.monotonic() < settled:
        time.sleep(0.01)
    stop.set()
    runner.join(timeout=10)
    commands = bridge.command_counts  # only the subscriber's process commanded, measuring
    conn.send((elapsed, cpu, reads.stamps.tobytes(), reads.reads.tobytes(), commands))


def _subscribe(seconds: float, conn: Connection) -> None:
    """fsp/imu, reliable, with the events executor: SETTLE_S after it matched the node, tell
    it to measure, take `seconds` of frames, commanding the node at `COMMAND_RATE_HZ`
    meanwhile: (seconds, cpu, stamps, receive times, commands published, all acknowledged)."""
    import rclpy
    from rclpy.duration import Duration
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu
    from wftool_msgs.msg import RcCommand

    from wftool.ros2.node import DEFAULT_DEPTH

    rclpy.init()
    node = rclpy.create_node("wftool_bench_subscriber")
    stamps, received = array("q"), array("q")
    measuring = False

    def take(message: Any) -> None:
        now = time.time_ns()
        if measuring:
            stamp = message.header.stamp
            stamps.append(stamp.sec * 1_000_000_000 + stamp.nanosec)
            received.append(now)

    qos = QoSProfile(depth=DEFAULT_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
    subscription = node.create_subscription(Imu, IMU_TOPIC, take, qos)
    commander = node.create_publisher(
        RcCommand, COMMAND_TOPIC, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    )

    published = 0

    def command() -> None:
        nonlocal published
        message = RcCommand()
        message.roll, message.pitch, message.yaw, message.throttle, message.aux3, message.aux4 = (
            COMMAND_RC
        )
        stamp = node.get_clock().now().nanoseconds
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        commander.publish(message)
        published += 1

    executor = EventsExecutor()
    executor.add_node(node)
    while subscription.get_publisher_count() == 0:
        executor.spin_once(timeout_sec=0.05)
    settle_end = time.monotonic() + SETTLE_S
    while time.monotonic() < settle_end:
        executor.spin_once(timeout_sec=0.05)
    conn.send("measure")  # the parent tells the node
    measuring = True
    cpu0, start = time.process_time(), time.monotonic()
    end = start + seconds
    next_command = start
    while (now := time.monotonic()) < end:
        if now >= next_command:
            command()
            next_command = now + 1 / COMMAND_RATE_HZ  # one at a time, never to catch up
        executor.spin_once(timeout_sec=max(0.0, min(0.05, next_command - time.monotonic())))
    measuring = False
    cpu, elapsed = time.process_time() - cpu0, time.monotonic() - start
    commander.wait_for_all_acked(Duration(seconds=5))  # the node's reader has every command
    conn.send((elapsed, cpu, stamps.tobytes(), received.tobytes(), published))
    node.destroy_node()
    rclpy.shutdown()


def _figures(
    seconds: float, rate_hz: int, direct: tuple, received: tuple, published: tuple
) -> Ros2Bench:
    frames, elapsed, cpu, latencies = direct
    direct_figures = ReaderFigures(
        "FspReader", frames, elapsed, cpu, Distribution.of(v / 1e3 for v in array("q", latencies))
    )
    sub_elapsed, sub_cpu, stamps_raw, received_raw, _ = received
    node_elapsed, node_cpu, node_stamps_raw, reads_raw, commands = published
    stamps, receive = array("q", stamps_raw), array("q", received_raw)
    read_at = dict(zip(array("q", node_stamps_raw), array("q", reads_raw)))
    node_figures = ReaderFigures(
        "wftool ros2 → subscriber",
        len(read_at),
        node_elapsed,
        node_cpu,
        Distribution.of((r - s) / 1e3 for s, r in zip(stamps, receive)),
    )
    hops = [(r - read_at[s]) / 1e3 for s, r in zip(stamps, receive) if s in read_at]
    # The node measured from the subscriber's start, told a moment later, until after its end.
    window = [s for s in read_at if stamps and stamps[0] <= s <= stamps[-1]]
    taken = set(stamps)
    return Ros2Bench(
        seconds=seconds,
        rate_hz=rate_hz,
        direct=direct_figures,
        node=node_figures,
        published=len(window),
        received_of_published=sum(1 for s in window if s in taken),
        hop=Distribution.of(hops),
        subscriber_cpu_percent=100 * sub_cpu / sub_elapsed if sub_elapsed else math.nan,
        commands=commands,
    )
