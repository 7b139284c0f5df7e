"""FSP v5 packet models and their byte layouts (spec §3–§6, §10, §12–§15), without the COBS
framing.

The models hold raw wire values, so decode → encode is exact; properties convert to physical
units. Times the decoder derives (unwrapped, OBC-corrected) are left out of equality: two
packets are equal when their wire content is.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

from wftool.link.crc import crc8

VERSION = 5
TUNNEL_FLAG = 0x80
VERSION_BASE = VERSION
VERSION_TUNNEL = VERSION | TUNNEL_FLAG

STATE_LENGTH = 116
STATE_TUNNEL_LENGTH = 180
COMMAND_LENGTH = 24
TIMED_COMMAND_LENGTH = 28
ARMING_REQUEST_LENGTH = 16
TIME_REPLY_LENGTH = 20
UPLINK_STATUS_LENGTH = 64
UPLINK_STATUS_V1_LENGTH = 36
"""An uplink status of firmware before the authority fields (spec §12): no `authority`."""
UPLINK_STATUS_LENGTHS = (UPLINK_STATUS_V1_LENGTH, UPLINK_STATUS_LENGTH)
COMMAND_REPORT_LENGTH = 32
MAVLINK_FIELD_LENGTH = 64

E1_FLAG = 1 << 23
"""Bit 23 of the state packet's reserved2: the E1 counters are in use (spec §6)."""
SEQ_MODULUS = 1 << 24
DROPS_MODULUS = 1 << 16
U32_MODULUS = 1 << 32

Layout = tuple[tuple[str, str], ...]
"""(field name, `struct` code) in wire order, little-endian: the one statement of a layout,
from which the `struct` formats here and the NumPy dtypes of `columns` are derived."""

HEADER_LAYOUT: Layout = (
    ("version", "B"), ("seq_low", "B"), ("seq_high", "H"), ("tx_time_us", "I"),
)  # fmt: skip
"""Spec §3 bytes 0–7: `seq` is bits 0–7 and 8–23 of the E1 sequence number."""
FRAME_LAYOUT: Layout = (
    ("sample_time_us", "I"), ("acc", "3h"), ("acc_1g", "h"), ("gyro_scale", "f"), ("gyro", "3h"),
    ("attitude", "4h"), ("rc", "6h"), ("rpm", "4H"), ("vbat", "H"),
)  # fmt: skip
"""Spec §4: one sensor frame; a state packet carries two, after the header."""
TUNNEL_LAYOUT: Layout = (("mavlink", f"{MAVLINK_FIELD_LENGTH}s"),)
"""The 180-byte variant's MAVLink field, between the frames and the trailer."""
TRAILER_LAYOUT: Layout = (("drops", "H"), ("reserved2_high", "B"), ("crc", "B"))
"""reserved2 bits 0–15 (E1 `drops`) and 16–23 (bit 23: E1 in use), then the CRC."""


def _format(layout: Layout) -> str:
    return "".join(code for _, code in layout)


_FRAME_FORMAT = _format(FRAME_LAYOUT)
_FRAME_VALUES = sum(int(code[:-1] or 1) for _, code in FRAME_LAYOUT)
_HEADER_FORMAT = "<" + _format(HEADER_LAYOUT)
_TRAILER_FORMAT = _format(TRAILER_LAYOUT)
_STATE_BASE = struct.Struct(_HEADER_FORMAT + _FRAME_FORMAT * 2 + _TRAILER_FORMAT)
_STATE_TUNNEL = struct.Struct(
    _HEADER_FORMAT + _FRAME_FORMAT * 2 + _format(TUNNEL_LAYOUT) + _TRAILER_FORMAT
)
_HEADER = struct.Struct(_HEADER_FORMAT)
_FRAME = struct.Struct("<" + _FRAME_FORMAT)
_TRAILER = struct.Struct("<" + _TRAILER_FORMAT)
_new = object.__new__

