"""ROS 2 messages: our definitions against ROS 2's, our CDR bytes against rosbags' codec.

rosbags is the independent side: its ROS 2 Humble type store holds the standard message
definitions, its parser reads the schemas we embed, and its CDR (de)serializer knows
nothing of our `struct` layouts.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from tests.fsp.strategies import frames
from tests.tiers import examples
from wftool.fsp import Authority, AuthorityExit, SensorFrame, UplinkFlag, UplinkStatus
from wftool.fsp.packets import FAILSAFE_PHASES
from wftool.recording import ros2msg
from wftool.recording.events import Event, StreamHealth, UplinkReport
from wftool.recording.ros2msg import FrameEncoder

ALL_TYPES = (
    ros2msg.IMU,
    ros2msg.BATTERY_STATE,
    ros2msg.RC_CHANNELS,
    ros2msg.MOTOR_RPM,
    ros2msg.ATTITUDE,
    ros2msg.STREAM_HEALTH,
    ros2msg.UPLINK_STATUS,
    ros2msg.STREAM_EVENT,
    ros2msg.STREAM_EVENTS,
)


def typestore_of(*kinds: ros2msg.MessageType):
    """A type store that knows only what our schemas say (definitions and dependencies)."""
    store = get_typestore(Stores.EMPTY)
    for kind in kinds:
        store.register(get_types_from_msg(kind.schema, kind.name))
    return store


@pytest.fixture(scope="module")
def store():
    return typestore_of(*ALL_TYPES)


@pytest.fixture(scope="module")
def events_store():
    """The definition of `StreamEvents` alone (one store for every example: rosbags
    compiles a type's (de)serialiser the first time a store uses it)."""
    return typestore_of(ros2msg.STREAM_EVENTS)


@pytest.mark.parametrize(
    "name",
    [
        "sensor_msgs/msg/Imu",
        "sensor_msgs/msg/BatteryState",
        "std_msgs/msg/Header",
        "builtin_interfaces/msg/Time",
        "geometry_msgs/msg/Quaternion",
        "geometry_msgs/msg/Vector3",
    ],
)
def test_standard_types_match_ros2(store, name):
    """Field for field, the standard types we embed are ROS 2 Humble's (and Jazzy's)."""
    ours = store.fielddefs[name][1]
    for distro in (Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY):
        assert ours == get_typestore(distro).fielddefs[name][1], (name, distro)


def test_each_schema_carries_its_dependencies():
    for kind in ALL_TYPES:
        store = typestore_of(kind)  # alone: nothing else registered
        assert kind.name in store.fielddefs
        store.generate_msgdef(kind.name, ros_version=2)  # raises on an unknown field type


def _frame(**values) -> SensorFrame:
    fields = dict(
        sample_time_us=123, acc=(100, -2048, 4096), acc_1g=2048, gyro_scale=0.0609756,
        gyro=(1000, -32768, 32767), attitude=(-32768, 0, 0, 0),
        rc=(1500, 1400, 1600, 1000, 2000, 990), rpm=(0, 12000, 65535, 300), vbat=1587,
    )  # fmt: skip
    fields.update(values)
    return SensorFrame(**fields)


def test_imu_units_and_stamp(store):
    frame = _frame()
    stamp = 1_700_000_123_456_789_012
    msg = store.deserialize_cdr(FrameEncoder(0).imu(frame, stamp), "sensor_msgs/msg/Imu")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_123, 456_789_012)
    assert msg.header.frame_id == "fc"
    q = msg.orientation
    assert (q.w, q.x, q.y, q.z) == (-1.0, 0.0, 0.0, 0.0)  # the level craft of spec §4
    gyro_scale = frame.gyro_scale  # as the wire's float32 holds it
    expected_rad_s = [v * gyro_scale * math.pi / 180 for v in (1000, -32768, 32767)]
    w = msg.angular_velocity
    assert [w.x, w.y, w.z] == pytest.approx(expected_rad_s, rel=1e-12)
    a = msg.linear_acceleration
    assert [a.x, a.y, a.z] == pytest.approx([100 / 2048 * 9.80665, -9.80665, 19.6133], rel=1e-12)
    for covariance in (
        msg.orientation_covariance,
        msg.angular_velocity_covariance,
        msg.linear_acceleration_covariance,
    ):
        assert list(covariance) == [0.0] * 9  # known quantity, covariance unknown


