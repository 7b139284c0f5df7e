"""MSP (MultiWii Serial Protocol) client for Betaflight: framing plus the typed calls wftool needs.

Framing follows Betaflight's `msp_serial.c`: v1 (`$M`, XOR checksum, jumbo frames for
payloads ≥ 255 bytes) and v2 native (`$X`, CRC-8/DVB-S2). A reply with `!` instead of `>`
is the FC saying "unknown command or bad arguments". Payload layouts are those of
`msp.c` in Betaflight 2025.12.
"""

from __future__ import annotations

import enum
import statistics
import struct
import time
from collections.abc import Sequence
from dataclasses import dataclass

from wftool.errors import MspError
from wftool.fc.modes import AuxRange, parse_mode_ranges
from wftool.link.crc import DVB_S2_INIT, crc8
from wftool.link.transport import Port, open_port, port_errors, read_size


class MspVersion(enum.IntEnum):
    V1 = 1
    V2 = 2


class Cmd(enum.IntEnum):
    """The MSP command ids used here (`msp_protocol.h`)."""

    API_VERSION = 1
    FC_VARIANT = 2
    FC_VERSION = 3
    BOARD_INFO = 4
    BUILD_INFO = 5
    MODE_RANGES = 34
    FEATURE_CONFIG = 36
    SET_FEATURE_CONFIG = 37
    RX_CONFIG = 44
    RX_MAP = 64
    REBOOT = 68
    FAILSAFE_CONFIG = 75
    STATUS = 101
    RAW_IMU = 102
    RC = 105
    ATTITUDE = 108
    ANALOG = 110
    BOXIDS = 119
    STATUS_EX = 150
    SET_RAW_RC = 200


class RebootMode(enum.IntEnum):
    """Payload of MSP_REBOOT (`msp.c`: MSP_REBOOT_*)."""

    FIRMWARE = 0
    BOOTLOADER_ROM = 1
    MSC = 2
    MSC_UTC = 3
    BOOTLOADER_FLASH = 4


CAPABILITY_VCP = 1 << 0
CAPABILITY_SOFTSERIAL = 1 << 1
CAPABILITY_FLASH_BOOTLOADER = 1 << 3
CAPABILITY_RX_BIND = 1 << 6

FEATURE_RX_PPM = 1 << 0
FEATURE_RX_UDP = 1 << 1
"""The virtual FC's simulated radio (the SITL's RC input; SITL only)."""
FEATURE_RX_SERIAL = 1 << 3
FEATURE_RX_PARALLEL_PWM = 1 << 13
FEATURE_RX_MSP = 1 << 14
FEATURE_RX_SPI = 1 << 25
RECEIVER_FEATURES = (
    FEATURE_RX_PPM
    | FEATURE_RX_UDP
    | FEATURE_RX_SERIAL
    | FEATURE_RX_PARALLEL_PWM
    | FEATURE_RX_MSP
    | FEATURE_RX_SPI
)
"""Betaflight enables exactly one of these at boot (`validateAndFixConfig`)."""


class ArmingDisabled(enum.IntFlag):
    """Betaflight's arming disable flags (`armingDisableFlags_e`, runtime_config.h), those
    wftool names; the rest keep their bits, unnamed. ARM_SWITCH is always the FC's last flag,
    whose bit moves between versions (28 on 2025.12, 29 on 2026.6): `parse_status_ex` puts
    it at bit 31, which no version has used."""

    FAILSAFE = 1 << 1
    RX_FAILSAFE = 1 << 2
    """The receiver has no signal (the OSD's RXLOSS)."""
    CLI = 1 << 13
    MSP = 1 << 16
    ARM_SWITCH = 1 << 31
    """The ARM switch was on while arming was disabled: it must go off first."""


FAILSAFE_PROCEDURE_NAMES = ("AUTO-LAND", "DROP", "GPS-RESCUE")
"""`failsafe_procedure` by value (failsafeProcedure_e), as the CLI spells them."""

_JUMBO_SIZE = 255


def crc8_dvb_s2(data: bytes) -> int:
    """CRC-8/DVB-S2, the MSP v2 checksum: FSP's CRC-8 (poly 0xD5) from init 0x00."""
    return crc8(data, DVB_S2_INIT)


def _xor(data: bytes) -> int:
    checksum = 0
    for byte in data:
        checksum ^= byte
    return checksum


