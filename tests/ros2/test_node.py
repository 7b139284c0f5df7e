"""The ROS 2 node on the real middleware (Fast DDS from the wheels): what a separate rclpy
process receives from it, and what it does with the commands another one publishes."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.recording.test_rosbag import (
    READ_S,
    STATUS_EVERY,
    assert_imu_matches,
    decoded_frames,
    flight,
)
from tests.ros2 import peers
from wftool.errors import Ros2Error, UsageError
from wftool.fsp import SensorFrame, UplinkFlag
from wftool.recording.events import new_uplink
from wftool.ros2.commands import CommandCounts
from wftool.ros2.node import (
    FAST_DDS_PROFILES,
    THIS_HOST_PROFILE,
    Ros2Bridge,
    Ros2Options,
    discovery_scope,
)
from wftool.verify.monitor import HealthSampler, StreamMonitor

pytestmark = pytest.mark.usefixtures("ros2_env")

MS = 1_000_000
RC = [1500, 1500, 1500, 1000, 1000, 1000]
STREAM_TYPES = {
    "fsp/imu": "sensor_msgs/msg/Imu",
    "fsp/attitude": "wftool_msgs/msg/Attitude",
    "fsp/rc": "wftool_msgs/msg/RcChannels",
    "fsp/rpm": "wftool_msgs/msg/MotorRpm",
    "fsp/battery": "sensor_msgs/msg/BatteryState",
    "fsp/health": "wftool_msgs/msg/StreamHealth",
    "fsp/uplink_status": "wftool_msgs/msg/UplinkStatus",
    "fsp/command_status": "wftool_msgs/msg/CommandStatus",
}


@pytest.fixture
def bridge(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Ros2Bridge]:
    options = getattr(request, "param", {})
    bridge = Ros2Bridge(Ros2Options(namespace=peers.namespace_of(tmp_path), **options))
    try:
        yield bridge
    finally:
        bridge.close()


def stamp_of(message: dict) -> int:
    return message["header"]["stamp"]["sec"] * 1_000_000_000 + message["header"]["stamp"]["nanosec"]


@pytest.mark.parametrize("bridge", [{"frame_id": "quad7/fc_body"}], indirect=True)
def test_every_frame_reaches_a_separate_subscriber(bridge: Ros2Bridge, tmp_path: Path):
    """A flight fed as reads arrive: every frame on every per-frame topic, in order, stamped
    with its capture time on the ROS clock, in the frame asked for; battery at 10 Hz; each
    health snapshot, and each uplink status of the FC it carries once; a subscriber that
    joins later gets the latest status at once."""
    namespace = bridge.options.namespace
    reads = flight(1500, statuses=True)
    monitor = StreamMonitor("socket://sim:5762")
    sampler = HealthSampler(monitor)
    out = tmp_path / "received.jsonl"
    t0 = time.monotonic()
    monitor.connected(t0)
    snapshots = []
    topics = {f"{namespace}/{t}": kind for t, kind in STREAM_TYPES.items()}
    with peers.subscriber(out, 60, topics, matched=True):
        _wait_for_subscribers(bridge)
        t = t0
        for data in reads:
            t += READ_S  # in real time: three packets of two frames at 953 µs per read
            packets = monitor.feed(data, t)
            health = sampler.sample(packets, t)
            if health is not None and (not snapshots or health is not snapshots[-1]):
                snapshots.append(health)
            bridge.packets(packets, health)
            time.sleep(max(0.0, t - time.monotonic()))
    got: dict[str, list[dict]] = {}
    for line in peers.received(out):
        got.setdefault(line["topic"][len(namespace) + 1 :], []).append(line["message"])
    frames = decoded_frames(reads, t0)
    offset = bridge.encoder.wall_offset_ns
    stamps = [offset + int(frame.obc_time * 1e9) for frame in frames]
    for topic in ("fsp/imu", "fsp/attitude", "fsp/rc", "fsp/rpm"):
        assert [stamp_of(m) for m in got[topic]] == stamps, topic
    for message, frame in zip(got["fsp/rc"], frames):
        assert tuple(message[k] for k in ("roll", "pitch", "yaw", "throttle", "aux3", "aux4")) == (
            frame.rc
        )
    assert [tuple(m["rpm"]) for m in got["fsp/rpm"]] == [f.rpm for f in frames]
    for topic in STREAM_TYPES:
        assert {m["header"]["frame_id"] for m in got[topic]} == {"quad7/fc_body"}, topic
    _assert_imu(got["fsp/imu"], frames)
    span_s = (stamps[-1] - stamps[0]) / 1e9
    assert len(got["fsp/battery"]) == pytest.approx(span_s * 10, abs=1.5)
    assert [m["frames"] for m in got["fsp/health"]] == [s.frames for s in snapshots]
    status = got["fsp/command_status"]
    assert status and not status[-1]["accepting"] and status[-1]["received"] == 0
    reports = [new_uplink(s, b) for s, b in zip(snapshots, [None, *snapshots])]
    expected = [
        (r.status.tx_time_us, r.status.flags, offset + int(r.t * 1e9)) for r in reports if r
    ]
    uplink = got["fsp/uplink_status"]
    assert [(m["tx_time_us"], flags_of(m), stamp_of(m)) for m in uplink] == expected
    assert len(expected) >= 1500 // STATUS_EVERY // 2 and not uplink[-1]["live"]

    late = tmp_path / "late.jsonl"  # transient local: the latest, at once
    latest = {f"{namespace}/fsp/uplink_status": STREAM_TYPES["fsp/uplink_status"] + "=latest"}
    with peers.subscriber(late, 3.0, latest, matched=True):
        pass
    assert [line["message"] for line in peers.received(late)] == [uplink[-1]]


def flags_of(message: dict) -> int:
    """The `UplinkFlag` bits of an `UplinkStatus` message's flags."""
    return sum(flag for flag in list(UplinkFlag)[:5] if message[flag.name.lower()])


