"""Scaffolding for the ROS 2 tests: separate rclpy processes on the real middleware.

    python -m tests.ros2.peers subscribe OUT SECONDS TOPIC=TYPE ...
    python -m tests.ros2.peers publish BAG SECONDS NAMESPACE
    python -m tests.ros2.peers command TOPIC PLAN SECONDS
    python -m tests.ros2.peers node NAMESPACE SECONDS

`subscribe` is the independent receiving side: typed subscriptions (rclpy's own type
support decodes), reliable QoS (TOPIC=TYPE=latest: the latest only, transient local, as a
late joiner asks for what was published before it), every message written to OUT as a JSON line
{"topic", "received_ns", "message"} when it ends (SECONDS after every topic has a
publisher, IDLE_S after the last message, at SIGTERM, or when no publisher is found within
DISCOVERY_S); it prints "ready" once subscribed, "matched" once every topic has a publisher.
`publish` plays a recording's messages as `ros2 bag play` would: the stored CDR bytes,
as they are, on each topic (under NAMESPACE) with its type, once every topic is matched.
`command` is a ROS 2 program commanding the aircraft: it publishes `wftool_msgs/RcCommand`
on TOPIC as the JSON PLAN says, a list of {"rc": [six values], "age_ns": how old its stamp
is made (negative: ahead; a clock stepped back), "same_stamp": reuse the previous stamp,
"no_stamp": leave it unset, "arming": the request (1 arm, 2 disarm), "after_s": wait first};
it prints "matched" once it found the node, "done" when the plan is through.
`node` is wftool's node taking commands (`Ros2Bridge`, accept_commands) for SECONDS, as the
live loop would (it takes a command every millisecond); it prints its discovery scope, then
its command counts as JSON.
The tests run them through `subscriber()`, `play()`, `command()` and `node()` below.
"""

from __future__ import annotations

import array
import dataclasses
import importlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
QOS_DEPTH = 10_000
IDLE_S = 3.0
"""A subscriber stops this long after the last message."""
DISCOVERY_S = 30.0
"""A subscriber waits this long for its publishers: after its first few announcements Fast DDS
announces every 3 s, and a loaded host can miss the first few."""


def namespace_of(tmp_path: Path) -> str:
    """A ROS 2 namespace of the test's own: no other test, of this session or another one
    running on the machine, is heard."""
    return f"/t{os.getpid()}_" + "".join(c for c in tmp_path.name if c.isalnum())


def message_class(name: str) -> type:
    """The rclpy class of a ROS 2 type name such as `sensor_msgs/msg/Imu`."""
    package, kind, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), type_name)


def plain(value: Any) -> Any:
    """A message (rclpy's or rosbags') as plain data: dicts by field, lists, numbers; NaN as
    the string "nan", so two decodings compare with ==."""
    if hasattr(value, "get_fields_and_field_types"):  # rclpy
        return {name: plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):  # rosbags
        names = [f.name for f in dataclasses.fields(value)]
        fields = [n for n in names if not n.startswith("__") and not n.isupper()]  # constants
        return {name: plain(getattr(value, name)) for name in fields}
    if isinstance(value, (list, tuple, array.array)) or type(value).__name__ == "ndarray":
        return [plain(v) for v in value]
    if hasattr(value, "item"):  # a NumPy scalar
        value = value.item()
    if isinstance(value, bytes):
        return list(value)
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    return value


