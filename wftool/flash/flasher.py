"""`wftool flash`: identify, back up, reboot to DFU, write, read back, leave, confirm — the
config sector untouched.

Order matters: an image that does not fit the FC, or would not boot (no vector table at its
start), is refused (`UsageError`, exit 2) before anything happens; nothing is erased before
a configuration backup proven complete exists; every failure after that names the backup
and the next step. What was written is read back and compared before the bootloader is
left (as Betaflight Configurator verifies): a difference is an error and the board stays in
its bootloader. Success means the firmware that comes back reports a build (date, time,
git revision) that is in the image just written.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from intelhex import IntelHex

from wftool.errors import FlashError, UnsupportedFirmware, UsageError, WftoolError
from wftool.fc.board import Board, leave_open_cli
from wftool.fc.msp import BoardInfo, BuildInfo, FcIdentity, MspClient, RebootMode
from wftool.fc.params import ChangeReport, apply_plan, configuration_session
from wftool.fc.plan import plan_from_file
from wftool.fc.versions import mcu_part, mcu_targets, version_of
from wftool.firmware.manifest import FILE_NAME, Manifest
from wftool.firmware.project import find_project
from wftool.flash.backend import FlashBackend, Progress
from wftool.flash.dfu import DfuBackend
from wftool.flash.image import (
    MCU_FLASH,
    McuFlash,
    contains_string,
    erased_sectors,
    load_image,
    vector_table_problem,
    write_regions,
)
from wftool.progress import Log, quiet


@dataclass
class Firmware:
    path: Path
    image: IntelHex
    manifest: Manifest | None

    def compatibility_problems(self, board: BoardInfo) -> list[str]:
        """Why this image should not go on `board` (empty if it fits)."""
        problems = []
        if self.manifest:
            if not same_mcu(self.manifest.mcu, board.target_name):
                problems.append(f"built for {self.manifest.mcu}, the FC is {board.target_name}")
            if board.board_name and self.manifest.board != board.board_name:
                problems.append(
                    f"built for board {self.manifest.board}, the FC is {board.board_name}"
                )
            return problems
        for kind, name in (("target", board.target_name), ("board", board.board_name)):
            if name and not contains_string(self.image, name):
                problems.append(f"the image does not name the FC's {kind} {name}")
        return problems

    def is_running(self, build: BuildInfo) -> bool:
        """Whether the FC's reported build is this image."""
        if self.manifest and not self.manifest.git_revision.startswith(build.git_revision):
            return False
        return (
            contains_string(self.image, build.date)
            and contains_string(self.image, build.time)
            and contains_string(self.image, build.git_revision, whole=False)
        )

    def mcu_flash(self, board: BoardInfo | None) -> McuFlash:
        """Flash facts for this image's MCU: named by the manifest, the FC, or the image (by
        the target name of any Betaflight version wftool knows)."""
        names = [self.manifest.mcu] if self.manifest else []
        names += [board.target_name] if board else []
        names += sorted(name for name in mcu_targets() if contains_string(self.image, name))
        for name in names:
            if (part := mcu_part(name)) in MCU_FLASH:
                return MCU_FLASH[part]
        raise UsageError(
            f"wftool knows the flash layout of {', '.join(MCU_FLASH)} only "
            f"(this is for {', '.join(names) or 'an unknown MCU'})"
        )


def same_mcu(one: str, other: str) -> bool:
    """Whether two MCU target names are one part (STM32F7X2 of 2025.12 is 2026.6's STM32F722)."""
    return one == other or (mcu_part(one) or one) == (mcu_part(other) or other)


def find_manifest(build_dir: Path, board: BoardInfo) -> Manifest | None:
    """The newest build output for this FC: same board name, or same MCU for boards without."""
    manifests = sorted(
        (Manifest.load(p) for p in build_dir.glob(f"*/{FILE_NAME}")),
        key=lambda m: m.path.stat().st_mtime,
        reverse=True,
    )
    for manifest in manifests:
        if (
            (manifest.board == board.board_name)
            if board.board_name
            else same_mcu(manifest.mcu, board.target_name)
        ):
            return manifest
    return None


