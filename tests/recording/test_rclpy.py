"""Recordings as ROS 2 itself reads them: rclpy's own type support (the wheels' standard
messages, and wftool_msgs built from its package) decodes every message we write, on its own
and after a trip through the real middleware, to the values rosbags decodes and the frames
say. The schemas in a recording are the package's .msg files, to the byte.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from tests.recording.test_rosbag import (
    STATUS_EVERY,
    assert_imu_matches,
    decoded_frames,
    flight,
    read_bag,
    record,
)
from tests.ros2 import peers
from wftool.fsp import SensorFrame, UplinkFlag, UplinkStatus
from wftool.recording import ros2msg as ros2
from wftool.recording.events import Event, UplinkReport
from wftool.recording.recorder import Recorder
from wftool.recording.ros2msg import WFTOOL_MSGS, FrameEncoder

pytestmark = pytest.mark.usefixtures("ros2_env")

RULE = "=" * 80 + "\nMSG: "
OUR_TYPES = sorted(p.stem for p in (WFTOOL_MSGS / "msg").glob("*.msg"))


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[bytes]]:
    """A recorded synthetic flight (the real decoder and recorder) of an FC that reports on
    its uplink, with its reads."""
    path = tmp_path_factory.mktemp("rclpy") / "flight"
    reads = flight(1500, statuses=True)
    with Recorder(path, None, {"port": "socket://sim:5762"}) as recorder:
        record(recorder, reads)
    return path, reads


def rclpy_messages(mcap: Path) -> dict[str, list[tuple[str, object]]]:
    """Every message by topic, (type name, message), decoded by rclpy's type support."""
    from rclpy.serialization import deserialize_message

    topics: dict[str, list[tuple[str, object]]] = {}
    with mcap.open("rb") as handle:
        for schema, channel, message in make_reader(handle).iter_messages(log_time_order=False):
            decoded = deserialize_message(message.data, peers.message_class(schema.name))
            topics.setdefault(channel.topic, []).append((schema.name, decoded))
    return topics


def test_package_types_are_its_files():
    """The type support built into this environment has the fields the .msg files name."""
    for name in OUR_TYPES:
        ours = get_types_from_msg(ros2.wftool_msg(name), f"wftool_msgs/msg/{name}")
        fields = ours[f"wftool_msgs/msg/{name}"][1]
        built = peers.message_class(f"wftool_msgs/msg/{name}").get_fields_and_field_types()
        assert list(built) == [field_name for field_name, _ in fields], name


@pytest.mark.parametrize(
    "kind", [ros2.IMU, ros2.BATTERY_STATE], ids=lambda kind: kind.name.split("/")[-1]
)
def test_embedded_standard_types_are_the_installed_ones(kind: ros2.MessageType):
    """The standard definitions we embed are those of the ROS 2 installed here (Kilted):
    the same fields, in order, of the same types."""
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(kind.schema, kind.name))
    installed = peers.message_class(kind.name).get_fields_and_field_types()
    ours = store.fielddefs[kind.name][1]
    assert [name for name, _ in ours] == list(installed)


def test_recorded_schemas_are_the_package_files(bag):
    path, _ = bag
    seen = set()
    with (path / f"{path.name}_0.mcap").open("rb") as handle:
        for schema in make_reader(handle).get_summary().schemas.values():
            package, _, name = schema.name.split("/")
            if package != "wftool_msgs":
                continue
            definition = schema.data.decode().split(RULE)[0]
            assert definition == (WFTOOL_MSGS / "msg" / f"{name}.msg").read_text(), name
            seen.add(name)
    assert seen == {"RcChannels", "MotorRpm", "StreamHealth", "UplinkStatus", "StreamEvents"}


def test_every_message_decodes_as_rosbags_decodes_it(bag):
    path, reads = bag
    mcap = path / f"{path.name}_0.mcap"
    by_rclpy = rclpy_messages(mcap)
    by_rosbags = read_bag(path)
    assert by_rclpy.keys() == by_rosbags.keys()
    assert len(by_rclpy["/fsp/uplink_status"]) >= 1500 // STATUS_EVERY // 2  # every other one
    for topic, messages in by_rclpy.items():
        assert len(messages) == len(by_rosbags[topic]) > 0, topic
        for (_, ours), (_, theirs) in zip(messages, by_rosbags[topic]):
            assert peers.plain(ours) == peers.plain(theirs), topic
    frames = decoded_frames(reads)
    imu = [message for _, message in by_rclpy["/fsp/imu"]]
    assert len(imu) == len(frames) == 3000
    for message, frame in zip(imu, frames):
        assert_imu_matches(message, frame)
        assert message.header.frame_id == "fc"


def _frame() -> SensorFrame:
    return SensorFrame(
        123, (100, -2048, 4096), 2048, 0.0609756, (1000, -32768, 32767), (-32768, 5, -7, 9),
        (1100, 1400, 1600, 1000, 2000, 990), (0, 12000, 65535, 300), 1587,
    )  # fmt: skip


STAMP_NS = 1_700_000_123_456_789_012