def encode_request(cmd: int, payload: bytes = b"", version: MspVersion = MspVersion.V2) -> bytes:
    """One request frame ('<' direction) ready to write to the FC."""
    if version is MspVersion.V1:
        if cmd > 0xFF or len(payload) >= _JUMBO_SIZE:
            raise ValueError(f"MSP v1 cannot carry command {cmd} with {len(payload)} bytes")
        body = bytes([len(payload), cmd]) + payload
        return b"$M<" + body + bytes([_xor(body)])
    body = struct.pack("<BHH", 0, cmd, len(payload)) + payload
    return b"$X<" + body + bytes([crc8_dvb_s2(body)])


@dataclass(frozen=True)
class MspFrame:
    """A decoded frame. `error` is set for `$M!`/`$X!` replies."""

    cmd: int
    payload: bytes
    error: bool
    request: bool = False
    """`$M<`/`$X<`: a request (on a link that echoes, our own), never a reply from the FC."""


def decode_frame(buffer: bytes) -> tuple[MspFrame | None, int]:
    """Decode the first frame in `buffer`: (frame or None if incomplete, bytes consumed).

    Bytes before a `$` (CLI leftovers, line noise) are consumed and dropped. A frame whose
    checksum does not match raises `MspError`.
    """
    start = buffer.find(b"$")
    if start < 0:
        return None, len(buffer)
    frame = buffer[start:]
    if len(frame) < 3:
        return None, start
    magic, direction = frame[1:2], frame[2:3]
    if magic not in (b"M", b"X") or direction not in (b">", b"!", b"<"):
        return None, start + 1  # a stray '$': resynchronise on the next one
    if magic == b"M":
        if len(frame) < 5:
            return None, start
        size, cmd = frame[3], frame[4]
        header = 5
        if size == _JUMBO_SIZE:
            if len(frame) < 7:
                return None, start
            size = struct.unpack_from("<H", frame, 5)[0]
            header = 7
        end = header + size
        if len(frame) < end + 1:
            return None, start
        if _xor(frame[3:end]) != frame[end]:
            raise MspError(f"MSP v1 checksum mismatch in frame for command {cmd}")
    else:
        if len(frame) < 8:
            return None, start
        _flags, cmd, size = struct.unpack_from("<BHH", frame, 3)
        header = 8
        end = header + size
        if len(frame) < end + 1:
            return None, start
        if crc8_dvb_s2(frame[3:end]) != frame[end]:
            raise MspError(f"MSP v2 CRC mismatch in frame for command {cmd}")
    decoded = MspFrame(cmd, bytes(frame[header:end]), direction == b"!", direction == b"<")
    return decoded, start + end + 1


class FrameReader:
    """The frames in a byte stream that arrives in pieces (a poller's reads, a recording).

    Bytes between frames are dropped; a frame whose checksum fails is counted in
    `corrupt` and skipped, and reading goes on from the next `$`. Requests (`<`: a link
    that echoes) are no replies: counted in `requests` and skipped.
    """

    def __init__(self) -> None:
        self._rx = bytearray()
        self.corrupt = 0
        self.requests = 0

    def feed(self, data: bytes) -> list[MspFrame]:
        """The frames `data` completes, in order."""
        rx = self._rx
        rx += data
        frames: list[MspFrame] = []
        while True:
            try:
                frame, used = decode_frame(bytes(rx))
            except MspError:
                self.corrupt += 1
                del rx[: rx.find(b"$") + 1]  # past the bad frame's start
                continue
            del rx[:used]
            if frame is None:
                return frames
            if frame.request:
                self.requests += 1
                continue
            frames.append(frame)


class _Fields:
    """Sequential little-endian reader over a reply payload; short payloads raise MspError."""

    def __init__(self, cmd: Cmd, payload: bytes) -> None:
        self._cmd, self._payload, self._offset = cmd, payload, 0

    def _take(self, size: int) -> bytes:
        if self._offset + size > len(self._payload):
            raise MspError(f"{self._cmd.name} reply too short ({len(self._payload)} bytes)")
        chunk = self._payload[self._offset : self._offset + size]
        self._offset += size
        return chunk

    def unpack(self, fmt: str) -> tuple[int, ...]:
        return struct.unpack("<" + fmt, self._take(struct.calcsize("<" + fmt)))

    def u8(self) -> int:
        return self.unpack("B")[0]

    def data(self, size: int) -> bytes:
        return self._take(size)

    def text(self, size: int) -> str:
        return self._take(size).decode("ascii", "replace").rstrip("\0")

    def pstring(self) -> str:
        """A length-prefixed string (`sbufWritePString`)."""
        return self.text(self.u8())


