"""MSP framing (v1, v2, jumbo, errors) and the typed calls against the real SITL."""

from __future__ import annotations

import socket
import struct
import time
import types

import pytest

from wftool.errors import MspError
from wftool.fc.msp import (
    FEATURE_RX_MSP,
    ArmingDisabled,
    Cmd,
    FrameReader,
    MspClient,
    MspVersion,
    RebootMode,
    crc8_dvb_s2,
    decode_frame,
    encode_request,
    parse_status_ex,
)
from wftool.sitl.process import VirtualFC


def test_crc8_dvb_s2_check_value() -> None:
    # The catalogue check value of CRC-8/DVB-S2 (poly 0xD5, init 0) over "123456789".
    assert crc8_dvb_s2(b"123456789") == 0xBC


def test_v1_request_matches_the_classic_hand_written_frame() -> None:
    # MSP_API_VERSION as every MSP tool sends it: $M< size=0 cmd=1 checksum=1.
    assert encode_request(Cmd.API_VERSION, version=MspVersion.V1) == b"$M<\x00\x01\x01"


def test_v2_request_layout() -> None:
    frame = encode_request(0x1234, b"\xaa", MspVersion.V2)
    assert frame[:3] == b"$X<"
    assert struct.unpack("<BHH", frame[3:8]) == (0, 0x1234, 1)
    assert frame[8] == 0xAA
    assert frame[9] == crc8_dvb_s2(frame[3:9])


def _v1_reply(cmd: int, payload: bytes, direction: bytes = b">") -> bytes:
    size = (
        bytes([len(payload)]) if len(payload) < 255 else b"\xff" + struct.pack("<H", len(payload))
    )
    body = size[:1] + bytes([cmd]) + size[1:] + payload
    checksum = 0
    for byte in body:
        checksum ^= byte
    return b"$M" + direction + body + bytes([checksum])


def test_decode_skips_noise_and_reads_a_jumbo_frame() -> None:
    payload = bytes(range(256)) * 2
    frame, used = decode_frame(b"\r\n# junk" + _v1_reply(116, payload) + b"$M>")
    assert frame is not None
    assert (frame.cmd, frame.payload, frame.error) == (116, payload, False)
    assert used == len(b"\r\n# junk") + len(_v1_reply(116, payload))


def test_decode_reports_incomplete_frames_without_consuming_them() -> None:
    whole = _v1_reply(1, b"\x00\x01\x2f")
    assert decode_frame(whole[:-1]) == (None, 0)


def test_decode_error_reply() -> None:
    frame, _ = decode_frame(_v1_reply(250, b"", b"!"))
    assert frame is not None and frame.error


def test_decode_rejects_bad_checksums() -> None:
    good = _v1_reply(1, b"\x00\x01\x2f")
    with pytest.raises(MspError, match="checksum"):
        decode_frame(good[:-1] + bytes([good[-1] ^ 0xFF]))
    v2 = b"$X>" + struct.pack("<BHH", 0, 1, 1) + b"\x05"
    with pytest.raises(MspError, match="CRC"):
        decode_frame(v2 + bytes([crc8_dvb_s2(v2[3:]) ^ 1]))


ECHO = "loop://"
"""pyserial's loopback: every byte written comes back, as on a link that echoes (no FC)."""


@pytest.mark.parametrize("version", [MspVersion.V1, MspVersion.V2])
def test_a_request_is_no_reply(version: MspVersion) -> None:
    request = encode_request(Cmd.REBOOT, b"\x00", version)
    frame, used = decode_frame(request)
    assert frame is not None and frame.request and used == len(request)
    reply = _v1_reply(Cmd.REBOOT, b"\x00")
    frames = FrameReader().feed(request + reply + request)
    assert [(f.cmd, f.payload, f.request) for f in frames] == [(Cmd.REBOOT, b"\x00", False)]


