"""ROS 2 messages of the FSP stream: their `.msg` definitions and CDR bytes, encoded once here
for the recording and the live view (stamps, units, covariances: docs/recording.md).

    encoder = FrameEncoder()
    data = encoder.imu(frame, encoder.frame_stamp_ns(frame, packet.arrival_time))
"""

from __future__ import annotations

import functools
import math
import struct
import sys
import time
from array import array
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from wftool.fsp import SensorFrame, UplinkFlag
from wftool.recording.events import EVENT_KINDS, Event, StreamHealth, UplinkReport

FRAME_ID = "fc"
STANDARD_GRAVITY = 9.80665
SLOW_PERIOD_NS = 100_000_000
"""Battery state, and RC at the least: 10 Hz."""

IMU_TOPIC = "/fsp/imu"
RPM_TOPIC = "/fsp/rpm"
RC_TOPIC = "/fsp/rc"
ATTITUDE_TOPIC = "/fsp/attitude"
BATTERY_TOPIC = "/fsp/battery"
HEALTH_TOPIC = "/fsp/health"
UPLINK_STATUS_TOPIC = "/fsp/uplink_status"
CDR_LE = b"\x00\x01\x00\x00"
"""The encapsulation header of little-endian plain CDR, as ROS 2 writes it."""

_RULE = "=" * 80

TIME_MSG = "int32 sec\nuint32 nanosec\n"
HEADER_MSG = "builtin_interfaces/Time stamp\nstring frame_id\n"
QUATERNION_MSG = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
VECTOR3_MSG = "float64 x\nfloat64 y\nfloat64 z\n"
IMU_MSG = """\
std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance
"""
BATTERY_STATE_MSG = """\
uint8 POWER_SUPPLY_STATUS_UNKNOWN = 0
uint8 POWER_SUPPLY_STATUS_CHARGING = 1
uint8 POWER_SUPPLY_STATUS_DISCHARGING = 2
uint8 POWER_SUPPLY_STATUS_NOT_CHARGING = 3
uint8 POWER_SUPPLY_STATUS_FULL = 4
uint8 POWER_SUPPLY_HEALTH_UNKNOWN = 0
uint8 POWER_SUPPLY_HEALTH_GOOD = 1
uint8 POWER_SUPPLY_HEALTH_OVERHEAT = 2
uint8 POWER_SUPPLY_HEALTH_DEAD = 3
uint8 POWER_SUPPLY_HEALTH_OVERVOLTAGE = 4
uint8 POWER_SUPPLY_HEALTH_UNSPEC_FAILURE = 5
uint8 POWER_SUPPLY_HEALTH_COLD = 6
uint8 POWER_SUPPLY_HEALTH_WATCHDOG_TIMER_EXPIRE = 7
uint8 POWER_SUPPLY_HEALTH_SAFETY_TIMER_EXPIRE = 8
uint8 POWER_SUPPLY_TECHNOLOGY_UNKNOWN = 0
uint8 POWER_SUPPLY_TECHNOLOGY_NIMH = 1
uint8 POWER_SUPPLY_TECHNOLOGY_LION = 2
uint8 POWER_SUPPLY_TECHNOLOGY_LIPO = 3
uint8 POWER_SUPPLY_TECHNOLOGY_LIFE = 4
uint8 POWER_SUPPLY_TECHNOLOGY_NICD = 5
uint8 POWER_SUPPLY_TECHNOLOGY_LIMN = 6
std_msgs/Header header
float32 voltage
float32 temperature
float32 current
float32 charge
float32 capacity
float32 design_capacity
float32 percentage
uint8 power_supply_status
uint8 power_supply_health
uint8 power_supply_technology
bool present
float32[] cell_voltage
float32[] cell_temperature
string location
string serial_number
"""
WFTOOL_MSGS = Path(__file__).resolve().with_name("wftool_msgs")
"""The `wftool_msgs` ROS 2 package (package.xml, CMakeLists.txt, msg/): the one source of our
types' definitions, read here and built by ROS 2 (`colcon build`, or `wftool ros2 --build-msgs`)."""


