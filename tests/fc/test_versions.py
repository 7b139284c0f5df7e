"""The Betaflight versions wftool talks to: looked up from what an FC reports, checked against
the Betaflight tree of each (the mirror's tags, read with git), and an unknown one refused in
one line."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from tests.conftest import run_cli
from tests.fc.stand_in import identity_replies, msp_stand_in
from wftool.errors import UnsupportedFirmware
from wftool.fc.msp import ApiVersion, BoardInfo, BuildInfo, FcIdentity
from wftool.fc.versions import (
    BETAFLIGHT_2025_12,
    BETAFLIGHT_2026_6,
    VERSIONS,
    BetaflightVersion,
    for_release,
    mcu_part,
    version_of,
)

BOARD = BoardInfo("SITL", 0, 0, "SITL", "", "", 0)
BUILD = BuildInfo("Jan  1 2026", "00:00:00", "abcdef0")


def identity(version: str, api: tuple[int, int], variant: str = "BTFL") -> FcIdentity:
    return FcIdentity(variant, version, ApiVersion(0, *api), BOARD, BUILD)


def test_an_fc_is_matched_on_its_series_and_api() -> None:
    assert version_of(identity("2025.12.5", (1, 47))) is BETAFLIGHT_2025_12
    assert version_of(identity("2025.12.3", (1, 47))) is BETAFLIGHT_2025_12
    assert version_of(identity("2026.6.1", (1, 48))) is BETAFLIGHT_2026_6
    assert for_release("2026.6.0-RC2") is BETAFLIGHT_2026_6


@pytest.mark.parametrize(
    ("version", "api", "variant"),
    [("2026.12.0", (1, 49), "BTFL"), ("2026.6.1", (1, 47), "BTFL"), ("9.1.0", (2, 5), "INAV")],
    ids=["upstream-master", "api-of-another-series", "not-betaflight"],
)
def test_any_other_firmware_is_refused_in_one_line(
    version: str, api: tuple[int, int], variant: str
) -> None:
    with pytest.raises(UnsupportedFirmware) as refused:
        version_of(identity(version, api, variant))
    message = str(refused.value)
    assert "\n" not in message
    assert f"{variant} {version} (MSP API {api[0]}.{api[1]})" in message
    assert "Betaflight 2025.12 (MSP API 1.47), 2026.6 (MSP API 1.48)" in message


def test_mcu_names_of_every_version_are_one_part() -> None:
    assert mcu_part("STM32F7X2") == mcu_part("STM32F722") == "STM32F722"
    assert mcu_part("STM32G47X") == mcu_part("STM32G474") == "STM32G474"
    assert mcu_part("STM32F405") is None


def test_fsp_moved_off_upstreams_new_bit() -> None:
    assert BETAFLIGHT_2025_12.fsp_function == 1 << 19
    assert BETAFLIGHT_2026_6.fsp_function == 1 << 30
    assert BETAFLIGHT_2025_12.function_names(66 | 1 << 19 | 1 << 30) == "GPS+RX_SERIAL+FSP+bit 30"
    assert BETAFLIGHT_2026_6.function_names(1 << 19 | 1 << 30) == "LIDAR_NL+FSP"


# -- the profiles against the Betaflight trees they describe -------------------------------------

MIRROR = Path("/work/.mirror/betaflight+betaflight/repo")


def _show(version: BetaflightVersion, path: str) -> str:
    if not MIRROR.is_dir():
        pytest.skip(f"no Betaflight mirror at {MIRROR}")
    return subprocess.run(
        ["git", "-C", str(MIRROR), "show", f"{version.commit}:{path}"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: v.release)
def test_each_profile_is_its_trees(version: BetaflightVersion) -> None:
    """Upstream's numbers (the series' FSP aside) are the tree's at the release's commit."""
    header = _show(version, "src/main/build/version.h")
    release = ".".join(
        re.search(rf"#define FC_VERSION_{part}\s+(\d+)", header)[1]  # type: ignore[index]
        for part in ("YEAR", "MONTH", "PATCH_LEVEL")
    )
    assert release == version.release
    protocol = _show(version, "src/main/msp/msp_protocol.h")
    api = tuple(
        int(re.search(rf"#define API_VERSION_{part}\s+(\d+)", protocol)[1])  # type: ignore[index]
        for part in ("MAJOR", "MINOR")
    )
    assert api == version.api
    serial_h = _show(version, "src/main/io/serial.h")
    upstream = {int(bit) for bit in re.findall(r"FUNCTION_\w+\s*=\s*\(1 << (\d+)\)", serial_h)}
    ours = {bit.bit_length() - 1 for name, bit in version.serial_functions.items() if name != "FSP"}
    assert ours == upstream
    assert version.fsp_function.bit_length() - 1 not in upstream
    flags = re.findall(r'^\s+"(\w+)",$', _show(version, "src/main/fc/runtime_config.c"), re.M)
    assert tuple(flags) == version.arming_disable_flags
    targets = _show(version, "src/platform/STM32/target/")
    for name in version.mcu_targets:
        assert f"{name}/" in targets.splitlines()


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: v.release)
def test_battery_profiles_and_removed_settings_are_the_trees(version: BetaflightVersion) -> None:
    settings = _show(version, "src/main/cli/settings.c")
    names = _show(version, "src/main/fc/parameter_names.h")
    macros = dict(re.findall(r'#define\s+(PARAM_NAME_\w+)\s+"([^"]+)"', names))
    sections = {
        macros.get(m[1], m[1]).strip('"'): m[2]
        for m in re.finditer(r'\{\s*("[^"]+"|PARAM_NAME_\w+)\s*,\s*VAR_\w+\s*\|\s*(\w+)', settings)
    }
    battery = {name for name, section in sections.items() if section == "PROFILE_BATTERY_VALUE"}
    assert battery == version.battery_profile_settings
    assert not set(version.removed_settings) & set(sections)
    before = VERSIONS[VERSIONS.index(version) - 1] if VERSIONS.index(version) else None
    if before is not None:
        assert set(version.removed_settings) <= set(_settings_of(before)), (
            "a removed setting the version before did not have"
        )


def _settings_of(version: BetaflightVersion) -> set[str]:
    settings = _show(version, "src/main/cli/settings.c")
    macros = dict(
        re.findall(
            r'#define\s+(PARAM_NAME_\w+)\s+"([^"]+)"',
            _show(version, "src/main/fc/parameter_names.h"),
        )
    )
    found = re.findall(r'\{\s*("[^"]+"|PARAM_NAME_\w+)\s*,\s*VAR_', settings)
    return {macros.get(name, name).strip('"') for name in found}


def test_info_on_an_unknown_firmware_says_so_in_one_line_exit_2(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A STAND-IN answering MSP as upstream master does (2026.12.0, API 1.49)."""
    with msp_stand_in(identity_replies("2026.12.0", (1, 49))) as url:
        code, out, err = run_cli(capsys, "info", "--port", url)
    assert code == 2
    assert out.startswith("BTFL 2026.12.0 (MSP API 1.49)")
    [line] = err.strip().splitlines()
    assert line.startswith("error: the FC runs BTFL 2026.12.0 (MSP API 1.49), which wftool does")
