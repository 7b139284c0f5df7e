"""`wftool doctor`: can this machine build, flash and talk to a flight controller? `--fix`.

Each check says what it found and, when something is missing, how to fix it. `--fix`
installs the one thing wftool can fix itself: udev rules that give the logged-in user the
STM32 bootloader (0483:df11, for dfu-util) and the FC's USB serial port (0483:5740), and
keep ModemManager from probing that port (it grabs new ttyACM devices for seconds).
"""

from __future__ import annotations

import grp
import os
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from serial.tools import list_ports

from wftool.errors import ToolchainError, UsageError
from wftool.firmware import toolchain
from wftool.firmware.project import Project, find_project
from wftool.link.transport import STM32_DFU, STM32_VCP, UsbId

SYSTEM_RULES_DIRS = (
    Path("/etc/udev/rules.d"),
    Path("/usr/lib/udev/rules.d"),
    Path("/lib/udev/rules.d"),
)
RULES_FILE_NAME = "70-wftool.rules"
"""Before 73-seat-late.rules, which turns `uaccess` tags into ACLs: later would be too late."""
UDEV_RULES = f"""\
# Installed by `wftool doctor --fix`: flight controllers for the logged-in user.
# STM32 ROM bootloader (DFU), written by dfu-util during `wftool flash`
SUBSYSTEMS=="usb", ATTRS{{idVendor}}=="{STM32_DFU.vid:04x}", ATTRS{{idProduct}}=="{STM32_DFU.pid:04x}", TAG+="uaccess"
# Betaflight's USB serial port; ModemManager must not probe it
SUBSYSTEMS=="usb", ATTRS{{idVendor}}=="{STM32_VCP.vid:04x}", ATTRS{{idProduct}}=="{STM32_VCP.pid:04x}", TAG+="uaccess", ENV{{ID_MM_DEVICE_IGNORE}}="1"
"""  # noqa: E501 — udev rules are one line each


@dataclass(frozen=True)
class Check:
    name: str
    status: str
    """"ok", "warn" (works, with a caveat) or "fail" (something will not work)."""
    detail: str
    fix: str = ""


def _version_line(program: str) -> str | None:
    """First line of `program --version`, or None if it is not on PATH."""
    path = shutil.which(program)
    if path is None:
        return None
    result = subprocess.run([path, "--version"], capture_output=True, text=True, check=False)
    return (result.stdout or result.stderr).strip().splitlines()[0]


def check_toolchain(project: Project | None = None) -> Check:
    """arm-none-eabi-gcc, found as `wftool build` finds it ($WFTOOL_TOOLCHAIN, the installed
    release, PATH), against the version the pinned Betaflight requires."""
    if project is None:
        try:
            project = find_project()
        except UsageError:
            project = None  # outside a checkout: the pinned release still says the version
    try:
        required, installed = toolchain.arm_requirement(project.tree if project else None)
        found = toolchain.find_arm_toolchain(required, installed=installed)
    except ToolchainError as exc:
        return Check(
            "toolchain",
            "fail",
            str(exc),
            "wftool toolchain install (or apt install gcc-arm-none-eabi libnewlib-arm-none-eabi)",
        )
    if not found.matches:
        return Check(
            "toolchain",
            "warn",
            f"arm-none-eabi-gcc {found.version}; the pinned Betaflight expects {required}: "
            "wftool build warns, --strict-toolchain refuses",
            "`wftool toolchain install` fetches the expected toolchain",
        )
    return Check("toolchain", "ok", f"arm-none-eabi-gcc {found.version} ({found.gcc})")


def check_dfu_util() -> Check:
    line = _version_line("dfu-util")
    if line is None:
        return Check(
            "dfu-util",
            "fail",
            "dfu-util is not on PATH; `wftool flash` needs it",
            "apt install dfu-util",
        )
    return Check("dfu-util", "ok", line)


def check_serial_ports() -> Check:
    ports = list_ports.comports()
    fcs = [p.device for p in ports if (p.vid, p.pid) == (STM32_VCP.vid, STM32_VCP.pid)]
    if fcs:
        return Check("serial ports", "ok", f"flight controller on {', '.join(fcs)}")
    others = ", ".join(p.device for p in ports) or "none"
    return Check(
        "serial ports",
        "warn",
        f"no FC ({STM32_VCP}) connected; ports: {others}",
        "connect the FC by USB (a charge-only cable shows nothing)",
    )


