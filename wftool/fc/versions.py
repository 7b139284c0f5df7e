"""Which Betaflight an FC runs, and what wftool must know of each version it talks to: one
typed profile per release series (`BetaflightVersion`), looked up from what the FC reports
over MSP (`version_of`), from a backup's version line (`for_release`) or from an MCU target
name (`mcu_part`). Everything version-dependent lives here; the rest of wftool asks.

    version = version_of(msp.identify())
    version.fsp_function            # 1 << 19 on 2025.12, 1 << 30 on 2026.6
    version.function_names(mask)    # "GPS+RX_SERIAL"
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from wftool.errors import UnsupportedFirmware
from wftool.fc.msp import FcIdentity

VARIANT = "BTFL"
"""MSP_FC_VARIANT of Betaflight."""

_RELEASE = re.compile(r"(\d{4})\.(\d{1,2})\.(\d+)")


@dataclass(frozen=True, eq=False)
class BetaflightVersion:
    """What differs between the Betaflight release series wftool talks to (each with the
    Weitflug series applied); the values are the tree's own (file named per field). One
    object per series: compared by identity."""

    release: str
    """The release wftool builds and was checked against, e.g. "2025.12.5"; its series
    (year.month) is what an FC is matched on."""
    commit: str
    """The release tag's commit in Betaflight's repository."""
    api: tuple[int, int]
    """MSP_API_VERSION (major, minor) of the series (msp/msp_protocol.h)."""
    serial_functions: Mapping[str, int]
    """`serialPortFunction_e` by name (io/serial.h), with the series' FSP."""
    mcu_targets: Mapping[str, str]
    """MCU target names (FC_TARGET_MCU, MSP_BOARD_INFO's target) → the part they build for
    (src/platform/*/target/), for the parts wftool knows."""
    profile_kinds: tuple[str, ...]
    """The CLI's profile switches, in the order a `diff all` lists their sections."""
    config_verbs: frozenset[str]
    """The CLI commands a `diff all` holds, minus what wftool does itself (batch, save)."""
    baud_rates: tuple[int, ...]
    """`baudRates[]` (io/serial.c), from 9600 on."""
    fsp_baud_max: int
    """The highest baud rate the series lets an FSP port have (patch 0005)."""
    arming_disable_flags: tuple[str, ...]
    """`armingDisableFlagNames` (fc/runtime_config.c): flag n is bit n."""
    battery_profile_settings: frozenset[str] = frozenset()
    """Settings kept per battery profile (PROFILE_BATTERY_VALUE in cli/settings.c)."""
    removed_settings: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    """Settings of the series before this one that this one no longer has, and why: a
    backup's line setting one is dropped, saying so."""

    @property
    def series(self) -> tuple[int, int]:
        """(year, month): 2025.12.x is (2025, 12)."""
        parsed = parse_release(self.release)
        assert parsed is not None
        return parsed[0], parsed[1]

    @property
    def name(self) -> str:
        """ "Betaflight 2025.12"."""
        year, month = self.series
        return f"Betaflight {year}.{month}"

    @property
    def fsp_function(self) -> int:
        """FSP's serial function bit (the `serial` line's mask)."""
        return self.serial_functions["FSP"]

    @property
    def arm_switch_flag(self) -> int:
        """ARMING_DISABLED_ARM_SWITCH: the ARM switch was on while arming was disabled (always
        the last flag)."""
        return 1 << self.arming_disable_flags.index("ARM_SWITCH")

    @property
    def rx_failsafe_flag(self) -> int:
        """ARMING_DISABLED_RX_FAILSAFE: the receiver has no signal (the OSD's RXLOSS)."""
        return 1 << self.arming_disable_flags.index("RXLOSS")

    def function_names(self, mask: int) -> str:
        """A serial function mask in words, e.g. "GPS+RX_SERIAL" ("bit 25" for unnamed bits)."""
        names = {bit: name for name, bit in self.serial_functions.items()}
        return "+".join(names.get(1 << bit, f"bit {bit}") for bit in range(32) if mask >> bit & 1)

    def arming_flag_names(self, flags: int) -> str:
        """Arming disable flags in the OSD's words, e.g. "RXLOSS+ARM_SWITCH"."""
        named = self.arming_disable_flags
        return "+".join(
            named[bit] if bit < len(named) else f"bit {bit}"
            for bit in range(32)
            if flags >> bit & 1
        )