SENDER_LAYOUT: Layout = (("sender_low", "B"), ("sender_high", "H"))
"""A 24-bit sender identity (spec §5, §11): its bits 0–7 and 8–23, as `seq` in the header."""
CRC_LAYOUT: Layout = (("crc", "B"),)
COMMAND_LAYOUT: Layout = (*HEADER_LAYOUT, ("rc", "6h"), *SENDER_LAYOUT, *CRC_LAYOUT)
"""Spec §5: the header (`seq`, the OBC's `tx_time_us`), six RC values, the sender."""
TIMED_COMMAND_LAYOUT: Layout = (
    *HEADER_LAYOUT, ("rc", "6h"), ("at_us", "I"), *SENDER_LAYOUT, *CRC_LAYOUT,
)  # fmt: skip
"""Spec §13: a command with the FC time to act at, before the sender."""
ARMING_REQUEST_LAYOUT: Layout = (
    *HEADER_LAYOUT, ("request", "B"), *SENDER_LAYOUT, ("reserved", "3x"), *CRC_LAYOUT,
)  # fmt: skip
"""Spec §14: the header, what is asked (`ArmingAction`), the sender."""
UPLINK_STATUS_LAYOUT: Layout = (
    *HEADER_LAYOUT, ("accepted", "I"), ("stale", "I"), ("timeouts", "I"), ("rejected", "I"),
    ("timeout_ms", "H"), ("flags", "B"), ("failsafe_phase", "B"), ("timed_out_us", "I"),
)  # fmt: skip
"""Spec §12 bytes 0–31, every uplink status's: the header's `seq` is `command_seq`."""
AUTHORITY_LAYOUT: Layout = (
    ("authority", "B"), ("exit", "B"), ("proof_ms", "H"), ("exit_us", "I"), *SENDER_LAYOUT,
    ("reserved", "x"), ("foreign", "I"), ("refused", "I"), ("msp_rc_refused", "I"),
    ("rc_min_us", "H"), ("rc_max_us", "H"), ("reserved2", "3x"),
)  # fmt: skip
"""Spec §12 bytes 32–62: who flies (§15), the sender, the refusals, the FC's pulse range."""
TIME_REPLY_LAYOUT: Layout = (
    *HEADER_LAYOUT, ("rx_time_us", "I"), ("fc_tx_time_us", "I"), ("reserved", "3x"), *CRC_LAYOUT,
)  # fmt: skip
"""Spec §10: the header echoes the command (`command_seq`, `command_tx_time_us`)."""
COMMAND_REPORT_LAYOUT: Layout = (
    *HEADER_LAYOUT, ("at_us", "I"), ("event_us", "I"), ("outcome", "B"), ("queued", "B"),
    ("counts", "6H"), ("reserved", "x"), *CRC_LAYOUT,
)  # fmt: skip
"""Spec §13: the header echoes the timed command (`command_seq`, `command_tx_time_us`)."""


def _struct(*layouts: Layout) -> struct.Struct:
    return struct.Struct("<" + "".join(_format(layout) for layout in layouts))


_COMMAND = _struct(COMMAND_LAYOUT)
_TIMED_COMMAND = _struct(TIMED_COMMAND_LAYOUT)
_ARMING_REQUEST = _struct(ARMING_REQUEST_LAYOUT)
_TIME_REPLY = _struct(TIME_REPLY_LAYOUT)
_UPLINK_STATUS_V1 = _struct(UPLINK_STATUS_LAYOUT, (("reserved", "3x"),), CRC_LAYOUT)
_UPLINK_STATUS = _struct(UPLINK_STATUS_LAYOUT, AUTHORITY_LAYOUT, CRC_LAYOUT)
_COMMAND_REPORT = _struct(COMMAND_REPORT_LAYOUT)
assert _STATE_BASE.size == STATE_LENGTH
assert _STATE_TUNNEL.size == STATE_TUNNEL_LENGTH
assert _COMMAND.size == COMMAND_LENGTH
assert _TIMED_COMMAND.size == TIMED_COMMAND_LENGTH
assert _ARMING_REQUEST.size == ARMING_REQUEST_LENGTH
assert _TIME_REPLY.size == TIME_REPLY_LENGTH
assert _UPLINK_STATUS_V1.size == UPLINK_STATUS_V1_LENGTH
assert _UPLINK_STATUS.size == UPLINK_STATUS_LENGTH
assert _COMMAND_REPORT.size == COMMAND_REPORT_LENGTH

Q15 = 32768.0
RC_CHANNELS = ("roll", "pitch", "yaw", "throttle", "aux3", "aux4")
RC_PULSE_US = (750, 2250)
"""The widest RC values a command may carry: Betaflight's PWM_PULSE_MIN/PWM_PULSE_MAX
(rx/rx.h), within which `rx_min_usec`/`rx_max_usec` are configured (cli/settings.c). The FC
refuses a command with any value outside its own range (spec §5), which its uplink status
reports (`UplinkStatus.pulse_range`); before one has come, nothing outside these leaves the
OBC."""
SENDER_MODULUS = 1 << 24
"""A sender identity is 24 bits, and not 0 (spec §11)."""


class _WireEnum(enum.IntEnum):
    """A byte of the wire as a typed value: a value this version does not know (newer
    firmware) decodes as a member of its own, `UNKNOWN_<n>`, instead of failing."""

    @classmethod
    def _missing_(cls, value: object) -> _WireEnum | None:
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 0xFF:
            return None
        member = int.__new__(cls, value)
        member._name_ = f"UNKNOWN_{value}"
        member._value_ = value
        return cls._value2member_map_.setdefault(value, member)  # type: ignore[return-value]


