"""Driving Betaflight's make: one make process, progress reports, a full log, a short error
(how it is driven: docs/build.md).
"""

from __future__ import annotations

import os
import re
import subprocess
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from wftool.errors import BuildError
from wftool.progress import Progress, no_progress

HOOK_MAKEFILE = """\
# Written by wftool and read after Betaflight's Makefile (make -f Makefile -f wftool.mk).
# It reports what wftool records in manifest.json and builds every output in one make.
$(info wftool-var elf=$(abspath $(TARGET_ELF)))
$(info wftool-var hex=$(abspath $(TARGET_HEX)))
$(info wftool-var bin=$(abspath $(TARGET_BIN)))
$(info wftool-var exe=$(abspath $(TARGET_EXE)))
$(info wftool-var output=$(DEFAULT_OUTPUT))
$(info wftool-var revision=$(REVISION))
$(info wftool-var version=$(FC_VER))
$(info wftool-var flash_kb=$(TARGET_FLASH_SIZE))
$(info wftool-var mcu=$(TARGET))
$(info wftool-var objects=$(words $(TARGET_OBJS)))

.PHONY: wftool-firmware
wftool-firmware: $(if $(filter exe,$(DEFAULT_OUTPUT)),$(TARGET_EXE),$(TARGET_HEX) $(TARGET_BIN))

# wftool lets ccache serve units by direct mode despite __TIME__ (the STM32 HAL names macro
# parameters so); version.c expands __DATE__ and __TIME__, and must be compiled for its date.
$(TARGET_OBJ_DIR)/build/version.o: export CCACHE_SLOPPINESS :=
"""
GOAL = "wftool-firmware"

_VAR_LINE = re.compile(r"^wftool-var (\w+)=(.*)$")
_UNIT_DRY = re.compile(r'^echo "%% (?:\([^)]*\) )?(?P<source>[^"\s]+)')
_UNIT_RUN = re.compile(r"^%% ")
_LINKING = re.compile(r"^Linking ")
_COMPILER_ERROR = re.compile(
    r"^(?P<file>[^\s:][^:]*):(?P<line>\d+):(?:\d+:)? (?:fatal )?error: (?P<message>.+)$"
)
_ANY_ERROR = re.compile(r"(error|undefined reference|\*\*\*)", re.IGNORECASE)
_MEMORY_REGION = re.compile(
    r"^\s*(?P<name>[A-Z0-9_]+):\s+(?P<used>[\d.]+)\s*(?P<used_unit>[KMG]?B)"
    r"\s+(?P<size>[\d.]+)\s*(?P<size_unit>[KMG]?B)"
)
_SIZE_ROW = re.compile(r"^\s*(?P<text>\d+)\s+(?P<data>\d+)\s+(?P<bss>\d+)\s+\d+\s+[0-9a-f]+\s+\S")
_UNITS = {"B": 1, "KB": 1024, "MB": 1024**2, "GB": 1024**3}


@dataclass(frozen=True)
class Usage:
    """Memory the firmware uses; totals are None where the target has no fixed memory (SITL)."""

    flash_bytes: int
    flash_total: int | None
    ram_bytes: int
    ram_total: int | None


@dataclass(frozen=True)
class MakeCommand:
    """One invocation of Betaflight's make for one target and one set of flags."""

    tree: Path
    variables: Mapping[str, str]
    jobs: int
    hook: Path
    env: Mapping[str, str] = field(default_factory=dict)

    def argv(self, *, dry_run: bool = False) -> list[str]:
        """The make command line."""
        return [
            "make",
            "-C",
            str(self.tree),
            "-f",
            "Makefile",
            "-f",
            str(self.hook),
            f"-j{self.jobs}",
            *(["-n"] if dry_run else []),
            GOAL,
            *(f"{name}={value}" for name, value in self.variables.items()),
        ]


@dataclass(frozen=True)
class MakePlan:
    """What a dry run found: make's values, and the units that need compiling."""

    values: dict[str, str]
    units: list[str]
    up_to_date: bool


@dataclass(frozen=True)
class MakeRun:
    """What a real run did."""

    values: dict[str, str]
    compiled: int
    usage: Usage | None
    seconds: float


def object_dir_variables(tree: Path, object_dir: Path) -> dict[str, str]:
    """OBJECT_DIR and BIN_DIR for OBJECT_DIR, relative to TREE (where make runs).

    A dependency file names its object as the compiler's `-o` did. With CCACHE_BASEDIR, ccache
    rewrites an absolute `-o` below it to a relative one when it compiles, and keeps it absolute
    when it serves a hit: an object compiled fresh then got a rule make never matched to its
    absolute name, and a changed header did not recompile it. Given relative, both agree.
    """
    relative = os.path.relpath(object_dir.resolve(), tree.resolve())  # as make's cwd resolves
    return {"OBJECT_DIR": relative, "BIN_DIR": relative}


