"""The ROS 2 node on the real middleware (Fast DDS from the wheels): what a separate rclpy
process receives from it, and what it does with the commands another one publishes."""

from __future__ import annotations

import itertools
import os
import signal
import threading
import time
from collections.abc import Iterable, Iterator
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
from tests.waits import wait_for
from wftool.errors import Ros2Error, UsageError
from wftool.fsp import Authority, AuthorityExit, SensorFrame, UplinkFlag, UplinkStatus
from wftool.recording.events import StreamHealth, new_uplink
from wftool.ros2.commands import CommandCounts
from wftool.ros2.node import (
    FAST_DDS_PROFILES,
    STATUS_DEPTH,
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
    snapshots, got, t0 = _fly(bridge, reads, tmp_path / "received.jsonl", STREAM_TYPES)
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
    uplink = got["fsp/uplink_status"]
    expected = _uplink_statuses(snapshots, offset)
    assert [(m["tx_time_us"], flags_of(m), stamp_of(m)) for m in uplink] == expected
    assert len(expected) >= 1500 // STATUS_EVERY // 2 and not uplink[-1]["live"]

    late = tmp_path / "late.jsonl"  # transient local: the latest, at once
    latest = {f"{namespace}/fsp/uplink_status": STREAM_TYPES["fsp/uplink_status"] + "=latest"}
    with peers.subscriber(late, 3.0, latest, matched=True):
        pass
    joined = [line["message"] for line in peers.received(late)]
    # the latest last, after those of the ones the node keeps before it that the subscriber
    # (keeping one) took as they came, in order
    assert joined and joined[-1] == uplink[-1]
    kept = uplink[-STATUS_DEPTH:]
    positions = [kept.index(m) if m in kept else None for m in joined]
    assert None not in positions and positions == sorted(set(positions)), positions


def test_a_subscriber_its_host_stops_still_gets_every_status(bridge: Ros2Bridge, tmp_path: Path):
    """A subscriber to every topic, which its host stops for 120 reads (720 frames, over a
    health period) mid-flight, still gets each health snapshot and each uplink status: the
    node keeps STATUS_DEPTH of each to repeat (with the latest alone kept, it lost one in
    every such stop: the frames had filled what it receives into)."""
    reads = flight(3000, statuses=True)  # 1000 reads, 0.95 s
    out = tmp_path / "received.jsonl"
    snapshots, got, _ = _fly(bridge, reads, out, STREAM_TYPES, stopped=(300, 420))
    assert [m["frames"] for m in got["fsp/health"]] == [s.frames for s in snapshots]
    expected = _uplink_statuses(snapshots, bridge.encoder.wall_offset_ns)
    uplink = got["fsp/uplink_status"]
    assert [(m["tx_time_us"], flags_of(m), stamp_of(m)) for m in uplink] == expected


def _fly(
    bridge: Ros2Bridge,
    reads: list[bytes],
    out: Path,
    topics: dict[str, str],
    stopped: tuple[int, int] | None = None,
) -> tuple[list[StreamHealth], dict[str, list[dict]], float]:
    """Feed `reads` to `bridge` as they arrive, in real time, with a `subscribe` process on
    `topics` (name under the node's namespace -> type), which its host stops from read
    `stopped[0]` to `stopped[1]`: the health snapshots fed, what the subscriber got by
    topic, and when the flight began."""
    namespace = bridge.options.namespace
    monitor = StreamMonitor("socket://sim:5762")
    sampler = HealthSampler(monitor)
    t0 = time.monotonic()
    monitor.connected(t0)
    snapshots: list[StreamHealth] = []
    named = {f"{namespace}/{t}": kind for t, kind in topics.items()}
    stop, go = stopped or (-1, -1)
    assert go < len(reads), "the subscriber would stay stopped"
    with peers.subscriber(out, 60, named, matched=True) as receiving:
        _wait_for_subscribers(bridge, named)
        t = t0
        for i, data in enumerate(reads):
            if i in (stop, go):
                receiving.send_signal(signal.SIGSTOP if i == stop else signal.SIGCONT)
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
    return snapshots, got, t0


def _uplink_statuses(snapshots: list[StreamHealth], offset_ns: int) -> list[tuple[int, int, int]]:
    """The uplink statuses the node publishes for `snapshots`, each once: (tx_time_us, flags,
    stamp)."""
    reports = [new_uplink(s, b) for s, b in zip(snapshots, [None, *snapshots])]
    return [(r.status.tx_time_us, r.status.flags, offset_ns + int(r.t * 1e9)) for r in reports if r]


def flags_of(message: dict) -> int:
    """The `UplinkFlag` bits of an `UplinkStatus` message's flags."""
    return sum(flag for flag in UplinkFlag if message[flag.name.lower()])


def _assert_imu(messages: list[dict], frames: list[SensorFrame]) -> None:
    class Message:  # attribute access over the JSON, for the recordings' own check
        def __init__(self, fields: dict) -> None:
            for name, value in fields.items():
                setattr(self, name, Message(value) if isinstance(value, dict) else value)

    for message, frame in zip(messages, frames, strict=True):
        assert_imu_matches(Message(message), frame)


def _wait_for_subscribers(
    bridge: Ros2Bridge, topics: Iterable[str], timeout_s: float = 10.0
) -> None:
    """Until the node's publisher on each of `topics` (full names) has a subscriber."""
    deadline = time.monotonic() + timeout_s
    names = set(topics)
    ours = [p for p in bridge._node.publishers if p.topic_name in names]
    assert len(ours) == len(names), f"no publisher on {names - {p.topic_name for p in ours}}"
    while any(p.get_subscription_count() == 0 for p in ours):
        assert time.monotonic() < deadline, "the subscriber never matched"
        time.sleep(0.02)


def _poll(bridge: Ros2Bridge, seconds: float) -> list[tuple[int, ...]]:
    """The loop's side: take a command every millisecond, and 'send' it (with the arming
    request the node asks for after it, as a trailing element)."""
    sent: list[tuple[int, ...]] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rc = bridge.command()
        if rc is not None:
            bridge.sent()
            arming = bridge.arming()
            sent.append(tuple(rc) if arming is None else (*rc, int(arming)))
        time.sleep(0.001)
    return sent


@pytest.mark.parametrize(
    "bridge", [{"accept_commands": True, "command_max_age_ns": 300 * MS}], indirect=True
)
def test_commands_pass_only_in_range_and_newer_by_their_publisher_stamps(bridge: Ros2Bridge):
    """Within a link (its publisher's commands less than the age limit apart, 300 ms here)
    a command must be newer by its stamp than the last taken; stamps are nothing else: after
    a silence a publisher starts a new link whatever its clock says."""
    good = [[1100 + 100 * i, 1500, 1500, 1000, 1000, 1000] for i in range(6)]
    plan = [
        {"rc": good[0], "after_s": 0.02},
        {"rc": [2251, 1500, 1500, 1000, 1000, 1000], "after_s": 0.02},  # out of range
        {"rc": good[1], "after_s": 0.02},
        {"rc": good[1], "same_stamp": True, "after_s": 0.005},  # a stuck sender's repeat
        {"rc": good[2], "age_ns": 200 * MS, "after_s": 0.02},  # older than the one before
        {"rc": [0, 0, 0, 0, 0, 0], "after_s": 0.02},  # an unset message
        {"rc": good[3], "no_stamp": True, "after_s": 0.02},  # unstamped
        {"rc": good[4], "age_ns": 5_000 * MS, "after_s": 0.5},  # after a silence: a new link
        {"rc": good[5], "age_ns": 4_990 * MS, "after_s": 0.02},  # newer within it
    ]
    topic = f"{bridge.options.namespace}/fsp/command"
    with _polling(bridge) as sent:
        assert peers.command(topic, plan) == "matched"
    assert sent == [tuple(good[0]), tuple(good[1]), tuple(good[4]), tuple(good[5])]
    assert bridge.command_counts == CommandCounts(
        received=9, sent=4, out_of_range=2, not_newer=2, unstamped=1, links=2
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


def _plan(roll: int, count: int, **step: object) -> list[dict]:
    """`count` commands at 100 Hz, roll `roll` (who sent it), throttle counting up."""
    return [{"rc": [roll, 1500, 1500, 1000 + i, 1000, 1000], "after_s": 0.01, **step}
            for i in range(count)]  # fmt: skip


def _switches(sent: list[tuple[int, ...]]) -> int:
    """How often the sender (the roll value) changes along what was sent."""
    return sum(a[0] != b[0] for a, b in itertools.pairwise(sent))


TWIN_LIMIT = {"accept_commands": True, "command_max_age_ns": 300 * MS}
"""The age limit of the twin tests: a publisher silent that long has ended its turn, and a
loaded host stalls a 100 Hz Python publisher for 50 ms now and then."""


@pytest.mark.parametrize("bridge", [TWIN_LIMIT], indirect=True)
def test_a_twin_publisher_is_counted_and_ignored(bridge: Ros2Bridge):
    """Two programs publishing commands at 100 Hz side by side: what reaches the FC comes
    from one of them while it publishes, the other's are foreign; a hand-over only once
    the first has finished (its publisher silent for the age limit)."""
    topic = f"{bridge.options.namespace}/fsp/command"
    with _polling(bridge) as sent, peers.commanders(topic, [_plan(1100, 200), _plan(1900, 200)]):
        pass
    counts = bridge.command_counts
    assert _switches(sent) <= 1, [rc[0] for rc in sent]
    first = [rc for rc in sent if rc[0] == sent[0][0]]
    assert len(first) >= 150  # the first publisher's commands got through
    assert counts.foreign >= 150 and counts.links == 1 + _switches(sent)
    throttles = [rc[3] for rc in first]
    assert throttles == sorted(set(throttles))  # in order, each once


@pytest.mark.parametrize("bridge", [TWIN_LIMIT], indirect=True)
def test_a_dead_publisher_hands_over_to_the_live_one_after_the_age_limit(bridge: Ros2Bridge):
    """The publisher taken is killed (SIGKILL) mid-run: its twin, ignored until then, is
    taken once the first has been silent for the age limit."""
    topic = f"{bridge.options.namespace}/fsp/command"
    plans = [_plan(1100, 300), _plan(1900, 300)]
    with _polling(bridge) as sent, peers.commanders(topic, plans) as processes:
        while len(sent) < 50 or bridge.command_counts.foreign < 20:  # both publishing
            time.sleep(0.01)
        taken = {1100: 0, 1900: 1}[sent[0][0]]
        processes[taken].kill()
        before = len(sent)
        while not any(rc[0] != sent[0][0] for rc in sent[before:]):
            time.sleep(0.01)
    assert _switches(sent) == 1
    counts = bridge.command_counts
    assert counts.links == 2 and counts.foreign >= 20


@pytest.mark.parametrize("bridge", [{"accept_commands": True}], indirect=True)
def test_a_publisher_clock_stepping_back_30_s_costs_one_age_limit(bridge: Ros2Bridge):
    """A publisher's clock steps back 30 s mid-run (100 Hz): its commands are not newer
    than the last taken until its link ends, 50 ms later; then they pass again. (Compared
    with the node's clock, as before, it would lose 30 s of them.)"""
    topic = f"{bridge.options.namespace}/fsp/command"
    plan = _plan(1100, 100) + _plan(1200, 100, age_ns=30_000 * MS)
    with _polling(bridge) as sent:
        assert peers.command(topic, plan) == "matched"
    counts = bridge.command_counts
    after = [rc for rc in sent if rc[0] == 1200]
    assert counts.links == 2 and 1 <= counts.not_newer < 20, counts
    assert len(after) >= 100 - 20 and after[-1][3] == 1099  # through to its last command


@pytest.mark.parametrize("bridge", [{"accept_commands": True}], indirect=True)
def test_a_command_that_waited_for_a_stalled_executor_is_stale(bridge: Ros2Bridge):
    """A command's age counts from when the middleware received it: one that waited in the
    reader's queue past the age limit while the node's executor was held (a starved host)
    never flies; the next, on time, does."""
    hold, held, release = threading.Event(), threading.Event(), threading.Event()

    def holding() -> None:  # another callback of the node's executor, stalled while `hold`
        if hold.is_set():
            held.set()
            release.wait(timeout=30)

    bridge._node.create_timer(0.01, holding)
    topic = f"{bridge.options.namespace}/fsp/command"
    late = [1100, *RC[1:]]
    with _polling(bridge) as sent:
        hold.set()
        assert held.wait(timeout=10)
        assert peers.command(topic, [{"rc": late}]) == "matched"  # published, then 0.5 s
        hold.clear()
        release.set()
        assert wait_for(lambda: bridge.command_counts.received == 1, 10.0)
    assert sent == []
    assert bridge.command_counts == CommandCounts(received=1, stale=1, links=1)
    with _polling(bridge) as sent:
        assert peers.command(topic, [{"rc": RC}]) == "matched"
    assert sent == [tuple(RC)]
    assert bridge.command_counts == CommandCounts(received=2, sent=1, stale=1, links=2)


@pytest.mark.parametrize("bridge", [{"accept_commands": True}], indirect=True)
def test_arming_is_forwarded_only_when_the_fc_says_its_receiver_is_the_obc(bridge: Ros2Bridge):
    topic = f"{bridge.options.namespace}/fsp/command"
    plan = [{"rc": RC, "after_s": 0.02}, {"rc": RC, "arming": 1, "after_s": 0.02}]
    with _polling(bridge) as sent:  # no status from the FC yet: not forwarded
        assert peers.command(topic, plan) == "matched"
    assert [len(rc) for rc in sent] == [6, 6]
    bridge.fc_status = fc_status(UplinkFlag.LIVE | UplinkFlag.OBC_RECEIVER)
    plan += [{"rc": RC, "arming": 2, "after_s": 0.02}, {"rc": RC, "arming": 7, "after_s": 0.02}]
    with _polling(bridge) as sent:
        assert peers.command(topic, plan) == "matched"
    assert sent == [tuple(RC), (*RC, 1), (*RC, 2)]  # the undefined request: out of range
    counts = bridge.command_counts
    assert (counts.arming_sent, counts.arming_refused, counts.out_of_range) == (2, 1, 1)


def fc_status(flags: int) -> UplinkStatus:
    """An uplink status of the FC with `flags`, who flies and its pulse range (spec §12)."""
    return UplinkStatus(
        5, 2_000_000, 5, 1, 0, 0, 50, flags, 0, 0, Authority.RECEIVER, AuthorityExit.NONE, 500,
        0, 0x5A17C3, 0, 0, 0, 885, 2115,
    )  # fmt: skip


def test_a_message_the_middleware_refuses_is_counted_and_the_stream_goes_on(bridge: Ros2Bridge):
    """Fast DDS refuses a message when a reliable writer has waited its longest for a stalled
    reader (rclpy's RCLError "cannot publish data"): the node counts it and publishes on."""
    from rclpy.impl.implementation_singleton import rclpy_implementation

    imu = next(p for p in bridge._node.publishers if p.topic_name.endswith("/fsp/imu"))
    publish, tried = imu.publish, []

    def refusing_once(message: object) -> None:
        tried.append(message)
        if len(tried) == 1:
            raise rclpy_implementation.RCLError("Failed to publish: cannot publish data")
        publish(message)

    imu.publish = refusing_once  # the middleware's answer, under the node's own publishing
    monitor = StreamMonitor("socket://sim:5762")
    monitor.connected(0.0)
    packets = [p for i, data in enumerate(flight(3)) for p in monitor.feed(data, 0.001 * i)]
    frames = sum(len(p.frames) for p in packets)
    bridge.packets(packets)
    bridge.flush()  # the publishing thread's
    assert frames >= 2 and len(tried) == frames
    assert bridge.unpublished == 1


def test_the_loop_never_waits_for_the_middleware(bridge: Ros2Bridge):
    """A publish that blocks (the middleware stalled) holds the publishing thread only: the
    live loop's `packets` returns at once, read after read, so the loop goes on sending the
    commands; once the middleware moves, every frame is published, in order."""
    imu = next(p for p in bridge._node.publishers if p.topic_name.endswith("/fsp/imu"))
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Imu

    publish, entered, release = imu.publish, threading.Event(), threading.Event()
    published: list[int] = []

    def stalled(message: bytes) -> None:  # the node publishes serialized messages
        entered.set()
        release.wait(10.0)
        stamp = deserialize_message(message, Imu).header.stamp
        published.append(stamp.sec * 1_000_000_000 + stamp.nanosec)
        publish(message)

    imu.publish = stalled  # under the node's own publishing
    data = flight(20)
    monitor = StreamMonitor("socket://sim:5762")
    monitor.connected(0.0)
    for i, read in enumerate(data, 1):
        bridge.packets(monitor.feed(read, i * READ_S))
    assert entered.wait(10.0) and published == []  # every read handed over, none published
    release.set()
    bridge.flush()
    offset = bridge.encoder.wall_offset_ns
    assert published == [offset + int(f.obc_time * 1e9) for f in decoded_frames(data, 0.0)]


def test_an_error_publishing_reaches_the_loop(bridge: Ros2Bridge):
    """What the publishing thread did not expect ends the run in the loop's thread, not in
    silence: the next read's `packets` raises it."""
    imu = next(p for p in bridge._node.publishers if p.topic_name.endswith("/fsp/imu"))

    def broken(message: object) -> None:
        raise RuntimeError("the middleware broke")

    imu.publish = broken
    monitor = StreamMonitor("socket://sim:5762")
    monitor.connected(0.0)
    first, second = (monitor.feed(data, 0.001 * i) for i, data in enumerate(flight(6)))
    bridge.packets(first)
    bridge.flush()
    with pytest.raises(RuntimeError, match="the middleware broke"):
        bridge.packets(second)


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
