"""`wftool flash` on a virtual board: the real SITL plays the FC (MSP, the `diff all` backup,
the reboot into the bootloader, the FC coming back), the real dfu-util and libusb write the
emulated STM32F722 bootloader's flash, and test scaffolding joins the two
(tests/flash/virtual_board.py). Judged by reading the emulated flash afterwards.

SITL comes back running its own build, so the synthetic images here carry the SITL's build
identity; `test_wftool_flash_on_a_virtual_speedybeef7v3` flashes the real board build.
"""

from __future__ import annotations

import os
import signal
import threading
from dataclasses import replace
from pathlib import Path

import pytest

from tests.conftest import fc_settings, run_cli
from tests.fc.faulty_transport import InjectFaults
from tests.fc.stand_in import identity_replies, msp_stand_in
from tests.flash.emulator import EmulatedBootloader
from tests.flash.images import (
    CONFIG_SECTOR,
    FLASH_BASE,
    OLD_FLASH,
    VECTORS,
    firmware_hex,
    image_bytes,
    sector,
    sector_span,
)
from tests.flash.virtual_board import SPEEDYBEEF7V3, VirtualBoard
from wftool.cli import fc as fc_commands
from wftool.errors import FlashError, UnsupportedFirmware, UsageError
from wftool.fc.board import SerialBoard
from wftool.fc.msp import BoardInfo, BuildInfo, MspClient
from wftool.fc.params import apply_plan
from wftool.fc.plan import plan_from_assignments
from wftool.firmware import BuildResult
from wftool.firmware.manifest import BuildFlags, Manifest
from wftool.firmware.project import PROJECT_ENV
from wftool.flash.flasher import find_manifest, flash_firmware, resolve_firmware
from wftool.flash.image import load_image
from wftool.sitl.process import VirtualFC

MSP_SET_BOARD_INFO = 248


def _build_of(board: VirtualBoard | VirtualFC) -> BuildInfo:
    with MspClient.open(board.url) as msp:
        return msp.build_info()


def _image(board: VirtualBoard, path: Path, *strings: str, vectors: bytes = VECTORS) -> Path:
    """An image the virtual board runs once flashed: its SITL's identity, STRINGS."""
    return firmware_hex(path, _build_of(board), *strings, vectors=vectors)


def _config(board: VirtualBoard) -> bytes:
    """What the FC keeps its configuration in (SITL: eeprom.bin), as the config sector."""
    start, end = sector_span(CONFIG_SECTOR)
    return board.eeprom.read_bytes()[: end - start]


def _one_line(error: pytest.ExceptionInfo[Exception]) -> str:
    message = str(error.value)
    assert "\n" not in message
    return message


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