@pytest.mark.parametrize(
    "kind, encode, expected",
    [
        (ros2.RC_CHANNELS, lambda: FrameEncoder(0).rc(_frame(), STAMP_NS),
         {"roll": 1100, "pitch": 1400, "yaw": 1600, "throttle": 1000, "aux3": 2000, "aux4": 990}),
        (ros2.MOTOR_RPM, lambda: FrameEncoder(0).rpm(_frame(), STAMP_NS),
         {"rpm": [0, 12000, 65535, 300]}),
        (ros2.ATTITUDE, lambda: ros2.attitude_message(STAMP_NS, -1.5, 2.25, 359.5),
         {"roll_deg": -1.5, "pitch_deg": 2.25, "yaw_deg": 359.5}),
        (ros2.MSP_RC, lambda: ros2.msp_rc_message(STAMP_NS, [1500, 1501, 1000, 2000, 988]),
         {"channels": [1500, 1501, 1000, 2000, 988]}),
        (ros2.BATTERY_STATE, lambda: ros2.battery_message(STAMP_NS, 15.87, 2.5),
         {"voltage": pytest.approx(15.87), "current": 2.5, "present": True}),
        (ros2.UPLINK_STATUS, lambda: FrameEncoder(STAMP_NS - 10**9).uplink_status(UplinkReport(
            UplinkStatus(77, 2**32 - 1, 1000, 3, 2, 1, 50,
                         UplinkFlag.OVERRIDE | UplinkFlag.RX_LOSS | UplinkFlag.ARMED, 1, 999),
            1.0, 0.5)),
         {"command_seq": 77, "accepted": 1000, "stale": 3, "rejected": 1, "timeouts": 2,
          "timeout_ms": 50, "live": False, "override": True, "obc_receiver": False,
          "rx_loss": True, "armed": True, "failsafe_phase": 1, "tx_time_us": 2**32 - 1,
          "timed_out_us": 999, "timed_out": {"sec": 1_700_000_122, "nanosec": 956_789_012}}),
    ],
    ids=lambda value: value.name.split("/")[-1] if isinstance(value, ros2.MessageType) else "",
)  # fmt: skip
def test_our_bytes_decode_to_their_values(kind, encode, expected):
    from rclpy.serialization import deserialize_message

    message = deserialize_message(encode(), peers.message_class(kind.name))
    stamp = message.header.stamp
    assert (stamp.sec, stamp.nanosec, message.header.frame_id) == (1_700_000_123, 456_789_012, "fc")
    values = peers.plain(message)
    assert {name: values[name] for name in expected} == expected


def test_events_decode_to_the_events_written():
    from rclpy.serialization import deserialize_message

    events = [
        Event("connected", 1.0),
        Event("bytes", 1.5, b"\x00\x01\x02"),
        Event("command", 1.75, rc=(1100, 1500, 1500, 1000, 1000, 1000)),
        Event("bytes", 2.0, b"abcde"),
        Event("disconnected", 3.0),
    ]
    batch = deserialize_message(
        ros2.encode_events(events), peers.message_class(ros2.STREAM_EVENTS.name)
    )
    assert list(batch.t) == [1.0, 1.5, 1.75, 2.0, 3.0]
    assert list(batch.kind) == [
        batch.CONNECTED,
        batch.BYTES,
        batch.COMMAND,
        batch.BYTES,
        batch.DISCONNECTED,
    ]
    assert list(batch.size) == [0, 3, 6, 5, 0]
    assert bytes(batch.data) == b"\x00\x01\x02abcde"
    assert list(batch.rc) == [1100, 1500, 1500, 1000, 1000, 1000]
    one = deserialize_message(
        ros2.encode_event(Event("bytes", 4.5, b"xyz")), peers.message_class(ros2.STREAM_EVENT.name)
    )
    assert (one.t, one.kind, bytes(one.data), list(one.rc)) == (4.5, one.BYTES, b"xyz", [])


def test_a_played_recording_arrives_over_the_middleware_as_recorded(bag, tmp_path: Path):
    """The recording played as `ros2 bag play` would (its CDR bytes, as stored) reaches a
    separate subscriber process, whose typed subscriptions decode what rosbags decodes."""
    path, _ = bag
    namespace = peers.namespace_of(tmp_path)
    topics = {f"{namespace}{topic}": kind for topic, kind in _topic_types(path).items()}
    out = tmp_path / "received.jsonl"
    with peers.subscriber(out, 60, topics):
        published = peers.play(path / f"{path.name}_0.mcap", namespace)
    got: dict[str, list] = {}
    for line in peers.received(out):
        got.setdefault(line["topic"][len(namespace) :], []).append(line["message"])
    expected = {topic: [peers.plain(m) for _, m in ms] for topic, ms in read_bag(path).items()}
    assert sum(map(len, got.values())) == published == sum(map(len, expected.values()))
    assert got == expected  # every topic, in order, field for field


def _topic_types(path: Path) -> dict[str, str]:
    with (path / f"{path.name}_0.mcap").open("rb") as handle:
        summary = make_reader(handle).get_summary()
    return {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}


def test_nan_survives(bag):
    """BatteryState's unmeasured fields are NaN in rclpy too (the message's convention)."""
    path, _ = bag
    battery = rclpy_messages(path / f"{path.name}_0.mcap")["/fsp/battery"]
    assert battery and all(math.isnan(message.current) for _, message in battery)