class SensorFrame:
    """One 52-byte sensor frame (spec §4): raw values as on the wire, units on request.

    The 24 unpacked wire values stay in one tuple (`values`) and the named fields slice it
    on access, which is what lets the decoder deliver several hundred thousand frames/s.
    """

    __slots__ = ("obc_time", "time_us", "values")

    def __init__(
        self,
        sample_time_us: int,
        acc: tuple[int, int, int],
        acc_1g: int,
        gyro_scale: float,
        gyro: tuple[int, int, int],
        attitude: tuple[int, int, int, int],
        rc: tuple[int, int, int, int, int, int],
        rpm: tuple[int, int, int, int],
        vbat: int,
    ) -> None:
        values = (sample_time_us, *acc, acc_1g, gyro_scale, *gyro, *attitude, *rc, *rpm, vbat)
        if len(values) != _FRAME_VALUES:
            raise ValueError("a frame takes 3 acc, 3 gyro, 4 attitude, 6 rc and 4 rpm values")
        self.values: tuple = values
        """The 24 wire values in layout order."""
        self.time_us: int | None = None
        """FC capture time unwrapped to 64 bits (set by the decoder)."""
        self.obc_time: float | None = None
        """Capture time on the OBC clock in seconds (set by the decoder's clock estimator)."""

    sample_time_us = property(lambda self: self.values[0])
    acc = property(lambda self: self.values[1:4])
    acc_1g = property(lambda self: self.values[4])
    gyro_scale = property(lambda self: self.values[5])
    gyro = property(lambda self: self.values[6:9])
    attitude = property(lambda self: self.values[9:13])
    rc = property(lambda self: self.values[13:19])
    rpm = property(lambda self: self.values[19:23])
    vbat = property(lambda self: self.values[23])

    def __eq__(self, other: object) -> bool:
        """Wire content only: derived times do not make two frames different."""
        if not isinstance(other, SensorFrame):
            return NotImplemented
        return self.values == other.values

    __hash__ = None  # type: ignore[assignment]  # the timing fields are mutable

    def __repr__(self) -> str:
        fields = ", ".join(f"{name}={getattr(self, name)!r}" for name in FRAME_FIELDS)
        return f"SensorFrame({fields}, time_us={self.time_us}, obc_time={self.obc_time})"

    @property
    def acc_g(self) -> tuple[float, float, float]:
        """Acceleration in g; NaN while the FC reports no 1 g calibration (acc_1g = 0)."""
        v = self.values
        one_g = v[4] or math.nan
        return (v[1] / one_g, v[2] / one_g, v[3] / one_g)

    @property
    def gyro_dps(self) -> tuple[float, float, float]:
        v = self.values
        return (v[6] * v[5], v[7] * v[5], v[8] * v[5])

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        """Attitude quaternion (w, x, y, z); −32768 reads as −1.0 (spec §4)."""
        v = self.values
        return (v[9] / Q15, v[10] / Q15, v[11] / Q15, v[12] / Q15)

    @property
    def euler_deg(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in degrees, in Betaflight's convention (yaw = heading, 0–360).

        Every term is a product of two components, so q and −q give the same angles.
        """
        w, x, y, z = self.quaternion
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if norm == 0.0:
            return (math.nan, math.nan, math.nan)
        w, x, y, z = w / norm, x / norm, y / norm, z / norm
        roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - x * z))))
        yaw = -math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return (math.degrees(roll), math.degrees(pitch), math.degrees(yaw) % 360.0)

    @property
    def vbat_v(self) -> float:
        return self.values[23] / 100.0


FRAME_FIELDS = tuple(name for name, _ in FRAME_LAYOUT)


class StatePacket:
    """FC → OBC state packet (spec §3): two sensor frames, optional MAVLink tunnel, E1."""

    __slots__ = (
        "arrival_time", "drops", "e1", "epoch", "frames", "mavlink", "outlier", "seq", "time_us",
        "tx_time_us",
    )  # fmt: skip

    def __init__(
        self,
        tx_time_us: int,
        frames: tuple[SensorFrame, SensorFrame],
        seq: int = 0,
        e1: bool = False,
        drops: int = 0,
        mavlink: bytes | None = None,
    ) -> None:
        self.tx_time_us = tx_time_us
        self.frames = frames
        self.seq = seq
        self.e1 = e1
        self.drops = drops
        self.mavlink: bytes | None = mavlink
        """The 64-byte tunnel field of the 180-byte variant, zero padding included; else None."""
        self.time_us: int | None = None
        """`tx_time_us` unwrapped to 64 bits (set by the decoder)."""
        self.arrival_time: float | None = None
        """OBC clock (s) when the bytes carrying this packet were read (set by the decoder)."""
        self.epoch = 0
        """How many FC resets the decoder had seen when this packet arrived."""
        self.outlier = False
        """The packet fits neither the stream before it nor (so far) the one after it: a
        repeat, or a time that passed the CRC by chance. Its times are provisional and it is
        left out of the books; the next packet may show it began a new epoch instead (the
        decoder then corrects it in place). Set by the decoder."""

    def _wire(self) -> tuple:
        return (self.tx_time_us, self.frames, self.seq, self.e1, self.drops, self.mavlink)

    def __eq__(self, other: object) -> bool:
        """Wire content only, like `SensorFrame`."""
        if not isinstance(other, StatePacket):
            return NotImplemented
        return self._wire() == other._wire()

    __hash__ = None  # type: ignore[assignment]  # the timing fields are mutable

    def __repr__(self) -> str:
        return (
            f"StatePacket(tx_time_us={self.tx_time_us}, seq={self.seq}, e1={self.e1}, "
            f"drops={self.drops}, tunnel={self.tunnel}, frames={self.frames!r})"
        )

    @property
    def version(self) -> int:
        return VERSION

    @property
    def tunnel(self) -> bool:
        return self.mavlink is not None


RcValues = tuple[int, int, int, int, int, int]
"""roll, pitch, yaw, throttle, aux3, aux4: what a command carries."""


def rc_values(rc: Sequence[int]) -> RcValues:
    """`rc` as a command carries it; ValueError unless it holds six values."""
    if len(rc) != 6:
        raise ValueError(
            f"a command carries 6 RC values (roll pitch yaw throttle aux3 aux4), not {len(rc)}"
        )
    roll, pitch, yaw, throttle, aux3, aux4 = rc
    return (roll, pitch, yaw, throttle, aux3, aux4)


@dataclass(slots=True)
class CommandPacket:
    """OBC → FC command packet (spec §5): RC values for the FC's MSP receiver path; with
    `at_us` a timed command (E4, spec §13), which the FC applies at that FC time."""

    rc: RcValues
    """roll, pitch, yaw, throttle, aux3, aux4 (µs-style, within the FC's pulse range)."""
    seq: int = 0
    """24 bits, one more per packet of the sender (commands and arming requests, §11)."""
    tx_time_us: int = 0
    """The OBC clock (u32 µs) when sent."""
    at_us: int | None = None
    """FC `micros()` (u32) to act at: a timed command (28 bytes); None acts when the FC
    decodes it (24 bytes)."""
    sender: int = 0
    """The sender identity (24 bits; the FC refuses 0, spec §11)."""


class ArmingAction(_WireEnum):
    """What an arming request asks (E5, spec §14)."""

    ARM = 1
    """Set the ARM switch the FC holds (AUX1) on: the FC arms by Betaflight's own rules."""
    DISARM = 2
    """Set it off."""


@dataclass(slots=True)
class ArmingRequest:
    """OBC → FC arming request (E5, spec §14): with the OBC alone, the one way it arms or
    disarms. Taken only from the latched sender with a command in effect."""

    request: ArmingAction
    seq: int = 0
    """The sender's sequence, shared with its commands (§11)."""
    tx_time_us: int = 0
    """The OBC clock (u32 µs) when sent."""
    sender: int = 0
    """The sender identity (24 bits, not 0)."""


@dataclass(slots=True)
class TimeReply:
    """FC → OBC time reply (spec §10, E2): which command it answers, and when, by the FC clock.

    Equality is the wire content; the decoder adds the unwrapped FC times and the arrival.
    """

    command_seq: int
    """`seq` of the command answered (24 bits)."""
    command_tx_time_us: int
    """That command's `tx_time_us` (OBC clock, u32), echoed."""
    rx_time_us: int
    """FC `micros()` (u32) when the FC took the command."""
    tx_time_us: int
    """FC `micros()` (u32) when the reply was written to the port."""
    received_us: int | None = field(default=None, compare=False)
    """`rx_time_us` unwrapped into the state stream's 64-bit FC time (set by the decoder)."""
    sent_us: int | None = field(default=None, compare=False)
    """`tx_time_us` unwrapped likewise."""
    arrival_time: float | None = field(default=None, compare=False)
    """OBC clock (s) when the bytes carrying the reply were read."""

    @property
    def version(self) -> int:
        return VERSION


class UplinkFlag(enum.IntFlag):
    """The flags byte of an uplink status (spec §12)."""

    LIVE = 1 << 0
    """A fresh command is in effect (less than the command timeout old)."""
    OVERRIDE = 1 << 1
    """The MSP OVERRIDE mode is on: the OBC's fresh commands steer the overridden channels."""
    OBC_RECEIVER = 1 << 2
    """The MSP receiver is the FC's receiver: the OBC flies alone."""
    RX_LOSS = 1 << 3
    """The FC's receiver has lost its signal (RXLOSS)."""
    ARMED = 1 << 4
    ARM_SWITCH = 1 << 5
    """The FC holds its ARM switch on for the OBC (an arming request, spec §14)."""


class Authority(_WireEnum):
    """Who flies (spec §15): an uplink status's `authority`."""

    PILOT = 0
    """The pilot's sticks (or, with the OBC alone and no link, no one: the FC's failsafe)."""
    PROVING = 1
    """A link, proving itself for `proof_ms`: the OBC's commands are ignored."""
    READY = 2
    """Proven: the pilot may engage the OBC (override switch off → on)."""
    ENGAGED = 3
    """The pilot engaged the OBC: its commands steer the overridden sticks."""
    RECEIVER = 4
    """The OBC alone, a command in effect: its commands are the FC's RC input."""

    @property
    def steers(self) -> bool:
        """The OBC's commands steer the aircraft (`ENGAGED`, `RECEIVER`)."""
        return self in (Authority.ENGAGED, Authority.RECEIVER)


class AuthorityExit(_WireEnum):
    """Why the OBC last lost its authority or link, or was refused it (spec §15)."""

    NONE = 0
    """None yet."""
    TIMEOUT = 1
    """No fresh command for `fsp_cmd_timeout_ms`."""
    SWITCH_OFF = 2
    """The pilot turned the override switch off."""
    REFUSED = 3
    """The latched sender sent a packet refused whole (§5, §14)."""
    FOREIGN = 4
    """A packet of another sender came."""
    CLOCK_STEP = 5
    """The sender's `tx_time_us` stepped back."""
    RX_LOSS = 6
    """The pilot's receiver lost its signal."""
    DISARMED = 7
    """The FC disarmed."""
    NOT_READY = 8
    """The pilot turned the switch on before the OBC was ready: off and on again once it is."""


FAILSAFE_PHASES = (
    "IDLE", "RX_LOSS_DETECTED", "LANDING", "LANDED", "RX_LOSS_MONITORING", "RX_LOSS_RECOVERED",
    "GPS_RESCUE",
)  # fmt: skip
"""Betaflight's `failsafePhase_e` (flight/failsafe.h), by value."""


@dataclass(slots=True)
class UplinkStatus:
    """FC → OBC uplink status (spec §12, E3): what the FC made of the commands so far, and
    who flies (§15).

    Firmware before the authority fields sends 36 bytes: their fields here (`authority` to
    `rc_max_us`) are then None, the firmware does not report them. Equality is the wire
    content; the decoder adds the unwrapped FC times and the arrival time.
    """

    command_seq: int
    """`seq` of the newest fresh packet (24 bits; 0 before the first)."""
    tx_time_us: int
    """FC `micros()` (u32) when the status was written."""
    accepted: int
    """Fresh packets (u32, wraps)."""
    stale: int
    """Packets of a sender that were not fresh: repeats, old ones, jumps, the candidate
    that starts a link."""
    timeouts: int
    """Times the command in effect timed out."""
    rejected: int
    """Chunks that failed COBS, length, version or CRC, and valid packets refused whole."""
    timeout_ms: int
    """The FC's command timeout, `fsp_cmd_timeout_ms`."""
    flags: int
    """`UplinkFlag` bits."""
    failsafe_phase: int
    """Betaflight's failsafe phase (`FAILSAFE_PHASES`)."""
    timed_out_us: int = 0
    """FC `micros()` (u32) when a command in effect last timed out; 0 before the first."""
    authority: Authority | None = None
    """Who flies (§15); None: the firmware does not report it (a 36-byte status)."""
    exit: AuthorityExit | None = None
    """Why the OBC last lost its authority or link, or was refused it."""
    proof_ms: int | None = None
    """The proof of life the pilot's engagement needs (ms)."""
    exit_us: int | None = None
    """FC `micros()` (u32) of that `exit`; 0 before the first."""
    sender: int | None = None
    """The latched sender while a command is in effect, else the last one latched (24 bits;
    0 before the first)."""
    foreign: int | None = None
    """Packets of another sender while one was latched (u32, wraps)."""
    refused: int | None = None
    """Valid packets refused whole for what they carry (§5, §13, §14)."""
    msp_rc_refused: int | None = None
    """`MSP_SET_RAW_RC` requests refused: the uplink owns the MSP receiver (§5)."""
    rc_min_us: int | None = None
    """The FC's pulse range, `rx_min_usec` …"""
    rc_max_us: int | None = None
    """… `rx_max_usec`: a command value outside it is refused."""
    sent_us: int | None = field(default=None, compare=False)
    """`tx_time_us` unwrapped into the state stream's 64-bit FC time (set by the decoder)."""
    timed_out_at_us: int | None = field(default=None, compare=False)
    """`timed_out_us` unwrapped likewise, when there was a timeout (set by the decoder)."""
    exit_at_us: int | None = field(default=None, compare=False)
    """`exit_us` unwrapped likewise, when there was an exit (set by the decoder)."""
    arrival_time: float | None = field(default=None, compare=False)
    """OBC clock (s) when the bytes carrying the status were read."""

    @property
    def version(self) -> int:
        return VERSION

    def has(self, flag: UplinkFlag) -> bool:
        return bool(self.flags & flag)

    @property
    def reports_authority(self) -> bool:
        """The status carries the authority fields (firmware with spec §15: 64 bytes)."""
        return self.authority is not None

    @property
    def steering(self) -> bool | None:
        """The OBC's commands steer the aircraft (`authority` `engaged` or `receiver`);
        None when the firmware does not say."""
        return None if self.authority is None else self.authority.steers

    @property
    def pulse_range(self) -> tuple[int, int] | None:
        """The FC's pulse range (`rx_min_usec`, `rx_max_usec`): a command with a value
        outside it is refused whole (spec §5); None when the firmware does not report it."""
        if self.rc_min_us is None or self.rc_max_us is None:
            return None
        return (self.rc_min_us, self.rc_max_us)

    @property
    def failsafe_phase_name(self) -> str:
        phase = self.failsafe_phase
        return FAILSAFE_PHASES[phase] if phase < len(FAILSAFE_PHASES) else f"phase {phase}"


class CommandOutcome(enum.IntEnum):
    """What became of a timed command (E4, spec §13): a command report's `outcome`."""

    ON_TIME = 0
    """Applied at the first PID iteration at or after its time."""
    LATE = 1
    """Its time had come when the FC took it: applied at the next PID iteration."""
    TOO_FAR = 2
    """Refused: due a command timeout or more after the FC took it."""
    QUEUE_FULL = 3
    """Refused: the FC's queue was full."""
    SUPERSEDED = 4
    """Dropped: a newer command acted in its place before or at its time."""
    EXPIRED = 5
    """Dropped: the OBC timed out (it sent no fresh command for the timeout) before its time;
    or refused on arrival: its time was a command timeout or more before the FC took it."""


OUTCOME_MODULUS = 1 << 16
"""A command report's counts wrap at 2^16."""


@dataclass(slots=True)
class CommandReport:
    """FC → OBC command report (spec §13, E4): what became of one timed command, and when.

    Equality is the wire content; the decoder adds the unwrapped FC times and the arrival.
    """

    command_seq: int
    """`seq` of the timed command (24 bits)."""
    command_tx_time_us: int
    """Its `tx_time_us` (OBC clock, u32), echoed."""
    at_us: int
    """The FC time (u32) it asked to act at, echoed."""
    event_us: int
    """FC `micros()` (u32) of the PID iteration that applied it (applied: `ON_TIME`, `LATE`);
    else when it was refused or dropped."""
    outcome: int
    """`CommandOutcome`."""
    queued: int
    """Timed commands waiting in the FC's queue after this outcome."""
    counts: tuple[int, int, int, int, int, int]
    """Timed commands per outcome so far (`CommandOutcome` order), this one included, each
    mod 2^16: the FC's books, whole even when a report is lost."""
    at_time_us: int | None = field(default=None, compare=False)
    """`at_us` unwrapped into the state stream's 64-bit FC time (set by the decoder)."""
    event_time_us: int | None = field(default=None, compare=False)
    """`event_us` unwrapped likewise."""
    arrival_time: float | None = field(default=None, compare=False)
    """OBC clock (s) when the bytes carrying the report were read."""

    @property
    def version(self) -> int:
        return VERSION

    @property
    def applied(self) -> bool:
        """The command reached the RC path (on time or late)."""
        return self.outcome in (CommandOutcome.ON_TIME, CommandOutcome.LATE)

    @property
    def delay_us(self) -> int | None:
        """Applied: FC µs from the time it asked for to the PID iteration that applied it
        (negative: never; late: how late); None when it was not applied."""
        return self.after_us if self.applied else None

    @property
    def after_us(self) -> int:
        """FC µs from the time it asked for to its event (applied, refused or dropped): the
        signed u32 difference `event_us` − `at_us`."""
        after = (self.event_us - self.at_us) % U32_MODULUS
        return after - U32_MODULUS if after >= U32_MODULUS // 2 else after


def parse_state(payload: bytes) -> StatePacket:
    """A validated 116- or 180-byte state payload (see `framing.Deframer`) as a packet.

    The decoder's hot path: objects are filled in directly rather than through __init__.
    """
    _, seq_low, seq_high, tx_time_us = _HEADER.unpack_from(payload)
    first = _new(SensorFrame)
    first.values, first.time_us, first.obc_time = _FRAME.unpack_from(payload, 8), None, None
    second = _new(SensorFrame)
    second.values, second.time_us, second.obc_time = _FRAME.unpack_from(payload, 60), None, None
    packet = _new(StatePacket)
    if len(payload) == STATE_LENGTH:
        packet.mavlink = None
        drops, reserved2_high, _ = _TRAILER.unpack_from(payload, 112)
    else:
        packet.mavlink = payload[112:176]
        drops, reserved2_high, _ = _TRAILER.unpack_from(payload, 176)
    packet.tx_time_us = tx_time_us
    packet.frames = (first, second)
    packet.seq = seq_low | seq_high << 8
    packet.e1 = reserved2_high >= 0x80
    packet.drops = drops
    packet.time_us = packet.arrival_time = None
    packet.epoch = 0
    packet.outlier = False
    return packet


def pack_state(packet: StatePacket) -> bytes:
    """The unframed payload of `packet`, CRC included."""
    seq = packet.seq % SEQ_MODULUS
    reserved2 = (packet.drops % DROPS_MODULUS) | (E1_FLAG if packet.e1 else 0)
    frames = (*packet.frames[0].values, *packet.frames[1].values)
    try:
        if packet.mavlink is None:
            body = _STATE_BASE.pack(
                VERSION_BASE, seq & 0xFF, seq >> 8, packet.tx_time_us, *frames,
                reserved2 & 0xFFFF, reserved2 >> 16, 0,
            )  # fmt: skip
        else:
            if len(packet.mavlink) > MAVLINK_FIELD_LENGTH:
                raise ValueError(f"MAVLink tunnel field holds at most {MAVLINK_FIELD_LENGTH} bytes")
            body = _STATE_TUNNEL.pack(
                VERSION_TUNNEL, seq & 0xFF, seq >> 8, packet.tx_time_us, *frames,
                packet.mavlink, reserved2 & 0xFFFF, reserved2 >> 16, 0,
            )  # fmt: skip
    except struct.error as exc:
        raise ValueError(f"state packet field out of range: {exc}") from None
    return body[:-1] + bytes([crc8(body[:-1])])


def parse_command(payload: bytes) -> CommandPacket:
    """A validated 24-byte command payload (or 28-byte timed command, E4) as a packet."""
    if len(payload) == TIMED_COMMAND_LENGTH:
        v = _TIMED_COMMAND.unpack(payload)
        return CommandPacket(v[4:10], v[1] | v[2] << 8, v[3], v[10], v[11] | v[12] << 8)
    v = _COMMAND.unpack(payload)
    return CommandPacket(v[4:10], v[1] | v[2] << 8, v[3], None, v[10] | v[11] << 8)


def parse_arming_request(payload: bytes) -> ArmingRequest:
    """A validated 16-byte arming request payload (E5) as a packet (what the FC decodes;
    for tests: the FC also refuses non-zero reserved bytes, which this does not keep)."""
    _, seq_low, seq_high, tx_time_us, request, sender_low, sender_high, _ = _ARMING_REQUEST.unpack(
        payload
    )
    return ArmingRequest(
        ArmingAction(request), seq_low | seq_high << 8, tx_time_us, sender_low | sender_high << 8
    )


def pack_arming_request(packet: ArmingRequest) -> bytes:
    """The unframed payload of `packet`, CRC included."""
    seq = packet.seq % SEQ_MODULUS
    sender = packet.sender % SENDER_MODULUS
    try:
        body = _ARMING_REQUEST.pack(
            VERSION, seq & 0xFF, seq >> 8, packet.tx_time_us, packet.request, sender & 0xFF,
            sender >> 8, 0,
        )  # fmt: skip
    except struct.error as exc:
        raise ValueError(f"arming request field out of range: {exc}") from None
    return body[:-1] + bytes([crc8(body[:-1])])


def parse_command_report(payload: bytes) -> CommandReport:
    """A validated 32-byte command report payload (E4) as a packet."""
    _, seq_low, seq_high, command_tx, at, event, outcome, queued, *counts, _ = (
        _COMMAND_REPORT.unpack(payload)
    )
    on_time, late, too_far, queue_full, superseded, expired = counts
    return CommandReport(
        seq_low | seq_high << 8, command_tx, at, event, outcome, queued,
        (on_time, late, too_far, queue_full, superseded, expired),
    )  # fmt: skip


def pack_command_report(report: CommandReport) -> bytes:
    """The unframed payload of `report`, CRC included (what the FC sends; for tests)."""
    seq = report.command_seq % SEQ_MODULUS
    if len(report.counts) != len(CommandOutcome):
        raise ValueError(f"a command report counts {len(CommandOutcome)} outcomes")
    try:
        body = _COMMAND_REPORT.pack(
            VERSION, seq & 0xFF, seq >> 8, report.command_tx_time_us, report.at_us,
            report.event_us, report.outcome, report.queued, *report.counts, 0,
        )  # fmt: skip
    except struct.error as exc:
        raise ValueError(f"command report field out of range: {exc}") from None
    return body[:-1] + bytes([crc8(body[:-1])])


def parse_time_reply(payload: bytes) -> TimeReply:
    """A validated 20-byte time reply payload as a packet."""
    _, seq_low, seq_high, command_tx, rx, tx, _ = _TIME_REPLY.unpack(payload)
    return TimeReply(seq_low | seq_high << 8, command_tx, rx, tx)


def pack_time_reply(reply: TimeReply) -> bytes:
    """The unframed payload of `reply`, CRC included (what the FC sends; for tests)."""
    seq = reply.command_seq % SEQ_MODULUS
    try:
        body = _TIME_REPLY.pack(
            VERSION, seq & 0xFF, seq >> 8, reply.command_tx_time_us, reply.rx_time_us,
            reply.tx_time_us, 0,
        )  # fmt: skip
    except struct.error as exc:
        raise ValueError(f"time reply field out of range: {exc}") from None
    return body[:-1] + bytes([crc8(body[:-1])])


_AUTHORITY_FIELDS = (
    "authority", "exit", "proof_ms", "exit_us", "sender", "foreign", "refused",
    "msp_rc_refused", "rc_min_us", "rc_max_us",
)  # fmt: skip


def parse_uplink_status(payload: bytes) -> UplinkStatus:
    """A validated uplink status payload as a packet: 64 bytes, or 36 of firmware before
    the authority fields (which are then None)."""
    if len(payload) == UPLINK_STATUS_V1_LENGTH:
        _, seq_low, seq_high, *values, _ = _UPLINK_STATUS_V1.unpack(payload)
        return UplinkStatus(seq_low | seq_high << 8, *values)
    (
        _, seq_low, seq_high, tx_time_us, accepted, stale, timeouts, rejected, timeout_ms, flags,
        failsafe_phase, timed_out_us, authority, exit, proof_ms, exit_us, sender_low,
        sender_high, foreign, refused, msp_rc_refused, rc_min_us, rc_max_us, _,
    ) = _UPLINK_STATUS.unpack(payload)  # fmt: skip
    return UplinkStatus(
        seq_low | seq_high << 8, tx_time_us, accepted, stale, timeouts, rejected, timeout_ms,
        flags, failsafe_phase, timed_out_us, Authority(authority), AuthorityExit(exit),
        proof_ms, exit_us, sender_low | sender_high << 8, foreign, refused, msp_rc_refused,
        rc_min_us, rc_max_us,
    )  # fmt: skip


def pack_uplink_status(status: UplinkStatus) -> bytes:
    """The unframed payload of `status`, CRC included (what the FC sends; for tests): 64
    bytes, or 36 when it carries no authority fields (all None)."""
    seq = status.command_seq % SEQ_MODULUS
    common = (
        VERSION, seq & 0xFF, seq >> 8, status.tx_time_us, status.accepted, status.stale,
        status.timeouts, status.rejected, status.timeout_ms, status.flags,
        status.failsafe_phase, status.timed_out_us,
    )  # fmt: skip
    given = [name for name in _AUTHORITY_FIELDS if getattr(status, name) is not None]
    try:
        if not given:
            body = _UPLINK_STATUS_V1.pack(*common, 0)
        elif len(given) < len(_AUTHORITY_FIELDS):
            missing = sorted(set(_AUTHORITY_FIELDS) - set(given))
            raise ValueError(f"an uplink status with authority fields has them all: no {missing}")
        else:
            sender = status.sender % SENDER_MODULUS  # type: ignore[operator]
            body = _UPLINK_STATUS.pack(
                *common, status.authority, status.exit, status.proof_ms, status.exit_us,
                sender & 0xFF, sender >> 8, status.foreign, status.refused,
                status.msp_rc_refused, status.rc_min_us, status.rc_max_us, 0,
            )  # fmt: skip
    except struct.error as exc:
        raise ValueError(f"uplink status field out of range: {exc}") from None
    return body[:-1] + bytes([crc8(body[:-1])])


def pack_command(packet: CommandPacket) -> bytes:
    """The unframed payload of `packet`, CRC included."""
    seq = packet.seq % SEQ_MODULUS
    if len(packet.rc) != len(RC_CHANNELS):
        raise ValueError(f"a command carries {len(RC_CHANNELS)} RC values: {RC_CHANNELS}")
    sender = packet.sender % SENDER_MODULUS
    header = (VERSION, seq & 0xFF, seq >> 8, packet.tx_time_us, *packet.rc)
    try:
        if packet.at_us is None:
            body = _COMMAND.pack(*header, sender & 0xFF, sender >> 8, 0)
        else:
            body = _TIMED_COMMAND.pack(*header, packet.at_us, sender & 0xFF, sender >> 8, 0)
    except struct.error as exc:
        raise ValueError(f"command packet field out of range: {exc}") from None
    return body[:-1] + bytes([crc8(body[:-1])])