def test_missing_attitude_and_acc_calibration_say_no_estimate(store):
    frame = _frame(attitude=(0, 0, 0, 0), acc_1g=0)
    msg = store.deserialize_cdr(FrameEncoder(0).imu(frame, 0), "sensor_msgs/msg/Imu")
    assert msg.orientation_covariance[0] == -1.0  # REP-145 / sensor_msgs: no estimate
    assert msg.linear_acceleration_covariance[0] == -1.0
    assert msg.angular_velocity_covariance[0] == 0.0
    a = msg.linear_acceleration
    assert (a.x, a.y, a.z) == (0.0, 0.0, 0.0)  # finite, for tools that ignore the -1


def test_battery_rc_rpm_attitude(store):
    frame = _frame()
    encoder = FrameEncoder(0)
    battery = store.deserialize_cdr(encoder.battery(frame, 5), "sensor_msgs/msg/BatteryState")
    assert battery.voltage == pytest.approx(15.87)
    assert math.isnan(battery.current) and math.isnan(battery.percentage)
    assert battery.present and battery.power_supply_status == 0
    assert len(battery.cell_voltage) == 0 and battery.location == ""
    rc = store.deserialize_cdr(encoder.rc(frame, 5), "wftool_msgs/msg/RcChannels")
    assert (rc.roll, rc.pitch, rc.yaw, rc.throttle, rc.aux3, rc.aux4) == frame.rc
    rpm = store.deserialize_cdr(encoder.rpm(frame, 5), "wftool_msgs/msg/MotorRpm")
    assert list(rpm.rpm) == [0, 12000, 65535, 300]
    attitude = store.deserialize_cdr(encoder.attitude(frame, 5), "wftool_msgs/msg/Attitude")
    assert (attitude.roll_deg, attitude.pitch_deg, attitude.yaw_deg) == pytest.approx(
        frame.euler_deg
    )


@settings(max_examples=examples(60))
@given(frame_id=st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=40))
def test_any_frame_id_moves_what_follows_the_header_by_the_rules(store, frame_id):
    """Every message with any frame id: the header's string shifts the rest of the message,
    which CDR realigns (an Imu's doubles to 8, StreamHealth's uint64 after three bools)."""
    frame = _frame()
    encoder = FrameEncoder(0, frame_id)
    health = StreamHealth(1.5, 7, 2, True, False, True, 10, 20, 1, 2, 3, 4, 5, 6)
    uplink = UplinkReport(UplinkStatus(9, 8, 7, 6, 5, 4, 50, 0b10101, 3, 2), 2.5, 1.25)
    for message, name in (
        (encoder.imu(frame, 5), "sensor_msgs/msg/Imu"),
        (encoder.battery(frame, 5), "sensor_msgs/msg/BatteryState"),
        (encoder.rc(frame, 5), "wftool_msgs/msg/RcChannels"),
        (encoder.rpm(frame, 5), "wftool_msgs/msg/MotorRpm"),
        (encoder.attitude(frame, 5), "wftool_msgs/msg/Attitude"),
        (encoder.health(health), "wftool_msgs/msg/StreamHealth"),
        (encoder.uplink_status(uplink), "wftool_msgs/msg/UplinkStatus"),
    ):
        decoded = store.deserialize_cdr(message, name)
        assert decoded.header.frame_id == frame_id, name
        reference = store.serialize_cdr(decoded, name)  # rosbags' own bytes of the same values
        assert message == reference, name
    rc = store.deserialize_cdr(encoder.rc(frame, 5), "wftool_msgs/msg/RcChannels")
    assert (rc.roll, rc.pitch, rc.yaw, rc.throttle, rc.aux3, rc.aux4) == frame.rc
    decoded = store.deserialize_cdr(encoder.health(health), "wftool_msgs/msg/StreamHealth")
    assert (decoded.lost_frames, decoded.reconnects) == (1, 6)
    decoded = store.deserialize_cdr(encoder.uplink_status(uplink), "wftool_msgs/msg/UplinkStatus")
    assert (decoded.failsafe_phase, decoded.tx_time_us, decoded.timed_out.sec) == (3, 8, 1)