def wftool_msg(name: str) -> str:
    """The definition of `wftool_msgs/msg/<name>`, as its `.msg` file holds it."""
    return (WFTOOL_MSGS / "msg" / f"{name}.msg").read_text(encoding="utf-8")


RC_CHANNELS_MSG = wftool_msg("RcChannels")
MOTOR_RPM_MSG = wftool_msg("MotorRpm")
ATTITUDE_MSG = wftool_msg("Attitude")
STREAM_HEALTH_MSG = wftool_msg("StreamHealth")
UPLINK_STATUS_MSG = wftool_msg("UplinkStatus")
MSP_RC_MSG = wftool_msg("MspRc")
STREAM_EVENT_MSG = wftool_msg("StreamEvent")
STREAM_EVENTS_MSG = wftool_msg("StreamEvents")


@dataclass(frozen=True)
class MessageType:
    name: str
    """ROS 2 type name, e.g. `sensor_msgs/msg/Imu`."""
    schema: str
    """The `ros2msg` schema: the definition, then each type it uses."""

    @property
    def schema_bytes(self) -> bytes:
        return self.schema.encode()


def _message_type(name: str, definition: str, *uses: tuple[str, str]) -> MessageType:
    parts = [definition]
    for used_name, used_definition in uses:
        parts.append(f"{_RULE}\nMSG: {used_name}\n{used_definition}")
    return MessageType(name, "".join(parts))


_HEADER_USES = (("std_msgs/Header", HEADER_MSG), ("builtin_interfaces/Time", TIME_MSG))
IMU = _message_type(
    "sensor_msgs/msg/Imu",
    IMU_MSG,
    *_HEADER_USES,
    ("geometry_msgs/Quaternion", QUATERNION_MSG),
    ("geometry_msgs/Vector3", VECTOR3_MSG),
)
BATTERY_STATE = _message_type("sensor_msgs/msg/BatteryState", BATTERY_STATE_MSG, *_HEADER_USES)
RC_CHANNELS = _message_type("wftool_msgs/msg/RcChannels", RC_CHANNELS_MSG, *_HEADER_USES)
MOTOR_RPM = _message_type("wftool_msgs/msg/MotorRpm", MOTOR_RPM_MSG, *_HEADER_USES)
ATTITUDE = _message_type("wftool_msgs/msg/Attitude", ATTITUDE_MSG, *_HEADER_USES)
STREAM_HEALTH = _message_type("wftool_msgs/msg/StreamHealth", STREAM_HEALTH_MSG, *_HEADER_USES)
UPLINK_STATUS = _message_type("wftool_msgs/msg/UplinkStatus", UPLINK_STATUS_MSG, *_HEADER_USES)
STREAM_EVENT = _message_type("wftool_msgs/msg/StreamEvent", STREAM_EVENT_MSG)
"""One event per message: the MSP baseline's recordings, and FSP ones before `STREAM_EVENTS`."""
STREAM_EVENTS = _message_type("wftool_msgs/msg/StreamEvents", STREAM_EVENTS_MSG)
"""Events in batches (`rosbag.EVENT_BATCH_S` of them a message): what recordings hold now."""
MSP_RC = _message_type("wftool_msgs/msg/MspRc", MSP_RC_MSG, *_HEADER_USES)


LIVE_PER_FRAME: tuple[tuple[str, MessageType, str], ...] = (
    (IMU_TOPIC, IMU, "imu"),
    (ATTITUDE_TOPIC, ATTITUDE, "attitude"),
    (RC_TOPIC, RC_CHANNELS, "rc"),
    (RPM_TOPIC, MOTOR_RPM, "rpm"),
)
"""What a live view publishes for every frame: (topic, type, the `FrameEncoder` method)."""


class Throttle:
    """Lets a stamp through at most once per `period_ns` (and again when stamps go back)."""

    def __init__(self, period_ns: int = SLOW_PERIOD_NS) -> None:
        self.period_ns = period_ns
        self.last_ns: int | None = None

    def due(self, stamp_ns: int) -> bool:
        last = self.last_ns
        if last is not None and 0 <= stamp_ns - last < self.period_ns:
            return False
        self.last_ns = stamp_ns
        return True


