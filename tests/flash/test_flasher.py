"""`wftool flash` end to end: the real SITL plays the FC, a STAND-IN plays dfu-util.

Real: identifying the FC over MSP, the `diff all` backup, the MSP reboot into the
bootloader (SITL logs it and exits), and, after "flashing", the FC coming back and being
asked over MSP which build it runs. Simulated: the USB bootloader (tests/flash/
standin_dfu_util.py), and the board booting the written image — SITL restarts with its
own build, so the success tests flash an image that carries SITL's build strings.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import pytest
from intelhex import IntelHex

from tests.conftest import run_cli
from tests.fc.faulty_transport import InjectFaults
from tests.flash.standin import UNTOUCHED, StandinDfuUtil
from wftool.cli import main
from wftool.errors import FlashError, UsageError
from wftool.fc.msp import BoardInfo, BuildInfo, MspClient
from wftool.fc.params import apply_plan, plan_from_assignments
from wftool.firmware.manifest import BuildFlags, Manifest
from wftool.firmware.project import PROJECT_ENV
from wftool.flash.flasher import find_manifest, flash_firmware, resolve_firmware
from wftool.flash.image import load_image
from wftool.sitl.process import VirtualFC

MSP_SET_BOARD_INFO = 248


def _build_of(fc: VirtualFC) -> BuildInfo:
    with MspClient.open(fc.url) as msp:
        return msp.build_info()


def _image(path: Path, build: BuildInfo, *strings: str) -> Path:
    """A two-segment image (vector table, firmware) holding `build`'s identity strings."""
    image = IntelHex()
    image.puts(0x0800_0000, bytes(range(256)) * 2)
    names = (build.date, build.time, build.git_revision + "f2", *strings)
    image.puts(0x0800_8000, b"\0" + b"\0".join(s.encode() for s in names) + b"\0" * 4096)
    image.write_hex_file(str(path))
    return path


def _manifest(directory: Path, hex_path: Path, **fields: str) -> Path:
    """A schema-1 manifest.json in DIRECTORY for HEX_PATH, as `wftool build` writes it."""
    directory.mkdir(parents=True, exist_ok=True)
    manifest = Manifest(
        path=directory / "manifest.json",
        target="SPEEDYBEEF7V3",
        board="SPEEDYBEEF7V3",
        mcu="STM32F7X2",
        betaflight_commit="0" * 40,
        betaflight_head="1" * 40,
        betaflight_version="2025.12.5",
        git_revision="0000000",
        patch_series_sha256="2" * 64,
        patches=[],
        board_config_sha256=None,
        toolchain={"path": "arm-none-eabi-gcc", "version": "13.3.1", "required": "13.3.1",
                   "strict": False},
        flags=BuildFlags(),
        usage=None,
        build_seconds=1.0,
        built_at="2025-01-01T00:00:00+00:00",
        artifacts={"hex": os.path.relpath(hex_path, directory), "elf": "fw.elf"},
        artifact_sha256={},
        inputs_sha256="3" * 64,
    )  # fmt: skip
    manifest = replace(manifest, **fields)
    manifest.write()
    return manifest.path


