"""Packet models and layouts: the uplink status of both firmware generations, who flies, the
sender in every uplink packet."""

from __future__ import annotations

import pytest

from wftool.fsp import (
    ArmingAction,
    ArmingRequest,
    Authority,
    AuthorityExit,
    CommandPacket,
    UplinkFlag,
    UplinkStatus,
)
from wftool.fsp.packets import (
    ARMING_REQUEST_LENGTH,
    COMMAND_LENGTH,
    TIMED_COMMAND_LENGTH,
    UPLINK_STATUS_LENGTH,
    UPLINK_STATUS_V1_LENGTH,
    pack_arming_request,
    pack_command,
    pack_uplink_status,
    parse_arming_request,
    parse_command,
    parse_uplink_status,
)

LIVE_ARMED = UplinkFlag.LIVE | UplinkFlag.OVERRIDE | UplinkFlag.ARMED


def status(flags: int = LIVE_ARMED, **authority: object) -> UplinkStatus:
    return UplinkStatus(1234, 2_100_000, 1233, 1, 0, 2, 50, flags, 0, 0, **authority)


ENGAGED = dict(
    authority=Authority.ENGAGED, exit=AuthorityExit.SWITCH_OFF, proof_ms=500, exit_us=1_900_000,
    sender=0x5A17C3, foreign=3, refused=1, msp_rc_refused=7, rc_min_us=885, rc_max_us=2115,
)  # fmt: skip


def test_a_status_with_who_flies_is_64_bytes_at_the_spec_offsets():
    payload = pack_uplink_status(status(**ENGAGED))
    assert len(payload) == UPLINK_STATUS_LENGTH
    assert payload[26] == 0b10011 and payload[32:34] == bytes([3, 2])
    assert payload[34:36] == (500).to_bytes(2, "little")
    assert payload[36:40] == (1_900_000).to_bytes(4, "little")
    assert payload[40:44] == bytes([0xC3, 0x17, 0x5A, 0])
    assert payload[44:56] == bytes([3, 0, 0, 0, 1, 0, 0, 0, 7, 0, 0, 0])
    assert payload[56:63] == bytes([0x75, 0x03, 0x43, 0x08, 0, 0, 0])
    decoded = parse_uplink_status(payload)
    assert decoded == status(**ENGAGED)
    assert decoded.authority is Authority.ENGAGED and decoded.exit is AuthorityExit.SWITCH_OFF
    assert decoded.reports_authority and decoded.steering is True
    assert decoded.pulse_range == (885, 2115)


def test_the_arm_switch_the_fc_holds_is_flag_bit_5():
    held = UplinkFlag.LIVE | UplinkFlag.OBC_RECEIVER | UplinkFlag.ARM_SWITCH
    decoded = parse_uplink_status(pack_uplink_status(status(held, **ENGAGED)))
    assert decoded.flags == 0b100101
    assert decoded.has(UplinkFlag.ARM_SWITCH) and not decoded.has(UplinkFlag.ARMED)


def test_a_status_of_older_firmware_says_nothing_of_who_flies():
    payload = pack_uplink_status(status())
    assert len(payload) == UPLINK_STATUS_V1_LENGTH
    decoded = parse_uplink_status(payload)
    assert decoded == status()
    assert (decoded.authority, decoded.exit, decoded.sender, decoded.pulse_range) == (None,) * 4
    assert not decoded.reports_authority and decoded.steering is None


def test_a_status_carries_the_authority_fields_all_or_none():
    with pytest.raises(ValueError, match="has them all"):
        pack_uplink_status(status(authority=Authority.PILOT))


@pytest.mark.parametrize(
    ("authority", "steers"),
    [
        (Authority.PILOT, False),
        (Authority.PROVING, False),
        (Authority.READY, False),
        (Authority.ENGAGED, True),
        (Authority.RECEIVER, True),
    ],
)
def test_the_obc_steers_exactly_when_engaged_or_the_receiver(authority, steers):
    assert status(**{**ENGAGED, "authority": authority}).steering is steers


def test_a_value_newer_firmware_may_send_decodes_as_an_unknown_member():
    payload = pack_uplink_status(status(**{**ENGAGED, "authority": Authority(9)}))
    decoded = parse_uplink_status(payload[:32] + bytes([9, 12]) + payload[34:])
    assert isinstance(decoded.authority, Authority) and decoded.authority == 9
    assert decoded.authority.name == "UNKNOWN_9" and decoded.steering is False
    assert decoded.exit == 12 and decoded.exit.name == "UNKNOWN_12"
    assert Authority(9) is decoded.authority  # one member per value
    with pytest.raises(ValueError):
        Authority(256)


@pytest.mark.parametrize(
    ("at_us", "length", "offset"),
    [(None, COMMAND_LENGTH, 20), (5_002_000, TIMED_COMMAND_LENGTH, 24)],
)
def test_the_sender_sits_before_the_crc(at_us, length, offset):
    packet = CommandPacket((1500, 1500, 1500, 1000, 1500, 1500), 7, 1_000_000, at_us, 0x5A17C3)
    payload = pack_command(packet)
    assert len(payload) == length and payload[offset : offset + 3] == bytes([0xC3, 0x17, 0x5A])
    assert parse_command(payload) == packet


def test_an_arming_request_is_16_bytes_with_its_sender():
    packet = ArmingRequest(ArmingAction.DISARM, 11, 1_080_000, 0x5A17C3)
    payload = pack_arming_request(packet)
    assert len(payload) == ARMING_REQUEST_LENGTH
    assert payload[8] == 2 and payload[9:15] == bytes([0xC3, 0x17, 0x5A, 0, 0, 0])
    assert parse_arming_request(payload) == packet