def resolve_firmware(
    path: Path | None, build_dir: Path | None, board: BoardInfo | None
) -> Firmware:
    """FIRMWARE as given (manifest .json, .hex, .bin), or the last build for this board in
    BUILD_DIR (default: the build/ of the wftool project around the current directory)."""
    manifest = None
    if path is None:
        if board is None:
            raise UsageError(
                "name the FIRMWARE to flash: without the FC's answer (--no-reboot) "
                "wftool cannot pick its build"
            )
        if build_dir is None:
            build_dir = find_project().build_dir
        manifest = find_manifest(build_dir, board)
        if manifest is None:
            raise UsageError(
                f"no `wftool build` output for {board.board_name or board.target_name} in "
                f"{build_dir}/; build it or name the FIRMWARE"
            )
    elif path.suffix.lower() == ".json":
        manifest = Manifest.load(path)
    if manifest is not None:
        path = manifest.hex or manifest.bin
        if path is None:
            raise UsageError(f"{manifest.path} lists no hex or bin artifact")
    assert path is not None
    return Firmware(path, load_image(path), manifest)


@dataclass
class FlashReport:
    firmware: Firmware
    backup: Path | None
    erased: set[int]
    verified: int
    """Bytes read back from the board and found as written."""
    before: FcIdentity | None
    after: FcIdentity
    restored: ChangeReport | None