def test_mismatched_firmware_is_refused_before_anything_happens(
    virtual_fc: VirtualFC, built_hex: Path, standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    with pytest.raises(
        UsageError, match=r"refusing to flash .*the image does not name the FC's target SITL"
    ):
        flash_firmware(virtual_fc, built_hex, backup_dir=tmp_path / "backups")
    assert virtual_fc.running and virtual_fc.starts == 1
    assert not (tmp_path / "backups").exists()
    assert standin_dfu_util.calls() == []


def test_flash_backs_up_reboots_writes_around_the_config_and_verifies(
    virtual_fc: VirtualFC, standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    apply_plan(virtual_fc, plan_from_assignments(["p_pitch=55"]), tmp_path / "backups")
    build = _build_of(virtual_fc)
    hex_path = _image(tmp_path / "fw.hex", build)
    manifest = _manifest(
        tmp_path / "build" / "SPEEDYBEEF7V3", hex_path, git_revision=build.git_revision + "f2"
    )
    standin_dfu_util.configure(appear_after_lists=2)  # the bootloader enumerates late
    log: list[str] = []
    report = flash_firmware(
        virtual_fc,
        manifest,
        backup_dir=tmp_path / "backups",
        force=True,
        restore=True,
        log=log.append,
    )

    assert any("flashing despite: built for STM32F7X2, the FC is SITL" in line for line in log)
    assert report.backup is not None and "diff all" not in report.backup.read_text()
    assert "defaults nosave" in report.backup.read_text()
    assert b"[system]ResetToBootloader!" in virtual_fc.log_path.read_bytes()
    downloads = [call for call in standin_dfu_util.calls() if "-D" in call]
    assert [call[call.index("-s") + 1] for call in downloads] == ["0x08000000", "0x08008000:leave"]
    flash = standin_dfu_util.flash()
    assert flash[:512] == bytes(range(256)) * 2
    assert flash[0x4000:0x8000] == bytes([UNTOUCHED]) * 0x4000  # config sector survived
    assert report.erased == {0, 2}
    assert report.after.build == build
    assert report.restored is not None
    assert [(r.name, r.after) for r in report.restored.rows] == [("p_pitch", "55")]


def test_verification_failure_says_so_and_keeps_the_backup(
    virtual_fc: VirtualFC, built_hex: Path, standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    # A real STM32F7X2 build; the FC that comes back (SITL) runs a different build.
    with pytest.raises(FlashError) as error:
        flash_firmware(virtual_fc, built_hex, backup_dir=tmp_path / "backups", force=True)
    message = str(error.value)
    assert "verification failed: the FC runs" in message
    backups = list((tmp_path / "backups").iterdir())
    assert len(backups) == 1 and f"configuration backup: {backups[0]}" in message
    assert standin_dfu_util.flash()[0x4000:0x8000] == bytes([UNTOUCHED]) * 0x4000


def test_write_failure_names_the_backup_and_the_next_step(
    virtual_fc: VirtualFC, standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    hex_path = _image(tmp_path / "fw.hex", _build_of(virtual_fc), "STM32F7X2")
    standin_dfu_util.configure(fail_at_percent=30)
    with pytest.raises(FlashError) as error:
        flash_firmware(virtual_fc, hex_path, backup_dir=tmp_path / "b", force=True)
    message = str(error.value)
    assert message.startswith("writing the firmware: dfu-util failed writing at 0x08008000")
    assert "Device is unable to write memory" in message
    assert f"retry with `wftool flash --no-reboot {hex_path}`" in message
    assert "configuration backup: " in message


def test_no_reboot_flashes_a_board_already_in_dfu(
    sitl_binary: Path, standin_dfu_util: StandinDfuUtil, tmp_path: Path
) -> None:
    fc = VirtualFC(sitl_binary, tmp_path / "sitl", port_base=None)
    with fc:
        build = _build_of(fc)
    # The FC sits in its bootloader (SITL not running); flashing starts it again.
    hex_path = _image(tmp_path / "fw.hex", build, "STM32F7X2")
    try:
        report = flash_firmware(fc, hex_path, backup_dir=tmp_path / "b", no_reboot=True)
    finally:
        fc.stop()
    assert report.backup is None and report.before is None
    assert report.after.build == build


def test_no_reboot_with_full_erase_needs_force(tmp_path: Path) -> None:
    hex_path = _image(
        tmp_path / "fw.hex", BuildInfo("Jan 01 2000", "00:00:00", "abcdef0"), "STM32F7X2"
    )
    with pytest.raises(UsageError, match="without a backup; add --force"):
        flash_firmware(
            VirtualFC(tmp_path, tmp_path),
            hex_path,
            backup_dir=tmp_path,
            no_reboot=True,
            full_erase=True,
        )


def test_a_bin_over_the_config_sector_needs_full_erase(built_hex: Path, tmp_path: Path) -> None:
    binary = tmp_path / "fw.bin"
    load_image(built_hex).tobinfile(str(binary), start=0x0800_0000)
    with pytest.raises(UsageError, match="covers the config sector at 0x08004000"):
        flash_firmware(VirtualFC(tmp_path, tmp_path), binary, backup_dir=tmp_path, no_reboot=True)


def test_default_firmware_is_the_newest_build_for_this_board(tmp_path: Path) -> None:
    hex_path = tmp_path / "fw.hex"
    hex_path.write_text("")
    other = _manifest(tmp_path / "build" / "OTHER", hex_path, board="OTHERBOARD")
    older = _manifest(tmp_path / "build" / "OLD", hex_path)
    newer = _manifest(tmp_path / "build" / "NEW", hex_path)
    os.utime(older, (1, 1))
    board = BoardInfo("S7X2", 0, 0, "STM32F7X2", "SPEEDYBEEF7V3", "SPBE", 0)
    assert find_manifest(tmp_path / "build", board) == Manifest.load(newer)
    generic = BoardInfo("S7X2", 0, 0, "STM32F7X2", "", "", 0)  # no board name: match the MCU
    assert find_manifest(tmp_path / "build", generic) is not None
    assert other.exists()
    assert find_manifest(tmp_path / "nothing", board) is None


def test_bad_manifest_is_a_usage_error(tmp_path: Path) -> None:
    path = tmp_path / "manifest.json"
    path.write_text('{"target": "X"}')
    with pytest.raises(UsageError, match="bad build manifest"):
        Manifest.load(path)


def test_wftool_flash_command_end_to_end(
    on_sitl: VirtualFC,
    standin_dfu_util: StandinDfuUtil,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    hex_path = _image(tmp_path / "fw.hex", _build_of(on_sitl), "SITL", "STM32F7X2")
    with pytest.raises(SystemExit) as exit_info:
        main(["flash", str(hex_path), "--backup-dir", str(tmp_path / "b")])
    out, err = capsys.readouterr()
    assert exit_info.value.code == 0
    assert out.splitlines()[0] == "flashed fw.hex; erased sectors 0, 2"
    assert "Download" in err and "100%" in err  # the progress bars
    assert "get_status failed after leave, as usual" in err


def test_an_image_for_another_mcu_is_bad_input(
    on_sitl: VirtualFC,
    standin_dfu_util: StandinDfuUtil,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    hex_path = _image(tmp_path / "fw.hex", _build_of(on_sitl), "STM32F7X2")  # not "SITL"
    code, _, err = run_cli(capsys, "flash", str(hex_path), "--backup-dir", str(tmp_path / "b"))
    assert (code, err.splitlines()[-1]) == (
        2,
        "error: refusing to flash fw.hex: the image does not name the FC's target SITL "
        "(--force overrides)",
    )
    assert standin_dfu_util.calls() == [] and on_sitl.starts == 1


def test_a_board_name_no_image_can_hold_is_a_mismatch_not_a_crash(
    on_sitl: VirtualFC,
    standin_dfu_util: StandinDfuUtil,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    name = b"Qu\xe4d"  # Betaflight takes any bytes (MSP_SET_BOARD_INFO); MSP text is ASCII
    with MspClient.open(on_sitl.url) as msp:
        msp.request(MSP_SET_BOARD_INFO, bytes([len(name)]) + name + b"\x00")
    hex_path = _image(tmp_path / "fw.hex", _build_of(on_sitl), "SITL")
    code, _, err = run_cli(capsys, "flash", str(hex_path), "--backup-dir", str(tmp_path / "b"))
    assert (code, err.splitlines()[-1]) == (
        2,
        "error: refusing to flash fw.hex: the image does not name the FC's board Qu\ufffdd "
        "(--force overrides)",
    )
    assert standin_dfu_util.calls() == [] and on_sitl.starts == 1


def test_full_erase_does_not_happen_after_an_incomplete_backup(
    on_sitl: VirtualFC,
    standin_dfu_util: StandinDfuUtil,
    tmp_path: Path,
    inject_faults: InjectFaults,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # The FC's `diff all` loses its rest after a `# ` line (tests/fc/faulty_transport.py).
    faults = inject_faults(stall_after_comment=5, stall_s=None)
    hex_path = _image(tmp_path / "fw.hex", _build_of(on_sitl), "SITL", "STM32F7X2")
    code, _, err = run_cli(capsys, "flash", str(hex_path), "--full-erase", "--backup-dir",
                           str(tmp_path / "b"))  # fmt: skip
    assert faults.fired and faults.fired[0].startswith("`diff all` lost the rest")
    assert code == 1
    assert err.splitlines()[-1].startswith("error: the FC's `diff all` output on ")
    assert "incomplete" in err.splitlines()[-1]
    assert standin_dfu_util.calls() == []  # never in DFU, never erased
    assert standin_dfu_util.flash() == bytes([UNTOUCHED]) * len(standin_dfu_util.flash())
    assert b"ResetToBootloader" not in on_sitl.log_path.read_bytes()
    assert list((tmp_path / "b").iterdir()) == []
    assert _build_of(on_sitl).git_revision  # out of its CLI: it answers MSP


def _project(root: Path) -> Path:
    """A directory that is a wftool project (its .gitmodules declares betaflight/)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / ".gitmodules").write_text('[submodule "betaflight"]\n\tpath = betaflight\n')
    return root


def test_default_firmware_is_found_through_the_project_not_the_cwd(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    project = _project(tmp_path / "checkout")
    hex_path = _image(project / "fw.hex", BuildInfo("Jan 01 2000", "00:00:00", "abcdef0"))
    built = _manifest(project / "build" / "speedybeef7v3", hex_path)
    subdirectory = project / "docs" / "notes"
    subdirectory.mkdir(parents=True)
    monkeypatch.chdir(subdirectory)
    monkeypatch.delenv(PROJECT_ENV, raising=False)
    board = BoardInfo("S7X2", 0, 0, "STM32F7X2", "SPEEDYBEEF7V3", "SPBE", 0)
    firmware = resolve_firmware(None, None, board)
    assert firmware.manifest == Manifest.load(built)
    assert firmware.path.resolve() == hex_path


def test_wftool_flash_from_a_subdirectory_flashes_the_projects_build(
    on_sitl: VirtualFC,
    standin_dfu_util: StandinDfuUtil,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    with MspClient.open(on_sitl.url) as msp:
        fc = msp.identify()
    project = _project(tmp_path / "checkout")
    hex_path = _image(project / "fw.hex", fc.build, "STM32F7X2")
    _manifest(
        project / "build" / "sitl",
        hex_path,
        board=fc.board.board_name,
        mcu=fc.board.target_name,
        git_revision=fc.build.git_revision + "f2",
    )
    subdirectory = project / "scripts"
    subdirectory.mkdir()
    monkeypatch.chdir(subdirectory)
    monkeypatch.delenv(PROJECT_ENV, raising=False)
    code, out, err = run_cli(capsys, "flash", "--backup-dir", str(tmp_path / "b"))
    assert code == 0, err
    assert out.splitlines()[0] == "flashed fw.hex; erased sectors 0, 2"
