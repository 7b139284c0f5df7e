"""The command sender: what it records as sent is what goes out."""

from __future__ import annotations

import pytest

from wftool.fsp import CommandSender, RoundTripMatcher


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
