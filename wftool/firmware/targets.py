"""The firmware targets wftool builds: SITL, and every board in targets/configs/.

A target says what to pass to Betaflight's make (TARGET=SITL or CONFIG=<BOARD>) and what
the flight controller will report about itself (board name, MCU), which the manifest records
so that `wftool flash` can refuse firmware built for another board.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import UsageError
from wftool.fc.versions import mcu_part
from wftool.firmware.project import Project

SITL = "sitl"

KNOWN_BOARD_PARTS = {"SPEEDYBEEF7V3": "STM32F722"}
"""Boards the lab flies, with the MCU part their config.h must name (by the target name of
any Betaflight version: `wftool.fc.versions.mcu_part`), a guard against a wrong file."""

SITL_DEFINES = ("USE_LATE_TASK_STATISTICS", "ENABLE_GAZEBO_BRIDGE=0", "SITL_ATTITUDE_DIRECT")
"""USE_LATE_TASK_STATISTICS: the virtual FC does not run in real time, so its `tasks` also
reports run counts (reset by each `tasks`): the exact loop rate over a window, which the
stream tests compare with. ENABLE_GAZEBO_BRIDGE=0 and SITL_ATTITUDE_DIRECT: the simulator
input keeps its axes and the attitude is the simulator's quaternion, as `sitl.session`'s
motion sends them (Betaflight 2026.6's SITL otherwise applies the Gazebo plugin's frame
transforms and runs its own attitude estimator on the virtual IMU)."""

_DEFINE = r"^\s*#\s*define\s+{name}\s+(\S+)"


@dataclass(frozen=True)
class Target:
    """One buildable firmware target."""

    name: str
    """The lower-case name used on the command line and for build/<name>/."""
    board: str
    """BOARD_NAME as the flight controller reports it over MSP ("SITL" for the simulator)."""
    mcu: str
    """The Betaflight MCU target (FC_TARGET_MCU), e.g. STM32F7X2 (2025.12) or STM32F722
    (2026.6); "SITL" for the simulator."""
    config: str | None = None
    """The directory name under targets/configs/ that make's CONFIG= selects; None for SITL."""
    config_header: Path | None = None
    """targets/configs/<CONFIG>/config.h, None for SITL."""
    defines: tuple[str, ...] = ()
    """Compiler defines every build of this target gets."""

    @property
    def is_sitl(self) -> bool:
        """SITL builds with the host compiler into a runnable program, not a .hex."""
        return self.config is None

    @property
    def make_vars(self) -> dict[str, str]:
        """The variables that select this target in Betaflight's make."""
        return {"TARGET": "SITL"} if self.config is None else {"CONFIG": self.config}


def board_dirs(project: Project) -> dict[str, Path]:
    """Board definition directories by upper-case name (those that have a config.h)."""
    configs = project.config_dir / "configs"
    if not configs.is_dir():
        return {}
    return {path.name.upper(): path for path in configs.iterdir() if (path / "config.h").is_file()}


def known_targets(project: Project) -> list[str]:
    """Every target name that `resolve_target` accepts, sorted."""
    return [SITL, *sorted(name.lower() for name in board_dirs(project))]


def resolve_target(project: Project, name: str) -> Target:
    """The target called NAME (case-insensitive), or a UsageError that lists the known ones."""
    if name.lower() == SITL:
        return Target(name=SITL, board="SITL", mcu="SITL", defines=SITL_DEFINES)
    boards = board_dirs(project)
    directory = boards.get(name.upper())
    if directory is None:
        hint = ""
        if name.upper() in KNOWN_BOARD_PARTS:
            hint = f" (expected targets/configs/{name.upper()}/config.h in {project.root})"
        raise UsageError(
            f"unknown target {name!r}{hint}; known: {', '.join(known_targets(project))}"
        )
    header = directory / "config.h"
    text = header.read_text(errors="replace")
    mcu = _define(text, "FC_TARGET_MCU")
    if mcu is None:
        raise UsageError(f"{header} does not define FC_TARGET_MCU")
    board = _define(text, "BOARD_NAME") or directory.name
    expected = KNOWN_BOARD_PARTS.get(board.upper())
    if expected is not None and expected != mcu_part(mcu):
        raise UsageError(f"{header} names MCU {mcu}, but {board} is an {expected} board")
    return Target(
        name=directory.name.lower(),
        board=board,
        mcu=mcu,
        config=directory.name,
        config_header=header,
    )


def _define(text: str, name: str) -> str | None:
    """The value of `#define NAME value` in a C header, or None."""
    match = re.search(_DEFINE.format(name=name), text, re.MULTILINE)
    return match.group(1) if match else None
