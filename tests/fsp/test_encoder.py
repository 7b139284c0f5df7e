"""The command sender: what it records as sent is what goes out; one identity, one
sequence, the FC's pulse range."""

from __future__ import annotations

import pytest

from wftool.fsp import (
    ArmingAction,
    Authority,
    AuthorityExit,
    CommandSender,
    RoundTripMatcher,
    TimeReply,
    UplinkStatus,
)
from wftool.fsp.packets import RC_PULSE_US


@pytest.mark.parametrize("rc", [(1500,) * 5, (1500,) * 7, ()])
def test_a_command_without_six_rc_values_is_refused_and_never_counted_as_sent(rc):
    sender = CommandSender(now=lambda: 10.0, round_trips=RoundTripMatcher())
    with pytest.raises(ValueError, match="6 RC values"):
        sender.encode(rc)
    assert sender.next((1500, 1500, 1500, 1000, 1000, 1000)).seq == 0


@pytest.mark.parametrize("at_us", [-1, 2**32, 1.5, True, "5"])
def test_a_timed_command_for_no_u32_fc_time_is_refused_and_never_counted(at_us):
    sender = CommandSender(now=lambda: 10.0, round_trips=RoundTripMatcher())
    with pytest.raises(ValueError, match="u32"):
        sender.next((1500, 1500, 1500, 1000, 1000, 1000), at_us=at_us)
    packet = sender.next((1500, 1500, 1500, 1000, 1000, 1000), at_us=2**32 - 1)
    assert (packet.seq, packet.at_us) == (0, 2**32 - 1)


NEUTRAL = (1500, 1500, 1500, 1000, 1500, 1500)


def v2_status(rc_min_us: int, rc_max_us: int) -> UplinkStatus:
    """An FC's uplink status with who flies, reporting its pulse range."""
    return UplinkStatus(
        0, 2_000_000, 0, 0, 0, 0, 50, 0, 0, 0, Authority.PILOT, AuthorityExit.NONE, 500, 0, 0,
        0, 0, 0, rc_min_us, rc_max_us,
    )  # fmt: skip


def test_each_sender_names_itself_at_random_and_never_zero():
    identities = {CommandSender().sender for _ in range(200)}
    assert len(identities) >= 199  # 24 random bits each: a repeat in 200 is a 1-in-800 event
    assert all(0 < identity < 2**24 for identity in identities)
    sender = CommandSender(sender=0x5A17C3)
    assert {sender.next(NEUTRAL).sender, sender.arming_request(ArmingAction.ARM).sender} == {
        0x5A17C3
    }


@pytest.mark.parametrize("identity", [0, 2**24, -1])
def test_a_sender_identity_is_24_bits_and_not_zero(identity):
    with pytest.raises(ValueError, match="24 bits and not 0"):
        CommandSender(sender=identity)


@pytest.mark.parametrize("identity", [True, 1.0, "7"])
def test_a_sender_identity_is_an_int(identity):
    with pytest.raises(TypeError, match="is an int"):
        CommandSender(sender=identity)


def test_commands_and_arming_requests_share_one_sequence_and_the_round_trips():
    matcher = RoundTripMatcher()
    clock = iter([1.0, 1.02, 1.04, 1.06])
    sender = CommandSender(now=lambda: next(clock), round_trips=matcher)
    packets = [
        sender.next(NEUTRAL),
        sender.arming_request(ArmingAction.ARM),
        sender.next(NEUTRAL, at_us=5_000_000),
        sender.arming_request(ArmingAction.DISARM),
    ]
    assert [p.seq for p in packets] == [0, 1, 2, 3]
    assert [p.tx_time_us for p in packets] == [1_000_000, 1_020_000, 1_040_000, 1_060_000]
    assert [p.request for p in packets[1::2]] == [ArmingAction.ARM, ArmingAction.DISARM]
    for packet, sent_at in zip(packets, [1.0, 1.02, 1.04, 1.06]):  # a reply pairs with each
        reply = TimeReply(packet.seq, packet.tx_time_us, 0, 0, received_us=0, sent_us=0)
        reply.arrival_time = sent_at + 0.001
        trip = matcher.match(reply)
        assert trip is not None and trip.obc_sent == sent_at


@pytest.mark.parametrize("action", [ArmingAction(0), ArmingAction(3), 1])
def test_an_arming_request_arms_or_disarms_and_nothing_else(action):
    sender = CommandSender()
    if action == 1:  # the plain int of ARM is ARM
        assert sender.arming_request(action).request is ArmingAction.ARM
        return
    with pytest.raises(ValueError, match="arms or disarms"):
        sender.arming_request(action)
    assert sender.seq == 0  # nothing counted


def test_rc_values_are_checked_against_the_fc_pulse_range_once_a_status_says_it():
    sender = CommandSender(now=lambda: 1.0)
    assert sender.pulse_range == RC_PULSE_US
    sender.next((750, 2250, 750, 2250, 750, 2250))  # Betaflight's widest, before any status
    sender.observe(v2_status(885, 2115))
    assert sender.pulse_range == (885, 2115)
    with pytest.raises(ValueError, match=r"throttle 884 µs is outside the FC's pulse range "):
        sender.next((1500, 1500, 1500, 884, 1500, 1500))
    with pytest.raises(ValueError, match=r"aux4 2116 µs .* 885\.\.2115 µs"):
        sender.next((1500, 1500, 1500, 1000, 1500, 2116))
    assert sender.next((885, 2115, 885, 2115, 885, 2115)).seq == 1  # the refused never counted
    legacy = v2_status(885, 2115)
    legacy.authority = legacy.exit = legacy.proof_ms = legacy.exit_us = legacy.sender = None
    legacy.foreign = legacy.refused = legacy.msp_rc_refused = None
    legacy.rc_min_us = legacy.rc_max_us = None
    sender.observe(legacy)  # older firmware does not say: Betaflight's widest again
    assert sender.pulse_range == RC_PULSE_US