def write_hook(path: Path) -> None:
    """Write wftool.mk (only when its content changed, to keep make's view stable)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != HOOK_MAKEFILE:
        path.write_text(HOOK_MAKEFILE)


def plan(command: MakeCommand) -> MakePlan:
    """Dry-run make: read its values and list what it would compile."""
    try:
        proc = subprocess.run(
            command.argv(dry_run=True),
            env=_environment(command),
            capture_output=True,
            text=True,
            errors="replace",
            check=False,
        )
    except OSError as exc:
        raise BuildError(f"cannot run make: {exc}") from exc
    lines = proc.stdout.splitlines()
    if proc.returncode != 0:
        raise BuildError(f"make cannot start: {first_error(proc.stderr.splitlines() + lines)}")
    recipe = [
        line
        for line in lines
        if line.strip() and not line.startswith("make") and not _VAR_LINE.match(line)
    ]
    units = [match.group("source") for line in recipe if (match := _UNIT_DRY.match(line))]
    return MakePlan(values=_values(lines), units=units, up_to_date=not recipe)


def run(
    command: MakeCommand, log: Path, progress: Progress | None = None, planned: int | None = None
) -> MakeRun:
    """Run make, logging everything, reporting (phase, units compiled, total) to PROGRESS.

    The phases are compile, link, then done or failed. The total is PLANNED (from a dry
    run), or else all the target's units once make reports them. On failure raises
    BuildError with the first compiler error (file:line) and the log path.
    """
    report = progress or no_progress
    log.parent.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    compiled = 0
    total = planned or None
    phase = "compile"
    output: list[str] = []
    with log.open("w") as sink:
        sink.write("$ " + " ".join(command.argv()) + "\n")
        report(phase, compiled, total)
        try:
            proc = subprocess.Popen(
                command.argv(),
                env=_environment(command),
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                errors="replace",
                bufsize=1,
            )
        except OSError as exc:
            raise BuildError(f"cannot run make: {exc}") from exc
        with proc:
            assert proc.stdout is not None
            for line in proc.stdout:
                sink.write(line)
                output.append(line.rstrip("\n"))
                if planned is None and line.startswith("wftool-var objects="):
                    total = int(line.split("=", 1)[1])
                elif _UNIT_RUN.match(line):
                    compiled += 1
                elif _LINKING.match(line):
                    phase = "link"
                else:
                    continue
                report(phase, compiled, total)
        returncode = proc.returncode
        report("done" if returncode == 0 else "failed", compiled, total)
    if returncode != 0:
        raise BuildError(
            f"{first_error(output, command.tree)} (make exited {returncode}; log: {log})"
        )
    values = _values(output)
    return MakeRun(
        values=values,
        compiled=compiled,
        usage=parse_usage(output, values.get("flash_kb")),
        seconds=time.monotonic() - started,
    )


def parse_usage(output: list[str], flash_kb: str | None) -> Usage | None:
    """Flash/RAM use from the link: the linker's memory table, else `size`'s row (SITL)."""
    flash = ram = ram_total = 0
    regions = 0
    for line in output:
        region = _MEMORY_REGION.match(line)
        if region is None:
            continue
        regions += 1
        used = round(float(region.group("used")) * _UNITS[region.group("used_unit")])
        size = round(float(region.group("size")) * _UNITS[region.group("size_unit")])
        if "FLASH" in region.group("name"):
            flash += used
        elif "RAM" in region.group("name"):
            ram += used
            ram_total += size
    if regions:
        flash_total = int(flash_kb) * 1024 if flash_kb and flash_kb.isdigit() else None
        return Usage(flash, flash_total, ram, ram_total or None)
    for line in output:
        row = _SIZE_ROW.match(line)
        if row:
            text, data, bss = (int(row.group(name)) for name in ("text", "data", "bss"))
            return Usage(text + data, None, data + bss, None)
    return None


def _values(lines: list[str]) -> dict[str, str]:
    """The `wftool-var name=value` lines the hook makefile prints."""
    return {match.group(1): match.group(2) for line in lines if (match := _VAR_LINE.match(line))}


def _environment(command: MakeCommand) -> dict[str, str]:
    # LC_ALL=C keeps compiler messages parseable; MAKEFLAGS from a calling make would leak -j/-n.
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}
    return {**env, "LC_ALL": "C", **command.env}


def first_error(lines: list[str], tree: Path | None = None) -> str:
    """The first compiler error as `path:line: message`, else the first line that looks bad."""
    for line in lines:
        match = _COMPILER_ERROR.match(line)
        if match:
            path = Path(match.group("file"))
            if tree is not None and not path.is_absolute():
                path = tree / path
            return f"{_readable(path)}:{match.group('line')}: error: {match.group('message')}"
    for line in lines:
        if _ANY_ERROR.search(line):
            return line.strip()
    return lines[-1].strip() if lines else "no output"


def _readable(path: Path) -> str:
    """PATH relative to the current directory when it is below it, for clickable messages."""
    resolved = Path(os.path.normpath(path.absolute()))
    try:
        return str(resolved.relative_to(Path.cwd()))
    except ValueError:
        return str(resolved)