_EVENT_HEAD = struct.Struct("<4sdB3xI")
_COUNT = struct.Struct("<I")
_ALIGN = {"d": 8, "Q": 8, "f": 4, "i": 4, "I": 4, "h": 2, "H": 2, "B": 1, "?": 1, "s": 1}


def _cdr(*fields: str) -> struct.Struct:
    """The struct of a CDR message: the encapsulation header, then `fields` (struct codes
    with counts, "7f"), each padded to its alignment, which counts from the end of the
    encapsulation header."""
    layout, at = ["<4s"], 0
    for field in fields:
        code = field[-1]
        count = int(field[:-1] or 1)
        size = 1 if code == "s" else struct.calcsize(code)
        if at % _ALIGN[code]:
            pad = -at % _ALIGN[code]
            layout.append(f"{pad}x")
            at += pad
        layout.append(field)
        at += size * count
    return struct.Struct("".join(layout))


_STATUS_FLAGS = (
    UplinkFlag.LIVE, UplinkFlag.OVERRIDE, UplinkFlag.OBC_RECEIVER, UplinkFlag.RX_LOSS,
    UplinkFlag.ARMED,
)  # fmt: skip
"""The flags `UplinkStatus` carries as its first bools, in its order (`arm_switch` comes
with the authority fields)."""
_UPLINK_STATUS_FIELDS = (
    "5I", "H", "5?", "B", "2I", "i", "I",  # counters, flags, failsafe phase, the timeout
    "2B", "I", "i", "I", "H", "?", "4I", "2H",  # who flies (spec §15): exit, proof, sender, ...
)  # fmt: skip
"""`UplinkStatus` after its header."""
AUTHORITY_UNKNOWN = 255
"""`UplinkStatus.authority` of firmware that does not report it (its 36-byte statuses)."""


@dataclass(frozen=True)
class _Layouts:
    """Each message's struct for one `frame_id`: its length moves what follows the header."""

    frame_id: bytes
    """As CDR holds it: the characters and their terminating NUL."""
    imu: struct.Struct
    battery: struct.Struct
    rc: struct.Struct
    rpm: struct.Struct
    attitude: struct.Struct
    health: struct.Struct
    uplink_status: struct.Struct
    msp_rc_head: struct.Struct


@functools.lru_cache(maxsize=16)
def _layouts(frame_id: str) -> _Layouts:
    raw = frame_id.encode() + b"\0"
    header = ("i", "I", "I", f"{len(raw)}s")  # stamp, frame_id's length and characters
    return _Layouts(
        frame_id=raw,
        imu=_cdr(*header, "37d"),
        battery=_cdr(*header, "7f", "3B", "?", "I", "I", "I", "1s", "I", "1s"),
        rc=_cdr(*header, "6h"),
        rpm=_cdr(*header, "4H"),
        attitude=_cdr(*header, "3d"),
        health=_cdr(*header, "2I", "3?", "6Q", "2I"),
        uplink_status=_cdr(*header, *_UPLINK_STATUS_FIELDS),
        msp_rc_head=_cdr(*header, "I"),
    )


_ZEROS9 = (0.0,) * 9
_NO_ESTIMATE9 = (-1.0,) + (0.0,) * 8
_DEG = math.pi / 180.0
_NAN = math.nan
_BATTERY_UNMEASURED = (_NAN,) * 6
_EMPTY = b"\0"  # an empty CDR string's content


