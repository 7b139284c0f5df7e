"""The settings check: what `configure fsp` leaves passes; each way a configuration lets
control change hands without anyone deciding fails, naming its line. And the settings are
read from the FC itself (the patched SITL), over MSP and the CLI."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from wftool.fc.modes import MODE_ARM, MODE_FAILSAFE, MODE_MSP_OVERRIDE, AuxRange
from wftool.fc.msp import (
    FEATURE_RX_MSP,
    ApiVersion,
    BoardInfo,
    BuildInfo,
    FailsafeConfig,
    FcIdentity,
    RxConfig,
)
from wftool.preflight.settings import BoardSettings, check_settings, read_settings
from wftool.sitl.session import VirtualFcSession

IDENTITY = FcIdentity(
    "BTFL", "2025.12.5", ApiVersion(0, 1, 47),
    BoardInfo("SITL", 0, 0, "SITL", "", "", 0), BuildInfo("Jan 1 2026", "00:00:00", "abcdef0"),
)  # fmt: skip
AETR = (0, 1, 3, 2, 4, 5, 6, 7)
PILOT_ARM = AuxRange(0, MODE_ARM, 0, 1700, 2100)
OVERRIDE = AuxRange(1, MODE_MSP_OVERRIDE, 1, 1700, 2100)


def piloted(**changes: object) -> BoardSettings:
    """A board as `configure fsp` leaves it with a safety pilot (ARM on the radio's AUX1)."""
    values = {
        "fsp_cmd_timeout_ms": "50", "fsp_time_reply": "OFF", "msp_override_channels_mask": "15",
        "msp_override_failsafe": "OFF", "failsafe_procedure": "DROP",
        "failsafe_recovery_delay": "5",
    }  # fmt: skip
    values.update(changes.pop("values", {}))  # type: ignore[arg-type]
    board = BoardSettings(
        IDENTITY, 0, values, [PILOT_ARM, OVERRIDE], AETR,
        FailsafeConfig(1500, 60, 1000, 0, 10000, 1), RxConfig(885, 2115), ("UART2",),
    )  # fmt: skip
    return replace(board, **changes)  # type: ignore[arg-type]


def alone(**changes: object) -> BoardSettings:
    """A board as `configure fsp --obc-only` leaves it: ARM on AUX1, which the FC holds."""
    return replace(
        piloted(**changes),
        features=FEATURE_RX_MSP,
        ranges=changes.get("ranges", [PILOT_ARM]),  # type: ignore[arg-type]
    )


def failed(settings: BoardSettings, limit_ms: float = 100.0) -> list[str]:
    return [line.name for line in check_settings(settings, limit_ms).failed]


def test_what_configure_fsp_leaves_passes() -> None:
    assert failed(piloted()) == []
    assert failed(alone()) == []


def test_a_switch_range_without_an_off_position_fails() -> None:
    for start, end in ((900, 2100), (1000, 2000)):
        switch = AuxRange(1, MODE_MSP_OVERRIDE, 1, start, end)
        assert failed(piloted(ranges=[PILOT_ARM, switch])) == [
            "the override switch has an off position"
        ]
    middle = AuxRange(1, MODE_MSP_OVERRIDE, 1, 1300, 1700)  # a three-position switch's middle
    assert failed(piloted(ranges=[PILOT_ARM, middle])) == []


def test_no_override_switch_or_two_fail() -> None:
    assert failed(piloted(ranges=[PILOT_ARM])) == ["MSP OVERRIDE on one switch"]
    other = AuxRange(2, MODE_MSP_OVERRIDE, 3, 1700, 2100)
    assert failed(piloted(ranges=[PILOT_ARM, OVERRIDE, other])) == ["MSP OVERRIDE on one switch"]


def test_the_override_switch_that_arms_fails() -> None:
    arm = AuxRange(0, MODE_ARM, 1, 1300, 1500)
    assert failed(piloted(ranges=[arm, OVERRIDE])) == ["the override switch is not the ARM switch"]


def test_a_mask_with_aux_channels_fails() -> None:
    with_aux3 = 15 | 1 << 6
    assert failed(piloted(values={"msp_override_channels_mask": str(with_aux3)})) == [
        "msp_override_channels_mask: the sticks only"
    ]
    assert failed(piloted(values={"msp_override_channels_mask": "0"})) == [
        "msp_override_channels_mask: the sticks only"
    ]
    arm5 = AuxRange(0, MODE_ARM, 4, 1700, 2100)  # ARM on AUX5, which the mask hands the OBC
    assert failed(
        piloted(values={"msp_override_channels_mask": str(15 | 1 << 8)}, ranges=[arm5, OVERRIDE])
    ) == [
        "msp_override_channels_mask: the sticks only",
        "ARM and FAILSAFE off the channels the OBC overrides",
    ]


def test_msp_override_failsafe_on_fails() -> None:
    assert failed(piloted(values={"msp_override_failsafe": "ON"})) == [
        "msp_override_failsafe OFF (the OBC never keeps a lost radio link alive)"
    ]


def test_a_timeout_above_the_limit_fails() -> None:
    assert failed(piloted(values={"fsp_cmd_timeout_ms": "150"})) == ["fsp_cmd_timeout_ms"]
    assert failed(piloted(values={"fsp_cmd_timeout_ms": "150"}), limit_ms=150) == []
    assert failed(piloted(values={"fsp_cmd_timeout_ms": None})) == ["fsp_cmd_timeout_ms"]


def test_obc_alone_arm_on_an_obc_channel_fails() -> None:
    on_aux3 = AuxRange(0, MODE_ARM, 2, 1700, 2100)
    assert failed(alone(ranges=[on_aux3])) == [
        "ARM on AUX1 only, the switch the FC holds (arming requests)"
    ]
    assert failed(alone(ranges=[])) == [
        "ARM on AUX1 only, the switch the FC holds (arming requests)"
    ]


def test_obc_alone_any_other_mode_fails() -> None:
    on_aux5 = AuxRange(1, 1, 4, 1300, 1700)  # ANGLE on AUX5, held at 1500: on for good
    assert failed(alone(ranges=[PILOT_ARM, on_aux5])) == [
        "no mode on AUX1/AUX2/AUX5+ (FSP never drives them: it would be stuck)"
    ]
    failsafe_on_aux4 = AuxRange(1, MODE_FAILSAFE, 3, 1700, 2100)
    assert failed(alone(ranges=[PILOT_ARM, failsafe_on_aux4])) == [
        "no mode on AUX3/AUX4 (the OBC's: a command sent by accident would switch it)"
    ]


def test_the_settings_are_read_from_the_fc(sitl_binary: Path, tmp_path: Path) -> None:
    """`configure fsp` on the virtual FC, then its settings read back: the same configuration,
    through MSP and the CLI (which reboots the FC: it answers again afterwards)."""
    with VirtualFcSession(
        sitl_binary, tmp_path, port_base=None, pilot=True, cmd_timeout_ms=40
    ) as session:
        settings = read_settings(session.fc)
        assert not settings.obc_alone and settings.timeout_ms == 40
        assert settings.number("msp_override_channels_mask") == settings.sticks_mask == 15
        switch = settings.override_switch
        assert switch is not None and (switch.aux, switch.start, switch.end) == (2, 1700, 2100)
        assert settings.arm_switch is not None and settings.arm_switch.aux == 1
        assert settings.fsp_ports == ("UART2",) and settings.rcmap == AETR
        assert settings.failsafe.procedure_name == "DROP" and settings.failsafe.delay_ms == 1500
        assert (settings.rx.min_us, settings.rx.max_us) == (885, 2115)
        assert failed(settings) == []
        assert read_settings(session.fc) == settings  # the FC came back from its CLI
