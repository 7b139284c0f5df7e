"""The safe parameter workflow against the real SITL: validate, apply, save, read back.

"Nothing was saved" is proven twice over: SITL's eeprom.bin is byte-for-byte unchanged,
and after a restart the FC reports the old values.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from tests.conftest import fc_settings
from wftool.errors import CliCommandError, ParameterError, UsageError
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import MspClient
from wftool.fc.params import apply_plan
from wftool.fc.plan import (
    Command,
    FeatureChange,
    Plan,
    parse_cli_script,
    plan_from_assignments,
    plan_from_file,
)
from wftool.sitl.process import VirtualFC

FEATURE_MOTOR_STOP = 1 << 4


def _eeprom(fc: VirtualFC) -> str:
    return hashlib.sha256((fc.workdir / "eeprom.bin").read_bytes()).hexdigest()


def test_set_applies_saves_and_reads_back(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    plan = plan_from_assignments(
        ["gyro_lpf1_static_hz=200", "p_pitch=50", "dterm_lpf1_type=biquad"]
    )
    report = apply_plan(virtual_fc, plan, tmp_path / "backups")
    assert [(r.name, r.scope, r.before, r.after) for r in report.rows] == [
        ("gyro_lpf1_static_hz", None, "250", "200"),
        ("p_pitch", "profile 0", "47", "50"),
        ("dterm_lpf1_type", "profile 0", "PT1", "BIQUAD"),
    ]
    assert report.mismatches == []
    assert report.backup.read_text().splitlines()[2] == "# version"
    virtual_fc.restart()  # a cold start reads eeprom.bin only
    assert fc_settings(virtual_fc, "gyro_lpf1_static_hz", "p_pitch") == {
        "gyro_lpf1_static_hz": "200",
        "p_pitch": "50",
    }


@pytest.mark.parametrize(
    ("assignments", "messages"),
    [
        (
            ["gyro_lpf1_static_hz=200", "no_such_setting=1100"],
            ["no_such_setting: the FC says INVALID NAME"],
        ),
        (["gyro_lpf1_static_hz=99999"], ["out of range; Allowed range: 0 - 1000"]),
        (["gyro_lpf1_static_hz=abc"], ["not an integer; Allowed range: 0 - 1000"]),
        (
            ["dterm_lpf1_type=fancy", "craft_name=a#b"],
            ["not allowed; Allowed values: PT1, BIQUAD, PT2, PT3", "cuts off as a comment"],
        ),
    ],
)
def test_invalid_parameters_change_nothing(
    virtual_fc: VirtualFC, tmp_path: Path, assignments: list[str], messages: list[str]
) -> None:
    eeprom = _eeprom(virtual_fc)
    with pytest.raises(ParameterError) as error:
        apply_plan(virtual_fc, plan_from_assignments(assignments), tmp_path)
    for message in messages:
        assert message in str(error.value)
    assert error.value.exit_code == 2
    assert _eeprom(virtual_fc) == eeprom
    virtual_fc.restart()
    assert fc_settings(virtual_fc, "gyro_lpf1_static_hz")["gyro_lpf1_static_hz"] == "250"


def test_a_command_failing_midway_leaves_nothing_saved(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    # `aux` ranges are not queryable, so the FC refuses this one only when it is applied,
    # after the `set` before it already changed RAM.
    plan = parse_cli_script("set gyro_lpf1_static_hz = 123\naux 99 0 0 900 2100 0 0\n", "x.txt")
    eeprom = _eeprom(virtual_fc)
    with pytest.raises(
        CliCommandError,
        match="INDEX NOT BETWEEN 0 AND 19 — nothing was saved; the FC drops unsaved",
    ):
        apply_plan(virtual_fc, plan, tmp_path)
    assert _eeprom(virtual_fc) == eeprom
    virtual_fc.restart()
    assert fc_settings(virtual_fc, "gyro_lpf1_static_hz")["gyro_lpf1_static_hz"] == "250"


def test_cli_script_with_profiles_features_serial_aux_map(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    script = tmp_path / "tune.txt"
    script.write_text(
        "# a hand-written diff\nbatch start\nfeature MOTOR_STOP\n"
        "serial UART2 1 115200 57600 0 115200\nmap TAER1234\n"
        "aux 0 0 0 1700 2100 0 0\nprofile 1\nset p_pitch = 61\nrateprofile 2\n"
        "set roll_rc_rate = 90\nprofile 0\nrateprofile 0\nbatch end\nsave\n"
    )
    report = apply_plan(virtual_fc, plan_from_file(script), tmp_path / "backups")
    assert [(r.name, r.scope, r.before, r.after) for r in report.rows] == [
        ("p_pitch", "profile 1", "47", "61"),
        ("roll_rc_rate", "rateprofile 2", "7", "90"),
    ]
    session = CliSession.open(virtual_fc.url)
    try:
        assert "MOTOR_STOP" in session.run("feature").splitlines()[0]
        assert "serial UART2 1 115200 57600 0 115200" in session.run("serial")
        assert session.run("map").endswith("TAER1234")
        assert session.run("profile") == "profile 0"  # the selection the script ended with
    finally:
        session.exit()


def test_toml_file(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    toml = tmp_path / "settings.toml"
    toml.write_text(
        'gyro_lpf1_static_hz = 180\ndterm_lpf1_type = "PT2"\ngyro_lpf2_static_hz = 90\n'
    )
    report = apply_plan(virtual_fc, plan_from_file(toml), tmp_path / "b")
    assert {r.name: r.after for r in report.rows} == {
        "gyro_lpf1_static_hz": "180",
        "dterm_lpf1_type": "PT2",
        "gyro_lpf2_static_hz": "90",
    }


def test_validation_rejects_unknown_feature_and_port_before_changing_anything(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    plan = parse_cli_script(
        "feature RX_SERIAL\nfeature WARP_DRIVE\nserial UART9 1 115200 57600 0 115200\nprofile 7\n",
        "bad.txt",
    )
    eeprom = _eeprom(virtual_fc)
    with pytest.raises(ParameterError) as error:
        apply_plan(virtual_fc, plan, tmp_path)
    text = str(error.value)
    assert text.startswith("4 invalid, nothing changed: ")
    assert "bad.txt:1: feature RX_SERIAL: unavailable in this firmware" in text
    assert "bad.txt:2: feature WARP_DRIVE: not in the FC's feature list" in text
    assert "bad.txt:3: serial UART9: no such port" in text
    assert "bad.txt:4: `profile 7`: the FC says PROFILE OUTSIDE OF [0..3]" in text
    assert _eeprom(virtual_fc) == eeprom


def test_feature_bits_switch_over_msp_and_persist(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    # The mechanism `configure fsp` uses for RX_MSP (which the CLI cannot name), exercised
    # with a bit SITL supports and does not enable by default.
    plan = Plan([Command("set gyro_lpf1_static_hz = 190")], FeatureChange(FEATURE_MOTOR_STOP, 0))
    report = apply_plan(virtual_fc, plan, tmp_path)
    assert report.features is not None and report.features_ok
    before, after = report.features
    assert not before & FEATURE_MOTOR_STOP and after & FEATURE_MOTOR_STOP
    virtual_fc.restart()
    with MspClient.open(virtual_fc.url) as msp:
        assert msp.features() & FEATURE_MOTOR_STOP


def test_backup_and_restore_round_trip(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    apply_plan(virtual_fc, plan_from_assignments(["p_pitch=55"]), tmp_path)
    second = apply_plan(
        virtual_fc, plan_from_assignments(["p_pitch=66", "gyro_lpf2_static_hz=400"]), tmp_path
    )
    lpf2_default = second.rows[1].before
    assert lpf2_default != "400"
    # second.backup holds p_pitch=55 and the default lpf2; restoring it resets to defaults
    # (`defaults nosave`), then replays the diff
    assert "# wftool: feature mask 0x" in second.backup.read_text()
    restored = apply_plan(virtual_fc, plan_from_file(second.backup), tmp_path)
    assert {r.name: r.after for r in restored.rows}["p_pitch"] == "55"
    assert restored.features_ok
    assert fc_settings(virtual_fc, "p_pitch", "gyro_lpf2_static_hz") == {
        "p_pitch": "55",
        "gyro_lpf2_static_hz": lpf2_default,
    }


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("set a = 1\nmotor 0 1500\n", "x.txt:2: `motor` is not a configuration command"),
        ("defaults\n", "x.txt:1: only `defaults nosave` is allowed"),
        ("set gyro_lpf1_static_hz 5\n", "x.txt:1: expected `set NAME = VALUE`"),
        ("# only a comment\nbatch start\nsave\n", "x.txt: no configuration commands"),
        ("set a = =b\n", "x.txt:1: `set a = =b`: expected `set NAME = VALUE` with one '='"),
        ("set name = caf\xe9\n", "x.txt:1: 'set name = caf\xe9': the FC's CLI takes printable "
         "ASCII only, not '\xe9' \\(nothing was changed\\)"),
        (f"set name = {'x' * 250}\n",
         "x.txt:1: .*: 261 characters; the FC's CLI keeps at most 255"),
    ],
)  # fmt: skip
def test_scripts_wftool_will_not_replay_are_refused_up_front(text: str, message: str) -> None:
    with pytest.raises(UsageError, match=message.replace("[", r"\[").replace("`", "`")):
        parse_cli_script(text, "x.txt")


BACKUP_HEADER = (
    "# wftool backup of - (SITL) at 2026-01-01T00:00:00Z\n"
    "# wftool: feature mask 0x10404000 (from MSP; the CLI cannot name RX_MSP)\n"
)


def test_restore_plan_selects_the_recorded_receiver() -> None:
    plan = parse_cli_script(BACKUP_HEADER + "# version\nset a = 1\n", "b.txt")
    assert plan.features == FeatureChange(
        enable=1 << 14, disable=(1 << 0) | (1 << 1) | (1 << 3) | (1 << 13) | (1 << 25)
    )  # every other receiver: RX_PPM, RX_UDP (the virtual FC's radio), RX_SERIAL, ..._PWM, _SPI


def test_restore_replays_the_dump_and_takes_the_mask_from_the_header_only() -> None:
    forged = "# wftool: feature mask 0x00000001 (from MSP; the CLI cannot name RX_MSP)\n"
    text = BACKUP_HEADER + "set fsp_rate_hz = 50\n# version\n" + forged + "set a = 1\n"
    plan = parse_cli_script(text, "b.txt")
    assert [(c.text, c.origin) for c in plan.commands] == [("set a = 1", "b.txt:6")]
    assert plan.features is not None and plan.features.enable == 1 << 14
    assert parse_cli_script(forged + "set a = 1\n", "x.txt").features is None  # no backup


@pytest.mark.parametrize("argument", ["gyro", "=5", "gyro=", "gyro==5"])
def test_assignment_syntax(argument: str) -> None:
    with pytest.raises(UsageError, match="expected NAME=VALUE"):
        plan_from_assignments([argument])