class FrameEncoder:
    """CDR bytes of one frame's messages, stamped in Unix time, with `frame_id`.

    `wall_offset_ns` maps the OBC monotonic clock (what the decoder's times are on) to
    Unix time; by default it is taken now, once, so a run's stamps keep their spacing.
    """

    def __init__(self, wall_offset_ns: int | None = None, frame_id: str = FRAME_ID) -> None:
        if wall_offset_ns is None:
            wall_offset_ns = time.time_ns() - time.monotonic_ns()
        self.wall_offset_ns = wall_offset_ns
        self.frame_id = frame_id
        self._layouts = _layouts(frame_id)

    def stamp_ns(self, t: float) -> int:
        """Unix time (ns) of OBC monotonic time `t` (s)."""
        return self.wall_offset_ns + int(t * 1e9)

    def frame_stamp_ns(self, frame: SensorFrame, fallback: float | None) -> int:
        """The frame's capture time; else `fallback` (its arrival); else now."""
        t = frame.obc_time
        if t is None:
            if fallback is None:
                return time.time_ns()
            t = fallback
        return self.wall_offset_ns + int(t * 1e9)

    def imu(self, frame: SensorFrame, stamp_ns: int) -> bytes:
        v = frame.values
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        w, x, y, z = v[9], v[10], v[11], v[12]
        orientation_cov = _ZEROS9 if w or x or y or z else _NO_ESTIMATE9
        one_g = v[4]
        if one_g:
            scale = STANDARD_GRAVITY / one_g
            ax, ay, az = v[1] * scale, v[2] * scale, v[3] * scale
            acc_cov = _ZEROS9
        else:
            ax = ay = az = 0.0
            acc_cov = _NO_ESTIMATE9
        rad = v[5] * _DEG
        layouts = self._layouts
        return layouts.imu.pack(
            CDR_LE, sec, nsec, len(layouts.frame_id), layouts.frame_id,
            x / 32768.0, y / 32768.0, z / 32768.0, w / 32768.0, *orientation_cov,
            v[6] * rad, v[7] * rad, v[8] * rad, *_ZEROS9,
            ax, ay, az, *acc_cov,
        )  # fmt: skip

    def rc(self, frame: SensorFrame, stamp_ns: int) -> bytes:
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        layouts = self._layouts
        frame_id = layouts.frame_id
        return layouts.rc.pack(CDR_LE, sec, nsec, len(frame_id), frame_id, *frame.values[13:19])

    def rpm(self, frame: SensorFrame, stamp_ns: int) -> bytes:
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        layouts = self._layouts
        frame_id = layouts.frame_id
        return layouts.rpm.pack(CDR_LE, sec, nsec, len(frame_id), frame_id, *frame.values[19:23])

    def attitude(self, frame: SensorFrame, stamp_ns: int) -> bytes:
        return attitude_message(stamp_ns, *frame.euler_deg, frame_id=self.frame_id)

    def battery(self, frame: SensorFrame, stamp_ns: int) -> bytes:
        return battery_message(stamp_ns, frame.values[23] / 100.0, frame_id=self.frame_id)

    def health(self, health: StreamHealth) -> bytes:
        sec, nsec = divmod(self.stamp_ns(health.t), 1_000_000_000)
        layouts = self._layouts
        return layouts.health.pack(
            CDR_LE, sec, nsec, len(layouts.frame_id), layouts.frame_id,
            health.seq, health.epoch, health.e1, health.clock_locked, health.connected,
            health.packets, health.frames, health.lost_frames, health.lost_packets,
            health.fc_drops, health.rejected_chunks, health.resets, health.reconnects,
        )  # fmt: skip

    def uplink_status(self, report: UplinkReport) -> bytes:
        """An `UplinkStatus`, stamped when the FC sent it; who flies `AUTHORITY_UNKNOWN`
        (and zeros after it) when the firmware does not report it."""
        sec, nsec = divmod(self.stamp_ns(report.t), 1_000_000_000)
        status = report.status
        layouts = self._layouts
        arm_switch = status.has(UplinkFlag.ARM_SWITCH)
        if status.authority is None:
            authority: tuple = (AUTHORITY_UNKNOWN, 0, 0, 0, 0, 0, arm_switch, 0, 0, 0, 0, 0, 0)
        else:
            authority = (
                status.authority, status.exit, status.exit_us, *self._time(report.exit_t),
                status.proof_ms, arm_switch, status.sender, status.foreign, status.refused,
                status.msp_rc_refused, status.rc_min_us, status.rc_max_us,
            )  # fmt: skip
        return layouts.uplink_status.pack(
            CDR_LE, sec, nsec, len(layouts.frame_id), layouts.frame_id,
            status.command_seq, status.accepted, status.stale, status.rejected, status.timeouts,
            status.timeout_ms, *(status.has(flag) for flag in _STATUS_FLAGS), status.failsafe_phase,
            status.tx_time_us, status.timed_out_us, *self._time(report.timed_out_t), *authority,
        )  # fmt: skip

    def _time(self, t: float | None) -> tuple[int, int]:
        """A `builtin_interfaces/Time` of OBC time `t` on the frames' clock; zero for None."""
        return (0, 0) if t is None else divmod(self.stamp_ns(t), 1_000_000_000)