def rules_granting(usb_id: UsbId, rules_dirs: tuple[Path, ...]) -> list[Path]:
    """Rules files with a rule giving users access to `usb_id` (uaccess tag or open mode)."""
    vid = re.compile(rf'idVendor}}=="{usb_id.vid:04x}"', re.IGNORECASE)
    pid = re.compile(rf'idProduct}}=="{usb_id.pid:04x}"', re.IGNORECASE)
    access = re.compile(r'TAG\+="uaccess"|MODE="0?66[46]"|GROUP="(plugdev|dialout)"')
    found = []
    for directory in rules_dirs:
        for path in sorted(directory.glob("*.rules")) if directory.is_dir() else []:
            lines = path.read_text(errors="replace").splitlines()
            if any(vid.search(x) and pid.search(x) and access.search(x) for x in lines):
                found.append(path)
    return found


def check_udev_rules(rules_dirs: tuple[Path, ...]) -> Check:
    missing = [str(u) for u in (STM32_DFU, STM32_VCP) if not rules_granting(u, rules_dirs)]
    if missing:
        return Check(
            "udev rules",
            "fail",
            f"no rule gives users access to {', '.join(missing)}",
            "sudo wftool doctor --fix",
        )
    return Check("udev rules", "ok", f"access to {STM32_DFU} and {STM32_VCP} granted")


def check_groups(user_groups: set[str]) -> Check:
    """dialout/plugdev: the fallback when there is no logged-in seat (ssh, containers)."""
    existing = {g.gr_name for g in grp.getgrall()}
    missing = sorted(g for g in ("dialout", "plugdev") if g in existing and g not in user_groups)
    if missing:
        return Check(
            "groups",
            "warn",
            f"not in {', '.join(missing)}; fine at a desktop (udev uaccess), needed over ssh",
            f"sudo usermod -aG {','.join(missing)} $USER, then log in again",
        )
    return Check("groups", "ok", "dialout/plugdev membership in place (or groups absent)")


def check_modemmanager(proc: Path = Path("/proc"), rules_dirs: tuple[Path, ...] = ()) -> Check:
    running = any(
        (p / "comm").read_text(errors="replace").strip() == "ModemManager"
        for p in proc.iterdir()
        if p.name.isdigit() and (p / "comm").exists()
    )
    if not running:
        return Check("ModemManager", "ok", "not running")
    ignored = any(
        "ID_MM_DEVICE_IGNORE" in path.read_text() for path in rules_granting(STM32_VCP, rules_dirs)
    )
    if ignored:
        return Check("ModemManager", "ok", f"running, but told to ignore {STM32_VCP}")
    return Check(
        "ModemManager",
        "warn",
        "running: it probes new ttyACM ports, garbling MSP for seconds after plug-in",
        "sudo wftool doctor --fix (the rules set ID_MM_DEVICE_IGNORE)",
    )


def current_user_groups() -> set[str]:
    return {grp.getgrgid(gid).gr_name for gid in os.getgroups()}


def run_checks(rules_dirs: tuple[Path, ...] = SYSTEM_RULES_DIRS) -> list[Check]:
    return [
        check_toolchain(),
        check_dfu_util(),
        check_serial_ports(),
        check_udev_rules(rules_dirs),
        check_groups(current_user_groups()),
        check_modemmanager(rules_dirs=rules_dirs),
    ]


def install_udev_rules(rules_dir: Path, *, reload: bool) -> list[str]:
    """Write wftool's rules file into `rules_dir`; return what changed."""
    path = rules_dir / RULES_FILE_NAME
    if path.exists() and path.read_text() == UDEV_RULES:
        return [f"{path} is already up to date"]
    try:
        rules_dir.mkdir(parents=True, exist_ok=True)
        path.write_text(UDEV_RULES)
    except PermissionError as exc:
        raise UsageError(f"cannot write {path}: run it as root (sudo wftool doctor --fix)") from exc
    changes = [f"wrote {path}"]
    if reload and shutil.which("udevadm"):
        for args in (["control", "--reload-rules"], ["trigger", "--subsystem-match=usb"]):
            subprocess.run(["udevadm", *args], check=False)
        changes.append("reloaded udev rules; replug the FC")
    return changes
