"""The MSP baseline's recording of a real poll (the patched SITL), read back by rosbags.

rosbags (an independent rosbag2 reader and CDR codec, driven only by the definitions stored
in the file) must find every reply the poller saw on its topic, stamped with its reception
time, in ROS units; the raw log must give back exactly the replies the poller saw.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from tests.fc.test_msp_poller import Seen
from wftool.fc.msp import Cmd, MspVersion, parse_analog, parse_attitude, parse_raw_imu, parse_rc
from wftool.fc.msp_poller import PAPER_SCHEDULE, MspPoller, MspReply
from wftool.link.transport import open_port
from wftool.recording.msp import (
    ATTITUDE_TOPIC,
    BATTERY_TOPIC,
    IMU_TOPIC,
    RC_TOPIC,
    MspRecorder,
    msp_replies,
    poll_metadata,
)
from wftool.sitl.process import VirtualFC

ACC_1G = 512


class Both(Seen):
    """Sees the poll and records it."""

    def __init__(self, recorder: MspRecorder) -> None:
        super().__init__()
        self.recorder = recorder

    def connected(self, t):
        super().connected(t)
        self.recorder.connected(t)

    def disconnected(self, t):
        super().disconnected(t)
        self.recorder.disconnected(t)

    def request(self, t, wire):
        super().request(t, wire)
        self.recorder.request(t, wire)

    def read(self, t, data):
        super().read(t, data)
        self.recorder.read(t, data)

    def reply(self, reply):
        super().reply(reply)
        self.recorder.reply(reply)


def read_bag(path: Path) -> dict[str, list[tuple[int, object]]]:
    topics: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        for connection, log_time, raw in reader.messages():
            topics.setdefault(connection.topic, []).append(
                (log_time, reader.deserialize(raw, connection.msgtype))
            )
    return topics


def stamp_ns(message) -> int:
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


def test_a_poll_of_the_sitl_recorded_and_read_back(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    bag = tmp_path / "msp"
    metadata = poll_metadata(virtual_fc.url, PAPER_SCHEDULE, 4, 1, 100)
    with MspRecorder(bag, metadata, acc_1g=ACC_1G) as recorder:
        seen = Both(recorder)
        link = open_port(virtual_fc.url, timeout=0)
        try:
            result = MspPoller(link, PAPER_SCHEDULE, version=MspVersion.V1).run(2.0, seen)
        finally:
            link.close()
        recorder.finish(result)
    offset = recorder.wall_offset_ns

    # The raw log gives back exactly what the poller received, stamps included.
    stored_metadata, connections = msp_replies(bag)
    assert len(connections) == 1
    live = [MspReply(r.cmd, r.payload, r.t, r.error) for r in seen.replies]
    assert connections[0] == live
    assert stored_metadata["expected_rate_hz"] == "1000"
    assert stored_metadata["schedule"] == "RAW_IMU=1000,RC=100,ATTITUDE=100,ANALOG=10"
    assert json.loads(stored_metadata["result"]) == result.as_json()

    topics = read_bag(bag)
    by_cmd = {cmd: [r for r in seen.replies if r.cmd == cmd] for cmd in Cmd}
    expected_counts = {
        IMU_TOPIC: len(by_cmd[Cmd.RAW_IMU]),
        ATTITUDE_TOPIC: len(by_cmd[Cmd.ATTITUDE]),
        RC_TOPIC: len(by_cmd[Cmd.RC]),
        BATTERY_TOPIC: len(by_cmd[Cmd.ANALOG]),
    }
    assert all(count > 0 for count in expected_counts.values())
    assert {topic: len(topics.get(topic, [])) for topic in expected_counts} == expected_counts
    with Reader(bag) as reader:  # rosbags' rosbag2 reader: metadata.yaml agrees
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
        assert json.loads(reader.storage.metadata.custom["result"]) == result.as_json()
    assert {topic: counts[topic] for topic in expected_counts} == expected_counts
    assert types[IMU_TOPIC] == "sensor_msgs/msg/Imu"
    assert types[RC_TOPIC] == "wftool_msgs/msg/MspRc"

    for reply, (log_time, message) in zip(by_cmd[Cmd.RAW_IMU], topics[IMU_TOPIC], strict=True):
        assert stamp_ns(message) == log_time == offset + int(reply.t * 1e9)
        imu = parse_raw_imu(reply.payload)
        gyro = message.angular_velocity
        assert (gyro.x, gyro.y, gyro.z) == pytest.approx([v * math.pi / 180 for v in imu.gyro])
        acc = message.linear_acceleration
        assert (acc.x, acc.y, acc.z) == pytest.approx([v * 9.80665 / ACC_1G for v in imu.acc])
        assert message.orientation_covariance[0] == -1.0  # MSP_RAW_IMU has no orientation
        assert message.header.frame_id == "fc"
    for reply, (_, message) in zip(by_cmd[Cmd.RC], topics[RC_TOPIC], strict=True):
        assert tuple(message.channels) == parse_rc(reply.payload)
        assert stamp_ns(message) == offset + int(reply.t * 1e9)
    for reply, (_, message) in zip(by_cmd[Cmd.ATTITUDE], topics[ATTITUDE_TOPIC], strict=True):
        attitude = parse_attitude(reply.payload)
        assert (message.roll_deg, message.pitch_deg, message.yaw_deg) == pytest.approx(
            (attitude.roll_deg, attitude.pitch_deg, attitude.yaw_deg)
        )
    for reply, (_, message) in zip(by_cmd[Cmd.ANALOG], topics[BATTERY_TOPIC], strict=True):
        analog = parse_analog(reply.payload)
        assert message.voltage == pytest.approx(analog.voltage_v)
        assert message.current == pytest.approx(analog.current_a)
        assert math.isnan(message.temperature)


def test_acceleration_without_acc_1g_is_no_estimate(tmp_path: Path) -> None:
    bag = tmp_path / "msp"
    payload = bytes.fromhex("0100020003000a000b000c00000000000000")
    with MspRecorder(bag, {}) as recorder:
        recorder.connected(1.0)
        recorder.reply(MspReply(Cmd.RAW_IMU, payload, 1.5))
        recorder.reply(MspReply(Cmd.RAW_IMU, payload[:4], 1.6))  # short: in the raw log only
        recorder.disconnected(2.0)
    [(_, message)] = read_bag(bag)[IMU_TOPIC]
    assert message.linear_acceleration_covariance[0] == -1.0
    assert message.angular_velocity.x == pytest.approx(10 * math.pi / 180)