@pytest.mark.parametrize("flag", list(UplinkFlag), ids=lambda flag: flag.name)
def test_uplink_status(store, flag):
    """Every field where the message names it: each flag alone, counters at their limits,
    the stamps on the frames' clock (Unix time), who flies."""
    top = 2**32 - 1
    status = UplinkStatus(
        2**24 - 1, top, top, top - 1, top - 2, top - 3, 65535, flag, 6, 12345,
        Authority.ENGAGED, AuthorityExit.FOREIGN, 500, 12000, 2**24 - 1, top - 4, top - 5,
        top - 6, 885, 2115,
    )  # fmt: skip
    report = UplinkReport(status, 12.5, 12.25, 12.125)
    encoder = FrameEncoder(1_000_000_000_000)
    msg = store.deserialize_cdr(encoder.uplink_status(report), "wftool_msgs/msg/UplinkStatus")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1012, 500_000_000)
    assert (msg.timed_out.sec, msg.timed_out.nanosec) == (1012, 250_000_000)
    assert (msg.exit_time.sec, msg.exit_time.nanosec) == (1012, 125_000_000)
    assert (msg.command_seq, msg.tx_time_us, msg.accepted, msg.stale, msg.timeouts, msg.rejected,
            msg.timeout_ms, msg.failsafe_phase, msg.timed_out_us) == (
        2**24 - 1, top, top, top - 1, top - 2, top - 3, 65535, 6, 12345,
    )  # fmt: skip
    assert (msg.authority, msg.exit, msg.proof_ms, msg.exit_us, msg.sender, msg.foreign,
            msg.refused, msg.msp_rc_refused, msg.rc_min_us, msg.rc_max_us) == (
        msg.AUTHORITY_ENGAGED, msg.EXIT_FOREIGN, 500, 12000, 2**24 - 1, top - 4, top - 5,
        top - 6, 885, 2115,
    )  # fmt: skip
    flags = {name: getattr(msg, name) for name in ("live", "override", "obc_receiver",
                                                    "rx_loss", "armed", "arm_switch")}  # fmt: skip
    assert flags == {name: name == flag.name.lower() for name in flags}
    phases = [getattr(msg, f"FAILSAFE_{name}") for name in FAILSAFE_PHASES]  # Betaflight's
    assert phases == list(range(len(FAILSAFE_PHASES)))
    authorities = [getattr(msg, f"AUTHORITY_{a.name}") for a in Authority]  # the spec's
    exits = [getattr(msg, f"EXIT_{e.name}") for e in AuthorityExit]
    assert (authorities, exits) == (list(Authority), list(AuthorityExit))
    before = encoder.uplink_status(UplinkReport(status, 12.5, None))  # no timeout yet
    assert store.deserialize_cdr(before, "wftool_msgs/msg/UplinkStatus").timed_out.sec == 0


def test_a_status_of_firmware_without_who_flies_says_unknown(store):
    status = UplinkStatus(7, 100, 7, 0, 0, 0, 50, UplinkFlag.LIVE, 0, 0)  # 36 bytes' worth
    encoder = FrameEncoder(1_000_000_000_000)
    msg = store.deserialize_cdr(
        encoder.uplink_status(UplinkReport(status, 12.5, None)), "wftool_msgs/msg/UplinkStatus"
    )
    assert msg.authority == msg.AUTHORITY_UNKNOWN == 255
    assert (msg.exit, msg.exit_time.sec, msg.sender, msg.rc_min_us, msg.arm_switch) == (
        0, 0, 0, 0, False,
    )  # fmt: skip
    assert msg.live and msg.command_seq == 7


def test_health(store):
    health = StreamHealth(
        t=12.5, seq=2**24 - 1, epoch=3, e1=True, clock_locked=False, connected=True,
        packets=10, frames=20, lost_frames=2**40, lost_packets=5, fc_drops=6,
        rejected_chunks=7, resets=3, reconnects=1,
    )  # fmt: skip
    encoder = FrameEncoder(1_000_000_000_000)
    msg = store.deserialize_cdr(encoder.health(health), "wftool_msgs/msg/StreamHealth")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1012, 500_000_000)
    for field in ("seq", "epoch", "e1", "clock_locked", "connected", "packets", "frames",
                  "lost_frames", "lost_packets", "fc_drops", "rejected_chunks", "resets",
                  "reconnects"):  # fmt: skip
        assert getattr(msg, field) == getattr(health, field), field