def _assert_imu(messages: list[dict], frames: list[SensorFrame]) -> None:
    class Message:  # attribute access over the JSON, for the recordings' own check
        def __init__(self, fields: dict) -> None:
            for name, value in fields.items():
                setattr(self, name, Message(value) if isinstance(value, dict) else value)

    for message, frame in zip(messages, frames, strict=True):
        assert_imu_matches(Message(message), frame)


def _wait_for_subscribers(bridge: Ros2Bridge, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    ours = [p for p in bridge._node.publishers if p.topic_name not in _ROS_OWN]
    while any(p.get_subscription_count() == 0 for p in ours):
        assert time.monotonic() < deadline, "the subscriber never matched"
        time.sleep(0.02)


def _poll(bridge: Ros2Bridge, seconds: float) -> list[tuple[int, ...]]:
    """The loop's side: take a command every millisecond, and 'send' it."""
    sent = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rc = bridge.command()
        if rc is not None:
            bridge.sent()
            sent.append(rc)
        time.sleep(0.001)
    return sent


@pytest.mark.parametrize("bridge", [{"accept_commands": True}], indirect=True)
def test_commands_pass_only_fresh_in_range_and_newer(bridge: Ros2Bridge):
    good = [[1100 + 100 * i, 1500, 1500, 1000, 1000, 1000] for i in range(5)]
    plan = [
        {"rc": good[0], "after_s": 0.05},
        {"rc": [2251, 1500, 1500, 1000, 1000, 1000], "after_s": 0.05},  # out of range
        {"rc": good[1], "after_s": 0.05},
        {"rc": good[1], "same_stamp": True, "after_s": 0.005},  # a stuck sender's repeat
        {"rc": good[2], "age_ns": 200 * MS, "after_s": 0.05},  # stale
        {"rc": good[3], "age_ns": -500 * MS, "after_s": 0.05},  # ahead of the clock
        {"rc": [0, 0, 0, 0, 0, 0], "after_s": 0.05},  # an unset message
        {"rc": good[4], "after_s": 0.05},
    ]
    topic = f"{bridge.options.namespace}/fsp/command"
    with _polling(bridge) as sent:
        assert peers.command(topic, plan) == "matched"
    assert sent == [tuple(good[0]), tuple(good[1]), tuple(good[4])]
    assert bridge.command_counts == CommandCounts(
        received=8, sent=3, stale=1, future=1, out_of_range=2, not_newer=1
    )


class _polling:
    """Poll the bridge for commands in the background while the block runs."""

    def __init__(self, bridge: Ros2Bridge) -> None:
        import threading

        self._bridge = bridge
        self._stop = threading.Event()
        self._sent: list[tuple[int, ...]] = []
        self._thread = threading.Thread(target=self._run)

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sent += _poll(self._bridge, 0.05)

    def __enter__(self) -> list[tuple[int, ...]]:
        self._thread.start()
        return self._sent

    def __exit__(self, *_exc: object) -> None:
        time.sleep(0.2)  # the last command's way through the middleware
        self._stop.set()
        self._thread.join()


@pytest.mark.parametrize("bridge", [{"accept_commands": True}], indirect=True)
def test_a_silent_sender_is_silence(bridge: Ros2Bridge):
    """A sender that stops (dies, stalls) sends nothing more: the node repeats nothing."""
    topic = f"{bridge.options.namespace}/fsp/command"
    plan = [{"rc": [1100 + i, *RC[1:]], "after_s": 0.02} for i in range(25)]  # 50 Hz, 0.5 s
    with _polling(bridge) as sent:
        assert peers.command(topic, plan) == "matched"
    assert len(sent) == 25 and len(set(sent)) == 25
    assert _poll(bridge, 0.5) == []  # after the last: nothing, for as long as it lasts
    assert bridge.command_counts.sent == 25


def test_without_accept_commands_nothing_subscribes(bridge: Ros2Bridge):
    topic = f"{bridge.options.namespace}/fsp/command"
    assert topic not in bridge.topics
    assert peers.command(topic, [{"rc": RC}], seconds=2.0) == "unmatched"
    assert bridge.command() is None


def test_topics_are_under_the_namespace(bridge: Ros2Bridge):
    namespace = bridge.options.namespace
    expected = {f"{namespace}/{topic}" for topic in STREAM_TYPES}
    assert expected <= set(bridge.topics)
    assert all(t.startswith(namespace + "/") for t in bridge.topics if t not in _ROS_OWN)


_ROS_OWN = {"/parameter_events"}


def test_discovery_stays_on_this_host_unless_widened(monkeypatch: pytest.MonkeyPatch):
    for name in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "RMW_IMPLEMENTATION",
                 *FAST_DDS_PROFILES):  # fmt: skip
        monkeypatch.delenv(name, raising=False)
    assert discovery_scope() == (
        "this host only (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; set it to SUBNET to widen); "
        "Fast DDS on loopback and shared memory"
    )
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert os.environ[FAST_DDS_PROFILES[0]] == str(THIS_HOST_PROFILE)
    assert THIS_HOST_PROFILE.is_file()

    monkeypatch.setenv(FAST_DDS_PROFILES[1], "/etc/lab/dds.xml")
    monkeypatch.delenv(FAST_DDS_PROFILES[0])
    assert discovery_scope().endswith("; transports as your Fast DDS profile /etc/lab/dds.xml says")
    assert FAST_DDS_PROFILES[0] not in os.environ

    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "subnet")
    monkeypatch.setenv("ROS_STATIC_PEERS", "192.0.2.7")
    assert discovery_scope() == (
        "the local network (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET, as set); static peers 192.0.2.7"
    )


@pytest.mark.parametrize(
    "options, message",
    [
        ({"namespace": "drone"}, "a namespace starts with '/'"),
        ({"command_max_age_ns": 0}, "the command age limit must be positive"),
        ({"depth": 0}, "the queue depth must be at least 1"),
        ({"frame_id": ""}, "a frame id is 1-255 printable characters"),
        ({"frame_id": "fc\n"}, "a frame id is 1-255 printable characters"),
    ],
)
def test_bad_options_are_one_line(options, message):
    with pytest.raises(UsageError, match=message):
        Ros2Options(**options)


def test_a_bad_namespace_for_ros_is_an_error_not_a_traceback(tmp_path: Path):
    with pytest.raises(Ros2Error, match="the ROS 2 node did not start"):
        Ros2Bridge(Ros2Options(namespace="/has space"))