def parse_release(text: str) -> tuple[int, int, int] | None:
    """(year, month, patch) of a Betaflight version string ("2025.12.5", "2026.6.1-RC2")."""
    match = _RELEASE.match(text.strip())
    return (int(match[1]), int(match[2]), int(match[3])) if match else None


_SERIAL_FUNCTIONS_2025_12 = {
    "MSP": 1 << 0, "GPS": 1 << 1, "FRSKY_HUB": 1 << 2, "HOTT": 1 << 3, "LTM": 1 << 4,
    "SMARTPORT": 1 << 5, "RX_SERIAL": 1 << 6, "BLACKBOX": 1 << 7, "MAVLINK": 1 << 9,
    "ESC_SENSOR": 1 << 10, "SMARTAUDIO": 1 << 11, "IBUS": 1 << 12, "TRAMP": 1 << 13,
    "RCDEVICE": 1 << 14, "LIDAR_TF": 1 << 15, "FRSKY_OSD": 1 << 16, "VTX_MSP": 1 << 17,
    "GIMBAL": 1 << 18,
}  # fmt: skip
_CONFIG_VERBS_2025_12 = frozenset(
    {
        "set", "feature", "serial", "map", "aux", "profile", "rateprofile", "defaults",
        "resource", "timer", "dma", "beeper", "beacon", "led", "color", "mode_color",
        "adjrange", "rxrange", "rxfail", "vtxtable", "vtx", "mixer", "mmix", "smix", "servo",
        "board_name", "manufacturer_id", "mcu_id", "signature",
    }
)  # fmt: skip
_BAUD_RATES = (
    9600, 19200, 38400, 57600, 115200, 230400, 250000, 400000, 460800, 500000, 921600,
    1000000, 1500000, 2000000, 2470000,
)  # fmt: skip
_ARMING_DISABLE_FLAGS_2025_12 = (
    "NOGYRO", "FAILSAFE", "RXLOSS", "NOT_DISARMED", "BOXFAILSAFE", "RUNAWAY", "CRASH",
    "THROTTLE", "ANGLE", "BOOTGRACE", "NOPREARM", "LOAD", "CALIB", "CLI", "CMS", "BST", "MSP",
    "PARALYZE", "GPS", "RESCUE_SW", "DSHOT_TELEM", "REBOOT_REQD", "DSHOT_BBANG", "NO_ACC_CAL",
    "MOTOR_PROTO", "FLIP_SWITCH", "ALT_HOLD_SW", "POS_HOLD_SW", "ARM_SWITCH",
)  # fmt: skip
_BATTERY_PROFILE_SETTINGS_2026_6 = frozenset(
    {
        "bat_capacity", "cbat_alert_percent", "force_battery_cell_count",
        "vbat_full_cell_voltage", "vbat_max_cell_voltage", "vbat_min_cell_voltage",
        "vbat_warning_cell_voltage", "battery_profile_name",
    }
)  # fmt: skip
"""2026.6's PROFILE_BATTERY_VALUE settings (cli/settings.c); global ones on 2025.12."""
_GPS_RESCUE = "GPS rescue reworked upstream (#15382)"
_REMOVED_2026_6 = {
    "abs_control_gain": "absolute control removed upstream (#15023)",
    "abs_control_limit": "absolute control removed upstream (#15023)",
    "abs_control_error_limit": "absolute control removed upstream (#15023)",
    "abs_control_cutoff": "absolute control removed upstream (#15023)",
    "transient_throttle_limit": "airmode's throttle low-pass removed upstream (#15029)",
    "gps_rescue_max_angle": _GPS_RESCUE,
    "gps_rescue_roll_mix": _GPS_RESCUE,
    "gps_rescue_pitch_cutoff": _GPS_RESCUE,
    "gps_rescue_imu_yaw_gain": _GPS_RESCUE,
    "gps_rescue_disarm_threshold": _GPS_RESCUE,
    "gps_rescue_velocity_p": _GPS_RESCUE,
    "gps_rescue_velocity_i": _GPS_RESCUE,
    "gps_rescue_velocity_d": _GPS_RESCUE,
    "gps_rescue_use_mag": (
        f"{_GPS_RESCUE}; the magnetometer is a heading source only with `trust_mag = ON` "
        "(off by default): set it if the mag is calibrated"
    ),
    "pos_hold_without_mag": "position hold waits for a known heading upstream (#15240)",
}
"""Settings of 2025.12 that 2026.6 no longer has (cli/settings.c), and why."""