@dataclass(frozen=True)
class ApiVersion:
    protocol: int
    major: int
    minor: int

    def __str__(self) -> str:
        return f"{self.major}.{self.minor}"


@dataclass(frozen=True)
class BoardInfo:
    """MSP_BOARD_INFO. `target_name` is the MCU target (e.g. STM32F722), `board_name` the
    board (e.g. SPEEDYBEEF7V3, empty on SITL)."""

    board_identifier: str
    hardware_revision: int
    capabilities: int
    target_name: str
    board_name: str
    manufacturer_id: str
    mcu_type_id: int

    @property
    def has_flash_bootloader(self) -> bool:
        return bool(self.capabilities & CAPABILITY_FLASH_BOOTLOADER)


@dataclass(frozen=True)
class BuildInfo:
    """MSP_BUILD_INFO: the firmware's `__DATE__`, `__TIME__` and 7-digit git revision."""

    date: str
    time: str
    git_revision: str


@dataclass(frozen=True)
class RawImu:
    """MSP_RAW_IMU: accelerometer (raw ADC), gyro (deg/s), magnetometer (raw ADC)."""

    acc: tuple[int, int, int]
    gyro: tuple[int, int, int]
    mag: tuple[int, int, int]


@dataclass(frozen=True)
class Attitude:
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


@dataclass(frozen=True)
class Analog:
    """MSP_ANALOG, converted to SI units."""

    voltage_v: float
    mah_drawn: int
    rssi: int
    """0–1023."""
    current_a: float


@dataclass(frozen=True)
class FcIdentity:
    """Everything `wftool` needs to know which firmware a board runs."""

    variant: str
    version: str
    api: ApiVersion
    board: BoardInfo
    build: BuildInfo


@dataclass(frozen=True)
class FcStatus:
    """MSP_STATUS_EX: which modes are on, and what keeps the FC from arming."""

    boxes: int
    """The active-mode bits, in the order of the FC's MSP_BOXIDS (`mode_bits`)."""
    arming_disabled: ArmingDisabled

    def active(self, bit: int | None) -> bool:
        """Whether the mode at `bit` (`mode_bits`; None: the FC has no such mode) is on."""
        return bit is not None and bool(self.boxes >> bit & 1)


@dataclass(frozen=True)
class FailsafeConfig:
    """MSP_FAILSAFE_CONFIG (failsafe.h's settings; times in ms)."""

    delay_ms: int
    """`failsafe_delay`: RX loss to stage 2."""
    landing_time_s: int
    throttle: int
    switch_mode: int
    throttle_low_delay_ms: int
    procedure: int
    """`failsafe_procedure` (`FAILSAFE_PROCEDURE_NAMES`)."""

    @property
    def procedure_name(self) -> str:
        names = FAILSAFE_PROCEDURE_NAMES
        return names[self.procedure] if self.procedure < len(names) else str(self.procedure)


@dataclass(frozen=True)
class RxConfig:
    """What wftool reads of MSP_RX_CONFIG: the FC's valid pulse range."""

    min_us: int
    """`rx_min_usec`."""
    max_us: int
    """`rx_max_usec`."""


PID_PERIOD_SAMPLES = 200
"""MSP_STATUS reads `pid_looptime_us` averages: ±0.05 µs for a loop of a fractional period
(0.2 s at a 1 kHz serial task, 2 s at Betaflight's default 100 Hz)."""