# Messages from values, for sources other than FSP frames (the MSP baseline's replies).


def imu_message(
    stamp_ns: int,
    angular_velocity_rad_s: Sequence[float],
    linear_acceleration_m_s2: Sequence[float] | None,
    *,
    frame_id: str = FRAME_ID,
) -> bytes:
    """An `Imu` without orientation (element 0 of its covariance −1, REP-145); acceleration
    None: no estimate either."""
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    acc, acc_cov = (
        ((0.0, 0.0, 0.0), _NO_ESTIMATE9)
        if linear_acceleration_m_s2 is None
        else (linear_acceleration_m_s2, _ZEROS9)
    )
    layouts = _layouts(frame_id)
    return layouts.imu.pack(
        CDR_LE, sec, nsec, len(layouts.frame_id), layouts.frame_id,
        0.0, 0.0, 0.0, 0.0, *_NO_ESTIMATE9,
        *angular_velocity_rad_s, *_ZEROS9,
        *acc, *acc_cov,
    )  # fmt: skip


def attitude_message(
    stamp_ns: int, roll_deg: float, pitch_deg: float, yaw_deg: float, *, frame_id: str = FRAME_ID
) -> bytes:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    layouts = _layouts(frame_id)
    return layouts.attitude.pack(
        CDR_LE, sec, nsec, len(layouts.frame_id), layouts.frame_id, roll_deg, pitch_deg, yaw_deg
    )


def battery_message(
    stamp_ns: int, voltage_v: float, current_a: float = _NAN, *, frame_id: str = FRAME_ID
) -> bytes:
    """A `BatteryState` with what an FC measures: voltage, and current if it has a sensor."""
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    temperature, *others = _BATTERY_UNMEASURED[:5]
    layouts = _layouts(frame_id)
    return layouts.battery.pack(
        CDR_LE, sec, nsec, len(layouts.frame_id), layouts.frame_id,
        voltage_v, temperature, current_a, *others,
        0, 0, 0, True,  # status, health, technology unknown; present
        0, 0,  # no cell voltages or temperatures
        1, _EMPTY, 1, _EMPTY,  # location, serial number
    )  # fmt: skip


def msp_rc_message(stamp_ns: int, channels: Sequence[int], *, frame_id: str = FRAME_ID) -> bytes:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    layouts = _layouts(frame_id)
    head = layouts.msp_rc_head.pack(
        CDR_LE, sec, nsec, len(layouts.frame_id), layouts.frame_id, len(channels)
    )
    return head + struct.pack(f"<{len(channels)}H", *channels)


def encode_event(event: Event) -> bytes:
    """A `StreamEvent` message."""
    kind, t, data, rc = event
    head = _EVENT_HEAD.pack(CDR_LE, t, EVENT_KINDS.index(kind), len(data))
    padding = b"\0" * (-len(data) % 4)  # the rc sequence's length is 4-aligned
    return b"".join((head, data, padding, _COUNT.pack(len(rc)), struct.pack(f"<{len(rc)}h", *rc)))


@dataclass(frozen=True)
class EventArrays:
    """A `StreamEvents` message as flat arrays, without an object per event."""

    t: array
    """float64 per event."""
    kind: bytes
    """Per event, its index in EVENT_KINDS."""
    size: array
    """uint32 per event: its bytes in `data` (BYTES) or its values in `rc` (COMMAND)."""
    data: bytes
    """The BYTES events' data, one after the other."""
    rc: array
    """int16: the COMMAND events' RC values, one after the other."""

    def events(self) -> list[Event]:
        """The events, as `encode_events` took them."""
        events = []
        data_at = rc_at = 0
        for t, kind, size in zip(self.t, self.kind, self.size):
            name = EVENT_KINDS[kind]
            if name == "bytes":
                events.append(Event(name, t, self.data[data_at : data_at + size]))
                data_at += size
            elif name == "command":
                events.append(Event(name, t, rc=tuple(self.rc[rc_at : rc_at + size])))
                rc_at += size
            else:
                events.append(Event(name, t))
        return events


