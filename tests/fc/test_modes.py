"""Mode ranges: on where Betaflight's `isRangeActive` says, and a switch that can turn one off
only where a switch end lies clear of it; MSP_MODE_RANGES in the CLI `aux` form."""

from __future__ import annotations

from wftool.fc.modes import MODE_ARM, MODE_MSP_OVERRIDE, AuxRange, parse_mode_ranges


def test_a_range_is_on_from_its_start_up_to_its_end() -> None:
    switch = AuxRange(0, MODE_MSP_OVERRIDE, 1, 1700, 2100)
    assert not switch.covers(1699) and switch.covers(1700) and switch.covers(2100)
    assert switch.covers(2500)  # held at 2099 by Betaflight
    assert not AuxRange(0, MODE_ARM, 0, 900, 900).covers(900)  # an unused slot


def test_the_off_position_is_the_switchs_low_end_left_out() -> None:
    assert AuxRange(0, 50, 1, 1700, 2100).off_us == 1000
    assert AuxRange(0, 50, 1, 1300, 1700).off_us == 1000  # a three-position switch's middle
    assert AuxRange(0, 50, 1, 1125, 2100).off_us == 1000
    assert AuxRange(0, 50, 1, 900, 2100).off_us is None
    assert AuxRange(0, 50, 1, 1000, 2000).off_us is None  # the low end reads inside
    assert AuxRange(0, 50, 1, 1100, 2100).off_us is None  # within a radio's jitter of it
    assert AuxRange(0, 50, 1, 900, 1300).off_us is None  # on at rest, off only when flicked


def test_msp_mode_ranges_are_the_aux_slots() -> None:
    payload = bytes([0, 0, 32, 48, 50, 1, 32, 48]) + bytes(4) * 2
    ranges = parse_mode_ranges(payload)
    assert ranges[:2] == [AuxRange(0, 0, 0, 1700, 2100), AuxRange(1, 50, 1, 1700, 2100)]
    assert [r.usable for r in ranges] == [True, True, False, False]
    assert AuxRange.parse(ranges[1].command()) == ranges[1]
    assert ranges[1].describe() == "aux 1: MSP OVERRIDE on AUX2 1700-2100"