@pytest.mark.parametrize("version", [MspVersion.V1, MspVersion.V2])
def test_an_echoing_link_answers_nothing(version: MspVersion) -> None:
    with MspClient.open(ECHO, version=version, timeout=0.2) as msp:
        calls = {
            "MSP_API_VERSION": msp.api_version,
            "MSP_REBOOT": msp.reboot,
            "MSP_SET_FEATURE_CONFIG": lambda: msp.set_features(FEATURE_RX_MSP),
            "MSP_SET_RAW_RC": lambda: msp.set_raw_rc([1500] * 8),
        }
        outcomes = {}
        for name, call in calls.items():
            try:
                call()
                outcomes[name] = "answered"
            except MspError as exc:
                outcomes[name] = str(exc).removesuffix(f" from {ECHO}")
    assert outcomes == {name: f"no MSP reply to {name}" for name in calls}


def test_a_silent_peer_times_out() -> None:
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        with MspClient.open(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.3) as msp:
            started = time.monotonic()
            with pytest.raises(MspError, match="no MSP reply to MSP_API_VERSION"):
                msp.api_version()
            assert 0.3 <= time.monotonic() - started < 2


class ScriptedStatus(MspClient):
    """An MSP client whose MSP_STATUS reads give `cycles` in turn (no link)."""

    def __init__(self, cycles: list[int]) -> None:
        self._cycles = iter(cycles)
        self.link = types.SimpleNamespace(port="scripted")  # type: ignore[assignment]

    def pid_cycle_us(self) -> int:
        return next(self._cycles)


def test_a_loop_that_does_not_run_has_no_looptime() -> None:
    with pytest.raises(MspError, match="reports no PID loop running"):
        ScriptedStatus([0, 0, 0, 0, 0, 125, 125, 125, 125]).pid_looptime_us(9)


@pytest.mark.parametrize("version", [MspVersion.V1, MspVersion.V2])
def test_identify_sitl(virtual_fc: VirtualFC, version: MspVersion) -> None:
    with MspClient.open(virtual_fc.url, version=version) as msp:
        fc = msp.identify()
    assert fc.variant == "BTFL"
    assert fc.version == "2026.6.1"
    assert (fc.api.major, fc.api.minor) == (1, 48)
    assert fc.board.board_identifier == "SITL"
    assert fc.board.target_name == "SITL"
    assert not fc.board.has_flash_bootloader
    assert len(fc.build.git_revision) == 7
    time.strptime(f"{fc.build.date} {fc.build.time}", "%b %d %Y %H:%M:%S")


def test_unknown_command_gets_an_error_reply(virtual_fc: VirtualFC) -> None:
    with MspClient.open(virtual_fc.url) as msp:
        with pytest.raises(MspError, match="error reply"):
            msp.request(0x3FFF)
        assert msp.fc_variant() == "BTFL"  # the link is still in step


def test_sensor_and_state_replies_have_their_shapes(virtual_fc: VirtualFC) -> None:
    with MspClient.open(virtual_fc.url) as msp:
        imu = msp.raw_imu()
        attitude = msp.attitude()
        analog = msp.analog()
        rc = msp.rc()
    assert len(imu.acc) == len(imu.gyro) == len(imu.mag) == 3
    assert -180 <= attitude.roll_deg <= 180 and 0 <= attitude.yaw_deg <= 360
    assert analog.voltage_v >= 0 and 0 <= analog.rssi <= 1023
    assert len(rc) >= 8 and all(800 <= value <= 2200 for value in rc)


def status_ex(boxes: int, arming: int, extra_boxes: bytes = b"", flags: int = 29) -> bytes:
    """An MSP_STATUS_EX payload as Betaflight's msp.c writes it (2025.12: 29 arming disable
    flags; 2026.6: 30)."""
    head = struct.pack("<HHHIBHBB", 125, 0, 0x21, boxes & 0xFFFFFFFF, 0, 5, 4, 0)
    tail = struct.pack("<IBH", arming, 0, 0)
    return head + bytes([len(extra_boxes)]) + extra_boxes + bytes([flags]) + tail