class MspClient:
    """Request/reply MSP over an open link. One request in flight at a time."""

    def __init__(
        self,
        link: Port,
        *,
        version: MspVersion = MspVersion.V2,
        timeout: float = 1.0,
    ) -> None:
        self.link = link
        self.version = version
        self.timeout = timeout
        self._rx = bytearray()

    @classmethod
    def open(
        cls, url: str, *, version: MspVersion = MspVersion.V2, timeout: float = 1.0
    ) -> MspClient:
        """Open `url` (see `wftool.link.transport.open_port`) and talk MSP on it."""
        return cls(open_port(url, timeout=0.05), version=version, timeout=timeout)

    def close(self) -> None:
        self.link.close()

    def __enter__(self) -> MspClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def request(self, cmd: int, payload: bytes = b"", timeout: float | None = None) -> bytes:
        """Send one command and return its reply payload.

        Frames for other commands (late replies to an earlier timed-out request) are skipped,
        and so are requests (a link that echoes what it gets): a reply comes from the FC.
        """
        name = _command_name(cmd)
        url = self.link.port or "link"
        with port_errors(url):
            self._rx.clear()
            self.link.reset_input_buffer()
            self.link.write(encode_request(cmd, payload, self.version))
            deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
            while True:
                frame, used = decode_frame(bytes(self._rx))
                del self._rx[:used]
                if frame is not None:
                    if frame.request or frame.cmd != cmd:
                        continue
                    if frame.error:
                        raise MspError(f"the FC answered {name} with an error reply")
                    return frame.payload
                if time.monotonic() > deadline:
                    raise MspError(f"no MSP reply to {name} from {url}")
                self._rx += self.link.read(read_size(self.link))

    def api_version(self) -> ApiVersion:
        return ApiVersion(*_Fields(Cmd.API_VERSION, self.request(Cmd.API_VERSION)).unpack("BBB"))

    def fc_variant(self) -> str:
        """Four letters: BTFL for Betaflight."""
        return _Fields(Cmd.FC_VARIANT, self.request(Cmd.FC_VARIANT)).text(4)

    def fc_version(self) -> str:
        """The firmware version string, e.g. "2025.12.5"."""
        fields = _Fields(Cmd.FC_VERSION, self.request(Cmd.FC_VERSION))
        fields.unpack("BBB")  # year-2000, month, patch: the string below says the same
        return fields.pstring()

    def board_info(self) -> BoardInfo:
        fields = _Fields(Cmd.BOARD_INFO, self.request(Cmd.BOARD_INFO))
        identifier = fields.text(4)
        hardware_revision, _fc_type, capabilities = fields.unpack("HBB")
        target_name, board_name, manufacturer_id = (fields.pstring() for _ in range(3))
        fields.text(32)  # signature
        return BoardInfo(
            board_identifier=identifier,
            hardware_revision=hardware_revision,
            capabilities=capabilities,
            target_name=target_name,
            board_name=board_name,
            manufacturer_id=manufacturer_id,
            mcu_type_id=fields.u8(),
        )

    def build_info(self) -> BuildInfo:
        fields = _Fields(Cmd.BUILD_INFO, self.request(Cmd.BUILD_INFO))
        return BuildInfo(date=fields.text(11), time=fields.text(8), git_revision=fields.text(7))

    def identify(self) -> FcIdentity:
        return FcIdentity(
            variant=self.fc_variant(),
            version=self.fc_version(),
            api=self.api_version(),
            board=self.board_info(),
            build=self.build_info(),
        )

    def reboot(self, mode: RebootMode = RebootMode.FIRMWARE) -> None:
        """Ask the FC to reboot; it acknowledges first, then resets and the link drops.

        Modes the firmware lacks (MSC without USB mass storage) get an error reply.
        """
        acknowledged = self.request(Cmd.REBOOT, bytes([mode]))
        if acknowledged[:1] != bytes([mode]):
            raise MspError(f"the FC did not acknowledge reboot mode {mode.name}")

    def raw_imu(self) -> RawImu:
        return parse_raw_imu(self.request(Cmd.RAW_IMU))

    def attitude(self) -> Attitude:
        return parse_attitude(self.request(Cmd.ATTITUDE))

    def rc(self) -> tuple[int, ...]:
        """The RC channel values the FC currently uses (µs), in its channel order."""
        return parse_rc(self.request(Cmd.RC))

    def set_raw_rc(self, channels: Sequence[int]) -> None:
        """Feed RC channels through the MSP receiver (effective only with RX_MSP enabled)."""
        self.request(Cmd.SET_RAW_RC, struct.pack(f"<{len(channels)}H", *channels))

    def analog(self) -> Analog:
        return parse_analog(self.request(Cmd.ANALOG))

    def pid_cycle_us(self) -> int:
        """The PID loop period the FC measures (MSP_STATUS); 0 while the loop does not run."""
        return _Fields(Cmd.STATUS, self.request(Cmd.STATUS)).unpack("H")[0]

    def pid_looptime_us(self, samples: int = PID_PERIOD_SAMPLES) -> float:
        """The PID loop's mean period: `pid_cycle_us` (only the latest period, in whole µs as
        the FC's timer truncates it: 317 or 318 for a 3148 Hz loop) averaged over `samples`
        reads, those more than 5 % (at least 1 µs) from their median left out (a period a
        late run stretched is not the loop's); `MspError` if the loop does not run."""
        periods = [self.pid_cycle_us() for _ in range(samples)]
        median = statistics.median(periods)
        if median == 0:
            raise MspError(
                f"the FC on {self.link.port or 'its link'} reports no PID loop running "
                "(cycle time 0 in MSP_STATUS): its frame rate cannot be known"
            )
        band = max(1.0, 0.05 * median)
        return statistics.fmean(period for period in periods if abs(period - median) <= band)

    def status_ex(self, timeout: float | None = None) -> FcStatus:
        return parse_status_ex(self.request(Cmd.STATUS_EX, timeout=timeout))

    def mode_bits(self) -> dict[int, int]:
        """Permanent mode id → its bit in `FcStatus.boxes`, for the modes this FC has
        (MSP_BOXIDS)."""
        return {mode: bit for bit, mode in enumerate(self.request(Cmd.BOXIDS))}

    def mode_ranges(self) -> list[AuxRange]:
        """Every mode range slot, used or not (MSP_MODE_RANGES)."""
        return parse_mode_ranges(self.request(Cmd.MODE_RANGES))

    def failsafe_config(self) -> FailsafeConfig:
        fields = _Fields(Cmd.FAILSAFE_CONFIG, self.request(Cmd.FAILSAFE_CONFIG))
        delay, landing, throttle, switch, low_delay, procedure = fields.unpack("BBHBHB")
        return FailsafeConfig(delay * 100, landing, throttle, switch, low_delay * 100, procedure)

    def rx_config(self) -> RxConfig:
        fields = _Fields(Cmd.RX_CONFIG, self.request(Cmd.RX_CONFIG))
        fields.unpack("BHHHB")  # provider, maxcheck, midrc, mincheck, spektrum_sat_bind
        return RxConfig(*fields.unpack("HH"))

    def features(self) -> int:
        """The configured feature bit mask (takes effect at boot)."""
        return _Fields(Cmd.FEATURE_CONFIG, self.request(Cmd.FEATURE_CONFIG)).unpack("I")[0]

    def set_features(self, mask: int) -> None:
        """Replace the configured feature mask in RAM (persisted by the next CLI `save`)."""
        self.request(Cmd.SET_FEATURE_CONFIG, struct.pack("<I", mask))