def _reliable(latest: bool = False):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    if latest:
        return QoSProfile(
            depth=1,
            history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
    return QoSProfile(
        depth=QOS_DEPTH, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE
    )


def _subscribe(out: Path, seconds: float, topics: list[str]) -> None:
    import rclpy
    from rclpy.experimental import EventsExecutor

    rclpy.init()
    ending: list[bool] = []  # after rclpy's own handlers: the test says the run is over
    signal.signal(signal.SIGTERM, lambda *_: ending.append(True))
    node = rclpy.create_node("wftool_test_subscriber")
    received: list[tuple[str, int, Any]] = []
    subscriptions = []
    for spec in topics:
        topic, type_name, *qos = spec.split("=")

        def callback(message: Any, topic: str = topic) -> None:
            received.append((topic, time.time_ns(), message))

        subscriptions.append(
            node.create_subscription(
                message_class(type_name), topic, callback, _reliable(qos == ["latest"])
            )
        )
    executor = EventsExecutor()
    executor.add_node(node)
    print("ready", flush=True)
    matched = False
    end = time.monotonic() + max(seconds, DISCOVERY_S)  # discovery is not part of the stream
    while time.monotonic() < end and not ending:
        executor.spin_once(timeout_sec=0.05)
        if not matched and all(s.get_publisher_count() for s in subscriptions):
            matched = True
            end = time.monotonic() + seconds  # SECONDS of a stream, from its first publisher
            print("matched", flush=True)
        if received and time.time_ns() - received[-1][1] > IDLE_S * 1e9:
            break  # the stream is over
    with out.open("w") as sink:
        for topic, received_ns, message in received:
            record = {"topic": topic, "received_ns": received_ns, "message": plain(message)}
            sink.write(json.dumps(record) + "\n")
    node.destroy_node()
    rclpy.shutdown()


def _publish(bag: Path, seconds: float, namespace: str) -> None:
    import rclpy
    from mcap.reader import make_reader
    from rclpy.duration import Duration

    rclpy.init()
    node = rclpy.create_node("wftool_test_player")
    publishers: dict[str, Any] = {}
    messages: list[tuple[str, bytes]] = []
    with bag.open("rb") as handle:
        for schema, channel, message in make_reader(handle).iter_messages(log_time_order=True):
            if channel.topic not in publishers:
                kind = message_class(schema.name)
                publishers[channel.topic] = node.create_publisher(
                    kind, namespace + channel.topic, _reliable()
                )
            messages.append((channel.topic, message.data))
    deadline = time.monotonic() + seconds
    while any(p.get_subscription_count() == 0 for p in publishers.values()):
        if time.monotonic() > deadline:
            sys.exit("no subscriber matched every topic")
        time.sleep(0.02)
    for topic, data in messages:
        publishers[topic].publish(data)  # bytes: published as they are
    for publisher in publishers.values():  # reliable: stay until every message is delivered
        if not publisher.wait_for_all_acked(Duration(seconds=max(deadline - time.monotonic(), 1))):
            sys.exit(f"{publisher.topic_name}: not every message was acknowledged")
    print(len(messages), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def _command(
    topic: str, plan: list[dict[str, Any]], seconds: float, together: bool = False
) -> None:
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from wftool_msgs.msg import RcCommand

    rclpy.init()
    node = rclpy.create_node("wftool_test_commander")
    publisher = node.create_publisher(
        RcCommand, topic, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    )
    deadline = time.monotonic() + seconds
    while publisher.get_subscription_count() == 0:
        if time.monotonic() > deadline:
            print("unmatched", flush=True)
            return
        time.sleep(0.02)
    print("matched", flush=True)
    if together:  # its twins matched too: they start their plans at once (a line on stdin)
        sys.stdin.readline()
    # Each side discovers the other on its own: this writer has matched the node's reader, but
    # a best-effort reader drops what comes from a writer it has not matched yet (Fast DDS).
    time.sleep(1.0)
    stamp_ns = 0
    for step in plan:
        time.sleep(step.get("after_s", 0.0))
        message = RcCommand()
        message.roll, message.pitch, message.yaw, message.throttle, message.aux3, message.aux4 = (
            step["rc"]
        )
        if step.get("no_stamp"):
            stamp_ns = 0
        elif not step.get("same_stamp"):
            stamp_ns = node.get_clock().now().nanoseconds - step.get("age_ns", 0)
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        message.arming = step.get("arming", 0)
        publisher.publish(message)
    print("done", flush=True)
    time.sleep(0.5)
    node.destroy_node()
    rclpy.shutdown()


def command(
    topic: str,
    plan: list[dict[str, Any]],
    seconds: float = 20.0,
    *,
    wrapper: Sequence[str] = (),
    env: dict[str, str] | None = None,
) -> str:
    """Run a `command` process with `plan` (under `wrapper`, e.g. `ip netns exec NAME`);
    "matched" (it found the node and published) or "unmatched" (none within `seconds`)."""
    command = [sys.executable, "-m", "tests.ros2.peers", "command", topic, json.dumps(plan)]
    result = subprocess.run(
        [*wrapper, *command, str(seconds)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=seconds + 30,
        env=env,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    return result.stdout.split()[0]


@contextmanager
def commanders(
    topic: str, plans: Sequence[list[dict[str, Any]]], seconds: float = 20.0
) -> Iterator[list[subprocess.Popen]]:
    """`command` processes, one per plan, started together and matched with the node; once
    all have matched, each starts its plan a second later (they publish side by side, however
    long a loaded host took to start one); waits for them at the end, unless the block ended
    one (a killed publisher)."""
    verb = [sys.executable, "-m", "tests.ros2.peers", "command", topic]
    processes = [
        subprocess.Popen(
            [*verb, json.dumps(plan), str(seconds), "together"],
            cwd=REPO,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        for plan in plans
    ]
    try:
        for process in processes:
            assert process.stdout is not None
            assert process.stdout.readline().strip() == "matched", "a publisher found no node"
        for process in processes:
            assert process.stdin is not None
            process.stdin.write("go\n")
            process.stdin.flush()
        yield processes
        for process in processes:
            process.wait(timeout=seconds + 30)
    finally:
        for process in processes:
            if process.poll() is None:
                process.kill()
                process.wait()


def _node(namespace: str, seconds: float) -> None:
    from wftool.ros2.node import Ros2Bridge, Ros2Options

    bridge = Ros2Bridge(Ros2Options(namespace=namespace, accept_commands=True))
    print(bridge.discovery, flush=True)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if bridge.command() is not None:
            bridge.sent()
        time.sleep(0.001)
    print(json.dumps(dataclasses.asdict(bridge.command_counts)), flush=True)
    bridge.close()


@contextmanager
def node(namespace: str, seconds: float, env: dict[str, str]) -> Iterator[tuple[Any, str]]:
    """A `node` process with `env`, started: (the process, its discovery scope)."""
    command = [sys.executable, "-m", "tests.ros2.peers", "node", namespace, str(seconds)]
    process = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert process.stdout is not None
        yield process, process.stdout.readline().strip()
    finally:
        if process.poll() is None:
            try:
                process.wait(timeout=seconds + 30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def node_counts(process: subprocess.Popen) -> dict[str, int]:
    """The command counts a `node` process printed when it ended."""
    assert process.stdout is not None
    output = process.stdout.read()
    assert process.wait(timeout=60) == 0
    return json.loads(output.splitlines()[-1])


@contextmanager
def subscriber(
    out: Path, seconds: float, topics: dict[str, str], *, matched: bool = False
) -> Iterator[subprocess.Popen]:
    """A `subscribe` process for `topics` (name -> type), ready (and with `matched`, with a
    publisher on every topic: nothing they publish from then on is missed); waits for it at
    the end."""
    command = [sys.executable, "-m", "tests.ros2.peers", "subscribe", str(out), str(seconds)]
    command += [f"{topic}={kind}" for topic, kind in topics.items()]
    process = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert line.strip() == "ready", f"the subscriber did not start: {line!r}"
        if matched:
            line = process.stdout.readline()
            assert line.strip() == "matched", f"the subscriber found no publisher: {line!r}"
        yield process
        process.wait(timeout=seconds + 30)
        assert process.returncode == 0, f"the subscriber failed (exit {process.returncode})"
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def received(out: Path) -> list[dict[str, Any]]:
    with out.open() as lines:
        return [json.loads(line) for line in lines]


def play(bag: Path, namespace: str, seconds: float = 30.0) -> int:
    """Play the MCAP file `bag` with a `publish` process; how many messages it published."""
    result = subprocess.run(
        [sys.executable, "-m", "tests.ros2.peers", "publish", str(bag), str(seconds), namespace],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=seconds + 30,
        env=os.environ.copy(),
    )
    assert result.returncode == 0, result.stderr[-2000:]
    return int(result.stdout.split()[-1])


if __name__ == "__main__":
    verb, *arguments = sys.argv[1:]
    if verb == "subscribe":
        _subscribe(Path(arguments[0]), float(arguments[1]), arguments[2:])
    elif verb == "publish":
        _publish(Path(arguments[0]), float(arguments[1]), arguments[2])
    elif verb == "command":
        _command(
            arguments[0],
            json.loads(arguments[1]),
            float(arguments[2]),
            arguments[3:4] == ["together"],
        )
    elif verb == "node":
        _node(arguments[0], float(arguments[1]))
    else:
        sys.exit(f"unknown verb {verb}")