@pytest.mark.parametrize(
    ("kind", "data", "rc"),
    [
        ("bytes", b"\x01\x02\x03", ()),
        ("bytes", bytes(range(256)) * 3, ()),
        ("command", b"", (1100, 1500, -1, 1000, 2000, 32767)),
        ("connected", b"", ()),
    ],
)
def test_event_round_trip_and_rosbags_agree(store, kind, data, rc):
    message = ros2msg.encode_event(Event(kind, 1234.000001, data, rc))
    assert ros2msg.decode_event(message) == (kind, 1234.000001, data, rc)
    decoded = store.deserialize_cdr(message, "wftool_msgs/msg/StreamEvent")
    assert ros2msg.EVENT_KINDS[decoded.kind] == kind
    assert bytes(decoded.data) == data and tuple(decoded.rc) == rc
    assert store.serialize_cdr(decoded, "wftool_msgs/msg/StreamEvent") == message


def _event(kind: str, t: float, data: bytes, rc: list[int]) -> tuple:
    """Data only on a read, RC only on a command."""
    return (kind, t, data if kind == "bytes" else b"", tuple(rc) if kind == "command" else ())


event_batches = st.lists(
    st.builds(
        _event,
        st.sampled_from(ros2msg.EVENT_KINDS),
        st.floats(0.0, 1e7),
        st.binary(max_size=300),
        st.lists(st.integers(-32768, 32767), max_size=8),
    ),
    max_size=40,
)


@settings(max_examples=examples(200), deadline=None)
@given(events=event_batches)
def test_event_batches_round_trip_and_rosbags_agree(events_store, events):
    """A `StreamEvents` batch: our decoder gives the events back; rosbags, from the
    definition alone, reads the same arrays and writes the very same bytes."""
    store = events_store
    message = ros2msg.encode_events(events)
    assert ros2msg.decode_events(message).events() == events
    decoded = store.deserialize_cdr(message, "wftool_msgs/msg/StreamEvents")
    assert decoded.t.tolist() == [t for _, t, _, _ in events]
    assert [ros2msg.EVENT_KINDS[k] for k in decoded.kind.tolist()] == [k for k, *_ in events]
    assert bytes(decoded.data) == b"".join(data for _, _, data, _ in events)
    assert decoded.rc.tolist() == [v for *_, rc in events for v in rc]
    assert store.serialize_cdr(decoded, "wftool_msgs/msg/StreamEvents") == message


def test_a_damaged_event_batch_is_a_clear_error():
    message = ros2msg.encode_events([("bytes", 1.0, b"abc", ()), ("connected", 2.0, b"", ())])
    with pytest.raises(ValueError, match="cut short"):
        ros2msg.decode_events(message[:-8])
    with pytest.raises(ValueError, match="do not add up"):
        sizes = b"\x02\x00\x00\x00" + bytes(4)  # the read's 3 bytes said to be 2
        ros2msg.decode_events(message.replace(b"\x03\x00\x00\x00" + bytes(4), sizes))
    with pytest.raises(ValueError, match="not little-endian CDR"):
        ros2msg.decode_events(b"\x00\x00" + message[2:])


@settings(max_examples=examples(200), deadline=None)
@given(frame=frames)
def test_any_frame_encodes_as_rosbags_would(store, frame):
    """Over every wire value: rosbags decodes our bytes and re-encodes them identically."""
    encoder = FrameEncoder(0)
    stamp = 1_700_000_000_000_000_001
    for name, message in (
        ("sensor_msgs/msg/Imu", encoder.imu(frame, stamp)),
        ("sensor_msgs/msg/BatteryState", encoder.battery(frame, stamp)),
        ("wftool_msgs/msg/RcChannels", encoder.rc(frame, stamp)),
        ("wftool_msgs/msg/MotorRpm", encoder.rpm(frame, stamp)),
        ("wftool_msgs/msg/Attitude", encoder.attitude(frame, stamp)),
    ):
        decoded = store.deserialize_cdr(message, name)
        assert store.serialize_cdr(decoded, name) == message, name
    imu = store.deserialize_cdr(encoder.imu(frame, stamp), "sensor_msgs/msg/Imu")
    w, x, y, z = frame.attitude
    assert (imu.orientation.w, imu.orientation.x) == (w / 32768, x / 32768)
    assert (imu.orientation.y, imu.orientation.z) == (y / 32768, z / 32768)