# The replies a poller receives on its own (`wftool.fc.msp_poller`) are parsed here too.


def parse_raw_imu(payload: bytes) -> RawImu:
    values = _Fields(Cmd.RAW_IMU, payload).unpack("9h")
    return RawImu(acc=values[0:3], gyro=values[3:6], mag=values[6:9])  # type: ignore[arg-type]


def parse_attitude(payload: bytes) -> Attitude:
    roll, pitch, yaw = _Fields(Cmd.ATTITUDE, payload).unpack("hhh")
    return Attitude(roll_deg=roll / 10, pitch_deg=pitch / 10, yaw_deg=float(yaw))


def parse_rc(payload: bytes) -> tuple[int, ...]:
    return _Fields(Cmd.RC, payload).unpack(f"{len(payload) // 2}H")


def parse_status_ex(payload: bytes) -> FcStatus:
    """MSP_STATUS_EX: the first 32 mode bits at 6, the count of further bytes at 15 and
    those bytes, then the count of arming disable flags and their u32 (the last of them, the
    ARM switch's, at `ArmingDisabled.ARM_SWITCH`)."""
    fields = _Fields(Cmd.STATUS_EX, payload)
    fields.unpack("HHH")  # cycle time, I2C errors, sensors
    (boxes,) = fields.unpack("I")
    fields.unpack("BHBB")  # PID profile, load, profile count, rate profile
    extra = fields.u8()
    boxes |= int.from_bytes(fields.data(extra), "little") << 32
    count = fields.u8()
    (arming,) = fields.unpack("I")
    last = 1 << (count - 1) if 0 < count < 32 else 0  # ARMING_DISABLED_ARM_SWITCH
    switch = ArmingDisabled.ARM_SWITCH if arming & last else 0
    return FcStatus(boxes, ArmingDisabled(arming & ~last | switch))


def parse_analog(payload: bytes) -> Analog:
    _legacy_vbat, mah_drawn, rssi, centiamps, centivolts = _Fields(Cmd.ANALOG, payload).unpack(
        "BHHhH"
    )
    return Analog(
        voltage_v=centivolts / 100, mah_drawn=mah_drawn, rssi=rssi, current_a=centiamps / 100
    )


def _command_name(cmd: int) -> str:
    try:
        return f"MSP_{Cmd(cmd).name}"
    except ValueError:
        return f"MSP command {cmd}"