_NATIVE_LE = sys.byteorder == "little"
_BYTES = EVENT_KINDS.index("bytes")
_COMMAND = EVENT_KINDS.index("command")


def _le(values: array) -> bytes:
    if not _NATIVE_LE:
        values = array(values.typecode, values)
        values.byteswap()
    return values.tobytes()


def _sequence(parts: list[bytes], at: int, values: bytes, count: int, align: int) -> int:
    """Append a CDR sequence (its count, padding, `values`) at offset `at`; the new offset."""
    padding = -at % 4
    at += padding + 4
    inner = -at % align if count else 0  # no elements, nothing to align
    parts += (b"\0" * padding, _COUNT.pack(count), b"\0" * inner, values)
    return at + inner + len(values)


def encode_events(events: Sequence[Event]) -> bytes:
    """A `StreamEvents` message of `events`, in order."""
    times, kinds, sizes = array("d"), bytearray(), array("I")
    data: list[bytes] = []
    rc = array("h")
    for kind, t, payload, values in events:
        times.append(t)
        kinds.append(EVENT_KINDS.index(kind))
        if kind == "command":
            sizes.append(len(values))
            rc.extend(values)
        else:
            sizes.append(len(payload))
            data.append(payload)
    parts = [CDR_LE]
    at = _sequence(parts, 0, _le(times), len(times), 8)
    at = _sequence(parts, at, bytes(kinds), len(kinds), 1)
    at = _sequence(parts, at, _le(sizes), len(sizes), 4)
    blob = b"".join(data)
    at = _sequence(parts, at, blob, len(blob), 1)
    _sequence(parts, at, _le(rc), len(rc), 2)
    return b"".join(parts)


def decode_events(message: bytes) -> EventArrays:
    """The arrays of a `StreamEvents` message (ValueError if it is not one)."""
    if message[:4] != CDR_LE:
        raise ValueError(f"not little-endian CDR: {message[:4].hex()}")
    body = memoryview(message)[4:]
    at = 0
    fields = []
    for typecode, size in (("d", 8), ("B", 1), ("I", 4), ("B", 1), ("h", 2)):
        at += -at % 4
        if at + 4 > len(body):
            raise ValueError("a StreamEvents message cut short")
        (count,) = _COUNT.unpack_from(body, at)
        at += 4
        if count:
            at += -at % size
        end = at + count * size
        if end > len(body):
            raise ValueError("a StreamEvents message cut short")
        values = array(typecode)
        values.frombytes(body[at:end])
        if not _NATIVE_LE:
            values.byteswap()
        fields.append(values)
        at = end
    times, kinds, sizes, data, rc = fields
    if not len(times) == len(kinds) == len(sizes):
        raise ValueError("a StreamEvents message whose t, kind and size differ in length")
    if max(kinds, default=0) >= len(EVENT_KINDS):
        raise ValueError(f"an event kind beyond {len(EVENT_KINDS) - 1}")
    if kinds.count(_BYTES) == len(kinds):  # reads alone, as most batches are
        data_size, rc_size = sum(sizes), 0
    else:
        data_size = sum(size for kind, size in zip(kinds, sizes) if kind == _BYTES)
        rc_size = sum(size for kind, size in zip(kinds, sizes) if kind == _COMMAND)
    if (data_size, rc_size) != (len(data), len(rc)):
        raise ValueError("a StreamEvents message whose sizes do not add up to its data")
    return EventArrays(times, kinds.tobytes(), sizes, data.tobytes(), rc)


def decode_event(message: bytes) -> Event:
    """The event of a `StreamEvent` message, as `encode_event` took it."""
    encapsulation, t, kind, size = _EVENT_HEAD.unpack_from(message)
    if encapsulation != CDR_LE:
        raise ValueError(f"not little-endian CDR: {encapsulation.hex()}")
    start = _EVENT_HEAD.size
    data = message[start : start + size]
    rc_at = start + size + (-size % 4)
    (count,) = _COUNT.unpack_from(message, rc_at)
    rc = struct.unpack_from(f"<{count}h", message, rc_at + 4)
    return Event(EVENT_KINDS[kind], t, data, rc)