def test_status_ex_modes_past_32_and_the_arming_flags() -> None:
    status = parse_status_ex(status_ex(0x10001, 1 << 2 | 1 << 28, b"\x02"))
    assert status.boxes == 0x10001 | 0x2 << 32
    assert status.active(0) and status.active(33) and not status.active(1)
    assert not status.active(None)  # a mode the FC does not have
    assert status.arming_disabled == ArmingDisabled.RX_FAILSAFE | ArmingDisabled.ARM_SWITCH
    # 2026.6 put AUTOPILOT_SW at 28: the ARM switch is its last flag, 29
    status = parse_status_ex(status_ex(0, 1 << 2 | 1 << 29, flags=30))
    assert status.arming_disabled == ArmingDisabled.RX_FAILSAFE | ArmingDisabled.ARM_SWITCH
    status = parse_status_ex(status_ex(0, 1 << 28, flags=30))
    assert status.arming_disabled & ~ArmingDisabled.ARM_SWITCH  # AUTOPILOT_SW: a blocker
    with pytest.raises(MspError, match="STATUS_EX reply too short"):
        parse_status_ex(status_ex(0, 0)[:18])


def test_the_configuration_replies_of_a_fresh_fc(virtual_fc: VirtualFC) -> None:
    with MspClient.open(virtual_fc.url) as msp:
        bits = msp.mode_bits()
        status = msp.status_ex()
        ranges = msp.mode_ranges()
        failsafe = msp.failsafe_config()
        rx = msp.rx_config()
    assert bits[0] == 0  # ARM is always the first mode
    assert not status.active(bits[0]) and ArmingDisabled.RX_FAILSAFE in status.arming_disabled
    assert len(ranges) == 20 and not any(r.usable for r in ranges)
    assert (failsafe.delay_ms, failsafe.procedure_name) == (1500, "DROP")
    assert (rx.min_us, rx.max_us) == (885, 2115)


def test_set_raw_rc_drives_the_msp_receiver(virtual_fc: VirtualFC) -> None:
    # SITL's default receiver is RX_MSP; channels arrive AETR and the FC keeps them AERT.
    with MspClient.open(virtual_fc.url) as msp:
        assert msp.features() & FEATURE_RX_MSP
        for _ in range(5):
            msp.set_raw_rc([1234, 1600, 1100, 1700, 1000, 2000, 1500, 1500])
            time.sleep(0.05)
        assert msp.rc()[:6] == (1234, 1600, 1700, 1100, 1000, 2000)


def test_reboot_to_bootloader_resets_sitl(virtual_fc: VirtualFC) -> None:
    with MspClient.open(virtual_fc.url) as msp:
        msp.reboot(RebootMode.BOOTLOADER_ROM)
    assert virtual_fc._process is not None
    assert virtual_fc._process.wait(5) == 0
    assert b"[system]ResetToBootloader!" in virtual_fc.log_path.read_bytes()


def test_reboot_mode_the_firmware_lacks_is_refused(virtual_fc: VirtualFC) -> None:
    with MspClient.open(virtual_fc.url) as msp, pytest.raises(MspError, match="MSP_REBOOT"):
        msp.reboot(RebootMode.MSC)  # SITL has no USB mass storage


def test_the_pid_looptime_is_the_mean_of_the_usual_readings(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """317 and 318 µs readings of a 317.662 µs loop (3148 Hz) average to its period; a reading
    of a loop that stalled once is not one of them."""
    readings = iter([318, 317, 318, 318, 317, 318] * 10 + [2000, 0])
    monkeypatch.setattr(MspClient, "pid_cycle_us", lambda self: next(readings))
    client = MspClient.__new__(MspClient)  # no link: only the readings above
    assert client.pid_looptime_us(62) == pytest.approx((318 * 4 + 317 * 2) / 6)