BETAFLIGHT_2025_12 = BetaflightVersion(
    release="2025.12.5",
    commit="7348054f268f0058574719c134e9f149565bb8ea",
    api=(1, 47),
    serial_functions=MappingProxyType({**_SERIAL_FUNCTIONS_2025_12, "FSP": 1 << 19}),
    mcu_targets=MappingProxyType({"STM32F7X2": "STM32F722", "STM32G47X": "STM32G474"}),
    profile_kinds=("profile", "rateprofile"),
    config_verbs=_CONFIG_VERBS_2025_12,
    baud_rates=_BAUD_RATES,
    fsp_baud_max=2470000,
    arming_disable_flags=_ARMING_DISABLE_FLAGS_2025_12,
)

BETAFLIGHT_2026_6 = BetaflightVersion(
    release="2026.6.1",
    commit="6dbc4218fd6bc33bf16ea32c670304d4f89321d5",
    api=(1, 48),
    # 1 << 19 is upstream's FUNCTION_LIDAR_NL now (#14896): FSP takes a bit far from
    # upstream's growing end.
    serial_functions=MappingProxyType(
        {
            **_SERIAL_FUNCTIONS_2025_12,
            "LIDAR_NL": 1 << 19,
            "OSD_CUSTOM_TEXT": 1 << 20,
            "FSP": 1 << 30,
        }
    ),
    # STM32F7X2 and STM32G47X are named by their part since #15470.
    mcu_targets=MappingProxyType({"STM32F722": "STM32F722", "STM32G474": "STM32G474"}),
    profile_kinds=("profile", "rateprofile", "battery_profile"),
    config_verbs=_CONFIG_VERBS_2025_12 | {"battery_profile", "waypoint"},
    baud_rates=_BAUD_RATES,
    fsp_baud_max=2470000,
    arming_disable_flags=(*_ARMING_DISABLE_FLAGS_2025_12[:-1], "AUTOPILOT_SW", "ARM_SWITCH"),
    battery_profile_settings=_BATTERY_PROFILE_SETTINGS_2026_6,
    removed_settings=MappingProxyType(_REMOVED_2026_6),
)

VERSIONS: tuple[BetaflightVersion, ...] = (BETAFLIGHT_2025_12, BETAFLIGHT_2026_6)
"""Oldest first: the versions wftool talks to."""


def supported() -> str:
    """ "Betaflight 2025.12 (MSP API 1.47), 2026.6 (MSP API 1.48)"."""
    listed = ", ".join(
        f"{v.series[0]}.{v.series[1]} (MSP API {v.api[0]}.{v.api[1]})" for v in VERSIONS
    )
    return f"Betaflight {listed}"


def for_release(text: str) -> BetaflightVersion | None:
    """The profile of a version string's series ("2025.12.5" → 2025.12), or None."""
    parsed = parse_release(text)
    if parsed is None:
        return None
    return next((v for v in VERSIONS if v.series == parsed[:2]), None)


def version_of(fc: FcIdentity) -> BetaflightVersion:
    """The profile of the firmware FC reports (variant, version, MSP API); a firmware wftool
    does not know raises `UnsupportedFirmware`, one line saying what it is and what wftool
    knows."""
    version = for_release(fc.version) if fc.variant == VARIANT else None
    if version is not None and (fc.api.major, fc.api.minor) == version.api:
        return version
    raise UnsupportedFirmware(
        f"the FC runs {fc.variant} {fc.version} (MSP API {fc.api}), which wftool does not "
        f"talk to; it knows {supported()}"
    )


def mcu_part(target: str) -> str | None:
    """The part an MCU target name of any known version builds for ("STM32F7X2" and
    "STM32F722" → "STM32F722"), or None for a name wftool does not know."""
    for version in VERSIONS:
        if target in version.mcu_targets:
            return version.mcu_targets[target]
    return None


def mcu_targets() -> frozenset[str]:
    """Every MCU target name of every known version."""
    return frozenset(name for version in VERSIONS for name in version.mcu_targets)
