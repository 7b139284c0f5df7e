"""The CLI session against the real SITL, and the parsing of what `get` prints."""

from __future__ import annotations

import pytest

from tests.fc.stand_in import cli_stand_in
from wftool.errors import CliCommandError
from wftool.fc.cli_session import CliSession, Setting, parse_get
from wftool.fc.msp import MspClient
from wftool.link.transport import open_port
from wftool.sitl.process import VirtualFC


def test_first_command_after_entering_is_not_lost(virtual_fc: VirtualFC) -> None:
    session = CliSession.open(virtual_fc.url)
    try:
        assert session.run("get gyro_lpf1_static_hz").startswith("gyro_lpf1_static_hz = ")
    finally:
        session.exit()


def test_get_reports_value_range_and_scope(virtual_fc: VirtualFC) -> None:
    session = CliSession.open(virtual_fc.url)
    try:
        assert session.get("gyro_lpf1_static_hz") == Setting(
            "gyro_lpf1_static_hz", "250", "Allowed range: 0 - 1000"
        )
        p_pitch = session.get("p_pitch")
        assert (p_pitch.scope, p_pitch.int_range) == ("profile 0", (0, 250))
        lookup = session.get("dterm_lpf1_type")
        assert lookup.constraint.startswith("Allowed values: PT1, BIQUAD")
    finally:
        session.exit()


def test_fc_errors_carry_the_fc_text_and_allowed_range(virtual_fc: VirtualFC) -> None:
    session = CliSession.open(virtual_fc.url)
    try:
        with pytest.raises(CliCommandError) as invalid_name:
            session.get("no_such_setting")
        assert invalid_name.value.fc_error == "INVALID NAME: no_such_setting"
        with pytest.raises(CliCommandError) as out_of_range:
            session.set("gyro_lpf1_static_hz", "99999")
        assert out_of_range.value.fc_error == "INVALID VALUE (Allowed range: 0 - 1000)"
        with pytest.raises(CliCommandError, match="only longer names"):
            session.get("gyro_lpf1")  # a prefix: `get` lists the longer names it is part of
    finally:
        session.exit()


def test_save_persists_across_a_reset(virtual_fc: VirtualFC) -> None:
    session = CliSession.open(virtual_fc.url)
    session.set("gyro_lpf1_static_hz", "321")
    session.save()
    virtual_fc.wait_back()
    session = CliSession.open(virtual_fc.url)
    try:
        assert session.get("gyro_lpf1_static_hz").value == "321"
    finally:
        session.exit()


def test_exit_reboots_and_drops_unsaved_changes(virtual_fc: VirtualFC) -> None:
    session = CliSession.open(virtual_fc.url)
    session.set("gyro_lpf1_static_hz", "321")
    session.exit()
    virtual_fc.wait_back()
    assert virtual_fc.starts == 2  # exit is a reset, like save
    session = CliSession.open(virtual_fc.url)
    try:
        assert session.get("gyro_lpf1_static_hz").value == "250"
    finally:
        session.exit()


def test_exit_noreboot_hands_the_port_back_to_msp(virtual_fc: VirtualFC) -> None:
    session = CliSession.open(virtual_fc.url)
    session.set("gyro_lpf1_static_hz", "321")
    session.exit_noreboot()
    assert MspClient(session.link).fc_variant() == "BTFL"
    session.enter()
    assert session.get("gyro_lpf1_static_hz").value == "321"  # still live in RAM
    session.exit()


def test_diff_all_is_a_replayable_script(virtual_fc: VirtualFC) -> None:
    session = CliSession.open(virtual_fc.url)
    try:
        diff = session.diff_all()
    finally:
        session.exit()
    lines = diff.splitlines()
    assert lines[0] == "# version"
    assert "defaults nosave" in lines and "batch start" in lines
    assert lines[-1] == "save"


RANGE = Setting("x", "5", "Allowed range: -10 - 10")
LOOKUP = Setting("y", "OFF", "Allowed values: OFF, ON")
ARRAY = Setting("z", "1,2,3", "Array length: 3")
STRING = Setting("n", "-", "String length: 1 - 4")


@pytest.mark.parametrize(
    ("setting", "value", "problem"),
    [
        (RANGE, "-10", None),
        (RANGE, "+10", None),
        (RANGE, "11", "out of range; Allowed range: -10 - 10"),
        (RANGE, "abc", "not an integer; Allowed range: -10 - 10"),  # the FC would store 0
        (RANGE, "1.5", "not an integer; Allowed range: -10 - 10"),
        (LOOKUP, "on", None),
        (LOOKUP, "maybe", "not allowed; Allowed values: OFF, ON"),
        (ARRAY, "4, 5,6", None),
        (ARRAY, "4,5", "needs 3 comma-separated integers; Array length: 3"),
        (STRING, "abcd", None),
        (STRING, "-", None),
        (STRING, "abcde", "wrong length; String length: 1 - 4 (or '-' for empty)"),
    ],
)
def test_problem_follows_the_fc_constraint(setting: Setting, value: str, problem: str) -> None:
    assert setting.problem(value) == problem


def test_canonical_spelling_is_the_fcs() -> None:
    assert LOOKUP.canonical("on") == "ON"
    assert RANGE.canonical("+07") == "7"
    assert ARRAY.canonical("4, 5,6") == "4,5,6"


def test_parse_get_picks_the_exact_name_among_matches() -> None:
    output = (
        "gyro_lpf1_type = PT1\nAllowed values: PT1, BIQUAD\n\ngyro_lpf1 = 7\nAllowed range: 0 - 9"
    )
    assert parse_get("GYRO_LPF1", output) == Setting("gyro_lpf1", "7", "Allowed range: 0 - 9")


def test_a_long_diff_all_over_socket_is_read_whole() -> None:
    """400 KB of `diff all`: read a byte at a time over socket:// and searched whole for its
    end after each, it did not arrive within its 15 s (200 KB took 7 s)."""
    body = b"".join(b"set setting_%06d = %d\r\n" % (i, i) for i in range(16_000))
    end = b"# save configuration\r\nsave"
    with cli_stand_in(lambda command: body + end if command == "diff all" else b"") as url:
        session = CliSession(open_port(url, timeout=0.05))
        try:
            diff = session.diff_all()
        finally:
            session.close()
    assert len(body) > 400_000
    assert diff == (body + end).decode().replace("\r\n", "\n")