def test_flash_backs_up_writes_around_the_config_reads_back_and_confirms(
    virtual_board: VirtualBoard, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    apply_plan(virtual_board, plan_from_assignments(["p_pitch=55"]), tmp_path / "setup")
    config = _config(virtual_board)
    hex_path = _image(virtual_board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
    log: list[str] = []
    report = flash_firmware(virtual_board, hex_path, backup_dir=tmp_path / "b", log=log.append)

    assert report.backup is not None and "defaults nosave" in report.backup.read_text()
    assert b"[system]ResetToBootloader!" in virtual_board.fc.log_path.read_bytes()
    flash = bootloader.flash()
    segments = image_bytes(hex_path)
    for address, data in segments:  # every image region, byte for byte
        assert flash[address - FLASH_BASE : address - FLASH_BASE + len(data)] == data
    assert sector(flash, CONFIG_SECTOR) == config  # the config sector as the FC left it
    for untouched in (3, 4, 5, 6, 7):  # sectors the image does not need: never erased
        assert sector(flash, untouched) == sector(OLD_FLASH, untouched)
    assert [event[1] for event in bootloader.events("erase")] == [0x0800_0000, 0x0800_8000]
    assert report.erased == {0, 2}
    assert report.verified == sum(len(data) for _, data in segments)
    assert len(bootloader.events("upload")) >= 2  # read back before leaving
    left = bootloader.left()
    assert left is not None and (left.address, left.jumped, left.runs) == (FLASH_BASE, True, True)
    assert report.after.build == _build_of(virtual_board)
    assert "starting the firmware at 0x08000000" in log
    assert fc_settings(virtual_board.fc, "p_pitch") == {"p_pitch": "55"}  # config survived


def test_full_erase_wipes_the_config_and_restore_replays_the_backup(
    virtual_board: VirtualBoard, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    apply_plan(virtual_board, plan_from_assignments(["p_pitch=55"]), tmp_path / "setup")
    hex_path = _image(virtual_board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
    report = flash_firmware(
        virtual_board, hex_path, backup_dir=tmp_path / "b", full_erase=True, restore=True
    )
    assert [event[:2] for event in bootloader.events() if "erase" in event[0]] == [
        ["mass_erase"],
        ["erase", 0x0800_8000],  # the second download erases its sector again: harmless
    ]
    assert sector(bootloader.flash(), CONFIG_SECTOR) == b"\xff" * (16 << 10)
    assert report.restored is not None
    assert [(r.name, r.before, r.after) for r in report.restored.rows] == [
        ("p_pitch", "47", "55")  # the FC came back with defaults; the backup put 55 back
    ]
    assert fc_settings(virtual_board.fc, "p_pitch") == {"p_pitch": "55"}


def test_a_silently_corrupted_write_is_found_and_the_board_stays_in_dfu(
    virtual_board: VirtualBoard, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    hex_path = _image(virtual_board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
    bootloader.inject(corrupt_write_at=0x0800_8000 + 100)
    with pytest.raises(FlashError) as error:
        flash_firmware(virtual_board, hex_path, backup_dir=tmp_path / "b")
    written = dict(image_bytes(hex_path))[0x0800_8000][100]
    assert written != 0
    backups = list((tmp_path / "b").iterdir())
    assert _one_line(error) == (
        "verifying the flash: the flash does not read back as written (1 byte(s) differ from "
        f"0x08008000 on; the first, at 0x08008064, holds 0x{written & (written - 1):02x}, not "
        f"0x{written:02x}); the board stays in its bootloader — configuration backup: "
        f"{backups[0]} (`wftool restore {backups[0]}`); if the FC stays in DFU, retry with "
        f"`wftool flash --no-reboot {hex_path}`"
    )
    assert bootloader.left() is None and bootloader.attached  # not left: no leave
    assert not virtual_board.fc.running


@pytest.mark.parametrize(
    ("fault", "says"),
    [
        (
            {"write_fails_at": 0x0800_8000},
            "dfu-util failed writing at 0x08008000 (exit 74): DFU state(10) = dfuERROR, "
            "status(3) = Device is unable to write memory; dfu-util: Failed to write whole "
            "chunk: -1 of 2048 bytes",
        ),
        (
            {"erase_fails_at": 0x0800_0000},
            "dfu-util failed writing at 0x08000000 (exit 74): dfu-util: ERASE_PAGE not "
            "correctly executed",
        ),
    ],
)
def test_a_failed_write_names_the_backup_and_a_retry_recovers(
    virtual_board: VirtualBoard,
    bootloader: EmulatedBootloader,
    tmp_path: Path,
    fault: dict[str, int],
    says: str,
) -> None:
    hex_path = _image(virtual_board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
    bootloader.inject(**fault)
    with pytest.raises(FlashError) as error:
        flash_firmware(virtual_board, hex_path, backup_dir=tmp_path / "b")
    (backup,) = (tmp_path / "b").iterdir()
    assert _one_line(error) == (
        f"writing the firmware: {says} — configuration backup: {backup} (`wftool restore "
        f"{backup}`); if the FC stays in DFU, retry with `wftool flash --no-reboot {hex_path}`"
    )
    assert bootloader.attached and bootloader.left() is None
    bootloader.inject()  # the retry the message advises, on the board still in DFU
    report = flash_firmware(virtual_board, hex_path, backup_dir=tmp_path / "b", no_reboot=True)
    assert report.after.build == _build_of(virtual_board)


def test_a_board_vanishing_mid_download_is_a_clear_error(
    virtual_board: VirtualBoard, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    hex_path = _image(virtual_board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
    bootloader.inject(vanish_after_blocks=2)
    with pytest.raises(FlashError) as error:
        flash_firmware(virtual_board, hex_path, backup_dir=tmp_path / "b")
    (backup,) = (tmp_path / "b").iterdir()
    assert _one_line(error).startswith(
        "writing the firmware: dfu-util failed writing at 0x08008000 (exit 74): dfu-util: "
        "Error during download get_status; the board left USB (unplugged, or reset?) — "
        f"configuration backup: {backup}"
    )
    assert not bootloader.attached


def test_a_bootloader_that_never_appears_times_out(
    sitl_binary: Path, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    fc = VirtualFC(sitl_binary, tmp_path / "sitl", port_base=None)
    with VirtualBoard(fc, bootloader, bootloader_appears=False) as board:
        hex_path = _image(board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
        with pytest.raises(FlashError) as error:
            flash_firmware(board, hex_path, backup_dir=tmp_path / "b", dfu_timeout=2)
    (backup,) = (tmp_path / "b").iterdir()
    assert _one_line(error).startswith(
        "waiting for the DFU bootloader: no DFU device 0483:df11 appeared within 2 s: hold the "
        "board's BOOT button"
    )
    assert f"configuration backup: {backup}" in str(error.value)
    assert bootloader.flash() == OLD_FLASH


def test_an_image_that_would_not_boot_is_refused_before_anything_happens(
    virtual_board: VirtualBoard, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    hex_path = _image(virtual_board, tmp_path / "fw.hex", "SITL", "STM32F7X2", vectors=b"")
    with pytest.raises(UsageError) as error:
        flash_firmware(virtual_board, hex_path, backup_dir=tmp_path / "b")
    assert _one_line(error) == (
        "refusing to flash fw.hex: the board would not boot from it (0x03020100 at 0x08000000 "
        "is not an initial stack pointer in RAM; --force overrides)"
    )
    assert virtual_board.fc.running and virtual_board.fc.starts == 1
    assert not (tmp_path / "b").exists() and bootloader.events("attached") == []


def test_forced_onto_the_board_such_an_image_leaves_it_dark(
    virtual_board: VirtualBoard, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    hex_path = _image(virtual_board, tmp_path / "fw.hex", "SITL", "STM32F7X2", vectors=b"")
    with pytest.raises(FlashError) as error:
        flash_firmware(
            virtual_board, hex_path, backup_dir=tmp_path / "b", force=True, boot_timeout=2
        )
    assert _one_line(error).startswith(
        "waiting for the new firmware to start: the flight controller did not come back "
        "within 2 s — configuration backup: "
    )
    left = bootloader.left()
    assert left is not None and (left.jumped, left.runs) == (False, False)


def test_mismatched_firmware_is_refused_before_anything_happens(
    virtual_board: VirtualBoard, bootloader: EmulatedBootloader, built_hex: Path, tmp_path: Path
) -> None:
    with pytest.raises(
        UsageError, match=r"refusing to flash .*the image does not name the FC's target SITL"
    ):
        flash_firmware(virtual_board, built_hex, backup_dir=tmp_path / "backups")
    assert virtual_board.fc.running and virtual_board.fc.starts == 1
    assert not (tmp_path / "backups").exists()
    assert bootloader.events("attached") == [] and bootloader.flash() == OLD_FLASH


def test_no_reboot_flashes_a_board_already_in_dfu(
    virtual_board: VirtualBoard, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    hex_path = _image(virtual_board, tmp_path / "fw.hex", "STM32F7X2")
    virtual_board.enter_bootloader()  # BOOT held at power-up
    report = flash_firmware(virtual_board, hex_path, backup_dir=tmp_path / "b", no_reboot=True)
    assert report.backup is None and report.before is None
    assert report.after.build == _build_of(virtual_board)
    assert not (tmp_path / "b").exists()


def test_no_reboot_with_full_erase_needs_force(tmp_path: Path) -> None:
    build = BuildInfo("Jan 01 2000", "00:00:00", "abcdef0")
    hex_path = firmware_hex(tmp_path / "fw.hex", build, "STM32F7X2")
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


@pytest.mark.parametrize("built_for", ["STM32F7X2", "STM32F722"])
def test_a_board_of_either_versions_mcu_name_takes_a_build_of_the_other(
    tmp_path: Path, built_for: str
) -> None:
    """2025.12 reports the F722 target as STM32F7X2, 2026.6 as STM32F722 (#15470): the same
    part, so a board on either takes a build of either; another part is still refused."""
    hex_path = firmware_hex(tmp_path / "fw.hex", BuildInfo("Jan  1 2026", "00:00:00", "0000000"))
    manifest = _manifest(tmp_path / "build" / "sb", hex_path, mcu=built_for)
    for reported in ("STM32F7X2", "STM32F722"):
        board = BoardInfo("S7X2", 0, 0, reported, "", "", 0)  # no board name: by the MCU
        assert find_manifest(tmp_path / "build", board) == Manifest.load(manifest)
        firmware = resolve_firmware(manifest, None, board)
        assert firmware.compatibility_problems(board) == []
        assert firmware.mcu_flash(board).config_address == 0x0800_4000
    other = BoardInfo("S405", 0, 0, "STM32F405", "", "", 0)
    problems = resolve_firmware(manifest, None, other).compatibility_problems(other)
    assert problems == [f"built for {built_for}, the FC is STM32F405"]


def test_an_fc_on_a_firmware_wftool_does_not_know_is_not_flashed_without_a_backup(
    tmp_path: Path,
) -> None:
    """A STAND-IN answering MSP as upstream master does: its `diff all` cannot be proven
    complete, so nothing happens; the message says how to flash it all the same."""
    hex_path = firmware_hex(tmp_path / "fw.hex", BuildInfo("Jan  1 2026", "00:00:00", "0000000"))
    with (
        msp_stand_in(identity_replies("2026.12.0", (1, 49))) as url,
        pytest.raises(
            UnsupportedFirmware,
            match=r"the FC runs BTFL 2026\.12\.0 .*; so its "
            r"configuration cannot be backed up: .* `wftool flash --no-reboot",
        ),
    ):
        flash_firmware(SerialBoard(url), hex_path, backup_dir=tmp_path / "b")
    assert not (tmp_path / "b").exists()


def test_bad_manifest_is_a_usage_error(tmp_path: Path) -> None:
    path = tmp_path / "manifest.json"
    path.write_text('{"target": "X"}')
    with pytest.raises(UsageError, match="bad build manifest"):
        Manifest.load(path)


def test_wftool_flash_command_end_to_end(
    on_board: VirtualBoard, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hex_path = _image(on_board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
    code, out, err = run_cli(capsys, "flash", str(hex_path), "--backup-dir", str(tmp_path / "b"))
    assert code == 0, err
    verified = sum(len(data) for _, data in image_bytes(hex_path))
    assert out.splitlines()[0] == (
        f"flashed fw.hex; erased sectors 0, 2; {verified} bytes read back as written"
    )
    assert "Download" in err and "Verify" in err and "100%" in err  # the progress bars


def test_an_image_for_another_mcu_is_bad_input(
    on_board: VirtualBoard,
    bootloader: EmulatedBootloader,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    hex_path = _image(on_board, tmp_path / "fw.hex", "STM32F7X2")  # not "SITL"
    code, _, err = run_cli(capsys, "flash", str(hex_path), "--backup-dir", str(tmp_path / "b"))
    assert (code, err.splitlines()[-1]) == (
        2,
        "error: refusing to flash fw.hex: the image does not name the FC's target SITL "
        "(--force overrides)",
    )
    assert bootloader.events("attached") == [] and on_board.fc.starts == 1


def test_a_board_name_no_image_can_hold_is_a_mismatch_not_a_crash(
    on_board: VirtualBoard,
    bootloader: EmulatedBootloader,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    name = b"Qu\xe4d"  # Betaflight takes any bytes (MSP_SET_BOARD_INFO); MSP text is ASCII
    with MspClient.open(on_board.fc.url) as msp:
        msp.request(MSP_SET_BOARD_INFO, bytes([len(name)]) + name + b"\x00")
    hex_path = _image(on_board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
    code, _, err = run_cli(capsys, "flash", str(hex_path), "--backup-dir", str(tmp_path / "b"))
    assert (code, err.splitlines()[-1]) == (
        2,
        "error: refusing to flash fw.hex: the image does not name the FC's board Qu\ufffdd "
        "(--force overrides)",
    )
    assert bootloader.events("attached") == [] and on_board.fc.starts == 1


def test_full_erase_does_not_happen_after_an_incomplete_backup(
    on_board: VirtualBoard,
    bootloader: EmulatedBootloader,
    tmp_path: Path,
    inject_faults: InjectFaults,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # The FC's `diff all` loses its rest after a `# ` line (tests/fc/faulty_transport.py).
    faults = inject_faults(stall_after_comment=5, stall_s=None)
    hex_path = _image(on_board, tmp_path / "fw.hex", "SITL", "STM32F7X2")
    code, _, err = run_cli(capsys, "flash", str(hex_path), "--full-erase", "--backup-dir",
                           str(tmp_path / "b"))  # fmt: skip
    assert faults.fired and faults.fired[0].startswith("`diff all` lost the rest")
    assert code == 1
    assert err.splitlines()[-1].startswith("error: the FC's `diff all` output on ")
    assert "incomplete" in err.splitlines()[-1]
    assert bootloader.events("attached") == []  # never in DFU, never erased
    assert bootloader.flash() == OLD_FLASH
    assert b"ResetToBootloader" not in on_board.fc.log_path.read_bytes()
    assert list((tmp_path / "b").iterdir()) == []
    assert _build_of(on_board).git_revision  # out of its CLI: it answers MSP


def _project(root: Path) -> Path:
    """A directory that is a wftool project (its .gitmodules declares betaflight/)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / ".gitmodules").write_text('[submodule "betaflight"]\n\tpath = betaflight\n')
    return root


def test_default_firmware_is_found_through_the_project_not_the_cwd(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    project = _project(tmp_path / "checkout")
    build = BuildInfo("Jan 01 2000", "00:00:00", "abcdef0")
    hex_path = firmware_hex(project / "fw.hex", build)
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
    on_board: VirtualBoard,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    with MspClient.open(on_board.url) as msp:
        fc = msp.identify()
    project = _project(tmp_path / "checkout")
    hex_path = firmware_hex(project / "fw.hex", fc.build, "STM32F7X2")
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
    assert out.splitlines()[0].startswith("flashed fw.hex; erased sectors 0, 2; ")


def test_wftool_flash_on_a_virtual_speedybeef7v3(
    sitl_build: BuildResult,
    board_build: BuildResult,
    bootloader: EmulatedBootloader,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The whole `wftool flash`, no FIRMWARE named: the board build of this session onto a
    virtual SPEEDYBEEF7V3 (the session's SITL, presented as that board by the scaffolding)."""
    fc = VirtualFC(sitl_build.firmware, tmp_path / "sitl", port_base=None)
    with VirtualBoard(fc, bootloader, identity=SPEEDYBEEF7V3) as board:
        monkeypatch.setattr(fc_commands, "find_board", lambda port, present=True: board)
        apply_plan(board, plan_from_assignments(["p_pitch=55"]), tmp_path / "setup")
        config = _config(board)
        build_dir = board_build.manifest.path.parent.parent
        code, out, err = run_cli(capsys, "flash", "--build-dir", str(build_dir), "--restore",
                                 "--backup-dir", str(tmp_path / "b"))  # fmt: skip
        assert code == 0, err
        image = load_image(board_build.firmware)
        segments = [(s, bytes(image.tobinarray(start=s, size=e - s))) for s, e in image.segments()]
        lines = out.splitlines()
        assert lines[0] == (
            f"flashed {board_build.firmware.name}; erased sectors 0, 2, 3, 4, 5, 6, 7; "
            f"{sum(len(data) for _, data in segments)} bytes read back as written"
        )
        assert lines[1].startswith(f"configuration backup: {tmp_path / 'b'}/SPEEDYBEEF7V3-")
        flash = bootloader.flash()
        for address, data in segments:
            assert flash[address - FLASH_BASE : address - FLASH_BASE + len(data)] == data
        assert sector(flash, CONFIG_SECTOR) == config
        end = segments[-1][0] + len(segments[-1][1]) - FLASH_BASE
        assert flash[end : sector_span(7)[1]] == b"\xff" * (sector_span(7)[1] - end)
        assert [e[1] for e in bootloader.events("erase")] == [
            0x0800_0000, 0x0800_8000, 0x0800_C000, 0x0801_0000, 0x0802_0000, 0x0804_0000,
            0x0806_0000,
        ]  # fmt: skip
        left = bootloader.left()
        assert left is not None and (left.address, left.jumped, left.runs) == (
            FLASH_BASE, True, True
        )  # fmt: skip
        assert "p_pitch" in out  # --restore replayed the backup: its report
        assert fc_settings(board.fc, "p_pitch") == {"p_pitch": "55"}


def test_the_virtual_boards_port_lets_go_as_the_fcs_does(
    sitl_binary: Path, bootloader: EmulatedBootloader, tmp_path: Path
) -> None:
    """Scaffolding check: through the identity bridge, a link's close waits for the FC to let
    go of the connection, as on the FC's own port (a close that did not was followed by a
    connection the FC dropped: "New connection on UART1, 1"). The FC stopped, the close
    waits; the FC running again, it returns."""
    fc = VirtualFC(sitl_binary, tmp_path / "sitl", port_base=None)
    with VirtualBoard(fc, bootloader, identity=SPEEDYBEEF7V3) as board:
        msp = MspClient.open(board.url)
        assert msp.board_info().board_identifier == SPEEDYBEEF7V3.identifier
        assert fc._process is not None
        os.kill(fc._process.pid, signal.SIGSTOP)
        try:
            closing = threading.Thread(target=msp.close)
            closing.start()
            closing.join(0.05)  # well within the close's release timeout (0.3 s)
            assert closing.is_alive(), "the close returned while the FC held the connection"
        finally:
            os.kill(fc._process.pid, signal.SIGCONT)
        closing.join()
        for _ in range(5):  # and links opened at once after a close are served
            with MspClient.open(board.url) as msp:
                assert msp.board_info().board_identifier == SPEEDYBEEF7V3.identifier