def flash_firmware(
    board: Board,
    firmware_path: Path | None,
    *,
    backup_dir: Path,
    build_dir: Path | None = None,
    force: bool = False,
    full_erase: bool = False,
    no_reboot: bool = False,
    restore: bool = False,
    dfu_timeout: float = 30.0,
    boot_timeout: float = 30.0,
    progress: Progress | None = None,
    log: Log = quiet,
    backend: FlashBackend | None = None,
) -> FlashReport:
    """The whole `wftool flash` flow; see the module docstring. BACKEND writes the flash
    (default: dfu-util); PROGRESS gets its reports."""
    backend = backend or DfuBackend()
    before = None
    if not no_reboot:
        leave_open_cli(board, log)
        with MspClient.open(board.url) as msp:
            before = msp.identify()
        try:
            version_of(before)  # its backup needs to know it
        except UnsupportedFirmware as exc:
            raise UnsupportedFirmware(
                f"{exc}; so its configuration cannot be backed up: to flash it all the same, "
                "without a backup, put it in DFU mode and run `wftool flash --no-reboot FIRMWARE`"
            ) from None
    firmware = resolve_firmware(firmware_path, build_dir, before.board if before else None)
    if firmware.manifest:
        built = firmware.manifest
        log(f"firmware: {firmware.path} ({built.target} at {built.git_revision})")
    else:
        log(f"firmware: {firmware.path}")
    if before and (problems := firmware.compatibility_problems(before.board)):
        if not force:
            raise UsageError(
                f"refusing to flash {firmware.path.name}: {'; '.join(problems)} (--force overrides)"
            )
        log(f"--force: flashing despite: {'; '.join(problems)}")
    mcu = firmware.mcu_flash(before.board if before else None)
    regions = write_regions(firmware.image, mcu.layout)
    erased = erased_sectors(regions, mcu.layout)
    if mcu.config_sector in erased and not full_erase:
        raise UsageError(
            f"{firmware.path.name} covers the config sector at 0x{mcu.config_address:08x} "
            "(a .bin does; use the .hex), or pass --full-erase to wipe the configuration"
        )
    start = regions[0].address
    if (problem := vector_table_problem(firmware.image, start, mcu)) and not force:
        raise UsageError(
            f"refusing to flash {firmware.path.name}: the board would not boot from it "
            f"({problem}; --force overrides)"
        )
    if no_reboot and full_erase and not force:
        raise UsageError(
            "--full-erase with --no-reboot erases the configuration without a "
            "backup; add --force if that is what you want"
        )

    backup = None
    if before is not None:
        with configuration_session(board, backup_dir, log) as connected:
            session, msp, backup = connected.cli, connected.msp, connected.backup
            session.exit_noreboot()
            mode = (
                RebootMode.BOOTLOADER_FLASH
                if before.board.has_flash_bootloader
                else RebootMode.BOOTLOADER_ROM
            )
            log(f"rebooting the FC into its {mode.name.lower().replace('_', ' ')}")
            msp.reboot(mode)
    next_step = _next_step(firmware.path, backup)

    stage = "waiting for the DFU bootloader"
    try:
        device = backend.wait_for_device(dfu_timeout)
        if device.layout and device.layout != mcu.layout and not force:
            raise FlashError(
                f"the bootloader reports flash {device.name!r}, not the layout "
                "of the firmware's MCU (--force overrides)"
            )
        stage = "writing the firmware"
        for index, region in enumerate(regions):
            log(
                f"writing {len(region.data)} bytes at 0x{region.address:08x} "
                f"({index + 1}/{len(regions)})"
            )
            backend.write(
                device,
                region.address,
                region.data,
                mass_erase=full_erase and index == 0,
                progress=progress,
            )
        stage = "verifying the flash"
        verified = 0
        for region in regions:
            log(f"reading back {len(region.data)} bytes at 0x{region.address:08x}")
            read = backend.read(
                device, region.address, len(region.data), progress=_as_phase("Verify", progress)
            )
            if problem := _difference(region.address, region.data, read):
                raise FlashError(
                    f"the flash does not read back as written ({problem}); the board stays "
                    "in its bootloader"
                )
            verified += len(read)
        stage = "leaving the bootloader"
        log(f"starting the firmware at 0x{start:08x}")
        if remark := backend.leave(device, start):
            log(remark)
        stage = "waiting for the new firmware to start"
        board.wait_back(boot_timeout)
        with MspClient.open(board.url) as msp:
            after = msp.identify()
        if not firmware.is_running(after.build):
            build = after.build
            raise FlashError(
                f"the FC that came back runs {build.git_revision} built {build.date} "
                f"{build.time}, which is not {firmware.path.name}"
            )
    except WftoolError as exc:
        raise FlashError(f"{stage}: {exc} — {next_step}") from exc
    log(f"the FC runs {after.build.git_revision} built {after.build.date} {after.build.time}")
    restored = None
    if restore and backup is not None:
        log(f"restoring the configuration from {backup}")
        restored = apply_plan(board, plan_from_file(backup), backup_dir, log)
    return FlashReport(firmware, backup, erased, verified, before, after, restored)


def _as_phase(phase: str, progress: Progress | None) -> Progress | None:
    """PROGRESS, reporting every update as PHASE."""
    if progress is None:
        return None
    return lambda _phase, percent, done: progress(phase, percent, done)


def _difference(address: int, written: bytes, read: bytes) -> str | None:
    """Where READ differs from WRITTEN (both at ADDRESS), or None."""
    if read == written:
        return None
    if len(read) != len(written):
        return f"{len(read)} bytes came back for {len(written)} at 0x{address:08x}"
    offsets = [i for i, (a, b) in enumerate(zip(written, read)) if a != b]
    first = offsets[0]
    return (
        f"{len(offsets)} byte(s) differ from 0x{address:08x} on; the first, at "
        f"0x{address + first:08x}, holds 0x{read[first]:02x}, not 0x{written[first]:02x}"
    )


def _next_step(firmware: Path, backup: Path | None) -> str:
    saved = (
        f"configuration backup: {backup} (`wftool restore {backup}`)"
        if backup
        else "no configuration backup was taken (--no-reboot)"
    )
    return f"{saved}; if the FC stays in DFU, retry with `wftool flash --no-reboot {firmware}`"
