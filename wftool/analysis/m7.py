"""The series' code on the SPEEDYBEEF7V3's core: built for the Cortex-M7 and run in Unicorn,
counting the instructions the firmware's functions execute (the accelerometer filter, the
timed-command queue; docs/analysis.md).
"""

from __future__ import annotations

import re
import struct
import subprocess
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from wftool.analysis.harness import (
    HARNESS_DIR,
    PORTABLE_SOURCE,
    FilterSettings,
    HarnessError,
    run_compiler,
)
from wftool.analysis.sources import UnitTestSources

if TYPE_CHECKING:
    import numpy as np

M7_ARCH_FLAGS = ("-mthumb", "-mcpu=cortex-m7", "-mfloat-abi=hard", "-mfpu=fpv5-sp-d16")
"""ARCH_FLAGS of src/platform/STM32/mk/STM32F7.mk."""
M7_OPTIMISATION = ("-O2", "-ffast-math", "-fmerge-all-constants")
"""Betaflight's OPTIMISATION_BASE (Makefile) with OPTIMISE_DEFAULT -O2; the F722 sets
OPTIMISE_SPEED = -O2 too (STM32F7.mk), so filter.c and maths.c get the same. -flto is left
out: each file is compiled on its own, so calls across files are not inlined as LTO may."""
M7_FLAGS = (
    *M7_ARCH_FLAGS,
    *M7_OPTIMISATION,
    "-std=gnu17",
    "-ffunction-sections",
    "-fdata-sections",
    "-fno-common",
    "-D_GNU_SOURCE",
)
LINKER_SCRIPT = HARNESS_DIR / "m7.ld"
CLOCK_HZ = 216_000_000
"""The SPEEDYBEEF7V3's STM32F722 core clock."""
LONG_INSTRUCTIONS = {"vdiv.f32": 13, "vsqrt.f32": 13}
"""Extra cycles beyond one, per instruction (Cortex-M7 TRM: 14-cycle FP divide and root)."""

_BASE = 0x0010_0000
_MEMORY_SIZE = 0x0010_0000
_FILTER_ADDRESS = _BASE + 0x4_0000
_ARGS_ADDRESS = _BASE + 0x5_0000
_STACK_TOP = _BASE + 0xF_0000
_RETURN_ADDRESS = _BASE + 0xF_F000
_INSTRUCTION = re.compile(r"^\s*([0-9a-f]+):\s+(\S+)", re.MULTILINE)
"""An instruction line of `objdump -d --no-show-raw-insn`: address and mnemonic."""
_BRANCH = re.compile(
    r"^(b|bl|blx|bx|cbz|cbnz|tbb|tbh)(eq|ne|cs|cc|hs|lo|mi|pl|vs|vc|hi|ls|ge|lt|gt|le|al)?"
    r"(\.w|\.n)?$"
)


@dataclass(frozen=True)
class M7Image:
    """The linked harness: flat binary, symbols, and each instruction's mnemonic."""

    elf: Path
    binary: bytes
    symbols: dict[str, tuple[int, int]]
    """name -> (address, size)."""
    mnemonics: dict[int, str]
    """instruction address -> mnemonic, from the disassembly."""
    gcc_version: str

    def straight_line_length(self, function: str) -> int:
        """Instructions of FUNCTION through its first return; it must not branch before."""
        start, size = self.symbols[function]
        addresses = sorted(a for a in self.mnemonics if start <= a < start + size)
        for count, address in enumerate(addresses, start=1):
            mnemonic = self.mnemonics[address]
            if mnemonic == "bx":
                return count
            if _BRANCH.match(mnemonic):
                raise HarnessError(f"{function} branches at {address:#x}: not straight-line")
        raise HarnessError(f"{function} has no return")


@dataclass(frozen=True)
class CallCost:
    instructions: int
    cycles: int


def build_image(
    sources: UnitTestSources,
    out_dir: Path,
    gcc: Path,
    harness: Path = PORTABLE_SOURCE,
    entry: str = "accHarnessSetup",
) -> M7Image:
    """Compile and link `harness` (its entry point `entry`) and the firmware's `sources` for
    the Cortex-M7 into OUT_DIR (by default the filter's harness)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    tool = str(gcc)[: -len("gcc")]
    name = harness.stem.replace("_", "")
    objects = []
    for source in (*sources.sources, harness):
        obj = out_dir / f"{source.stem}.o"
        run_compiler(
            [
                str(gcc),
                *M7_FLAGS,
                *(f"-D{define}" for define in sources.defines),
                *(f"-I{directory}" for directory in sources.include_dirs),
                "-c",
                str(source),
                "-o",
                str(obj),
            ]
        )
        objects.append(str(obj))
    elf = out_dir / f"{name}-m7.elf"
    run_compiler(
        [
            str(gcc),
            *M7_ARCH_FLAGS,
            "-nostartfiles",
            "--specs=nano.specs",
            f"-Wl,--entry={entry}",
            f"-T{LINKER_SCRIPT}",
            "-o",
            str(elf),
            *objects,
            "-lm",
            "-lc",
            "-lnosys",
        ]
    )
    binary = out_dir / f"{name}-m7.bin"
    _tool(f"{tool}objcopy", "-O", "binary", str(elf), str(binary))
    symbols = {}
    for line in _tool(f"{tool}nm", "-S", "--defined-only", str(elf)).splitlines():
        fields = line.split()
        if len(fields) == 4:
            symbols[fields[3]] = (int(fields[0], 16), int(fields[1], 16))
    disassembly = _tool(f"{tool}objdump", "-d", "--no-show-raw-insn", str(elf))
    mnemonics = {
        int(match.group(1), 16): match.group(2) for match in _INSTRUCTION.finditer(disassembly)
    }
    version = _tool(str(gcc), "-dumpversion").strip()
    return M7Image(elf, binary.read_bytes(), symbols, mnemonics, version)


class M7Harness:
    """The image in an emulated Cortex-M7; each call reports what it executed."""

    def __init__(self, image: M7Image) -> None:
        from unicorn import UC_ARCH_ARM, UC_HOOK_CODE, UC_MODE_MCLASS, UC_MODE_THUMB, Uc
        from unicorn.arm_const import UC_CPU_ARM_CORTEX_M7

        if len(image.binary) > _FILTER_ADDRESS - _BASE:
            raise HarnessError("the Cortex-M7 harness image is larger than its slot")
        self.image = image
        self._uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self._uc.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M7)
        self._uc.mem_map(_BASE, _MEMORY_SIZE)
        self._uc.mem_write(_BASE, image.binary)
        self._uc.mem_write(_RETURN_ADDRESS, b"\x00\xbf\x00\xbf")  # nop; never executed
        self._counts: Counter[int] = Counter()
        self._uc.hook_add(UC_HOOK_CODE, self._count)
        self.motor_count = 0

    def _count(self, uc: object, address: int, size: int, data: object) -> None:
        self._counts[address] += 1

    def call(self, function: str, *args: int, floats: tuple[float, ...] = ()) -> CallCost:
        """Run FUNCTION(ARGS...) (integer/pointer args, then float args) to its return."""
        from unicorn import UcError
        from unicorn.arm_const import UC_ARM_REG_LR, UC_ARM_REG_R0, UC_ARM_REG_S0, UC_ARM_REG_SP

        for index, value in enumerate(args):
            self._uc.reg_write(UC_ARM_REG_R0 + index, value)
        for index, number in enumerate(floats):
            bits = struct.unpack("<I", struct.pack("<f", number))[0]
            self._uc.reg_write(UC_ARM_REG_S0 + index, bits)
        self._uc.reg_write(UC_ARM_REG_SP, _STACK_TOP)
        self._uc.reg_write(UC_ARM_REG_LR, _RETURN_ADDRESS | 1)
        self._counts.clear()
        try:
            self._uc.emu_start(self.image.symbols[function][0] | 1, _RETURN_ADDRESS)
        except UcError as exc:
            raise HarnessError(f"{function} faulted in the Cortex-M7 emulator: {exc}") from None
        instructions = sum(self._counts.values())
        extra = sum(
            count * LONG_INSTRUCTIONS.get(self.image.mnemonics.get(address, ""), 0)
            for address, count in self._counts.items()
        )
        return CallCost(instructions, instructions + extra)

    def result(self) -> int:
        from unicorn.arm_const import UC_ARM_REG_R0

        return self._uc.reg_read(UC_ARM_REG_R0)

    def address(self, symbol: str) -> int:
        """Where `symbol` (a function or an object of the image) lies."""
        try:
            return self.image.symbols[symbol][0]
        except KeyError:
            raise HarnessError(f"the Cortex-M7 image has no symbol {symbol}") from None

    def read(self, address: int, size: int) -> bytes:
        return bytes(self._uc.mem_read(address, size))

    def write(self, address: int, data: bytes) -> None:
        self._uc.mem_write(address, data)

    def setup(self, settings: FilterSettings, sample_rate_hz: int, motor_count: int) -> bool:
        """accRpmFilterSetup() on the emulated filter; returns whether it is active."""
        self._uc.mem_write(_ARGS_ADDRESS, struct.pack("<7i", *settings.as_ints()))
        self.call("accHarnessSetup", _FILTER_ADDRESS, _ARGS_ADDRESS, sample_rate_hz, motor_count)
        self.motor_count = motor_count
        return bool(self.result())

    def update(self, motor_hz: np.ndarray) -> CallCost:
        """accRpmFilterSetMotorFrequencies() with one sample's motor frequencies."""
        self._uc.mem_write(_ARGS_ADDRESS, struct.pack(f"<{self.motor_count}f", *motor_hz))
        return self.call("accRpmFilterSetMotorFrequencies", _FILTER_ADDRESS, _ARGS_ADDRESS)

    def process(self, xyz: np.ndarray) -> tuple[tuple[float, float, float], CallCost]:
        """accRpmFilterProcess() on one sample; returns the filtered sample and the cost."""
        self._uc.mem_write(_ARGS_ADDRESS, struct.pack("<3f", *xyz))
        cost = self.call("accRpmFilterProcess", _FILTER_ADDRESS, _ARGS_ADDRESS)
        return struct.unpack("<3f", self._uc.mem_read(_ARGS_ADDRESS, 12)), cost

    def notch_apply(self) -> CallCost:
        """One svfNotchApply() on a notch in emulated memory (the reference function)."""
        state = struct.pack("<5f", 0.9, 0.05, 0.06, 0.0, 0.0)  # a1, a2q, fq, ic1q, ic2
        self._uc.mem_write(_ARGS_ADDRESS, state)
        return self.call("svfNotchApply", _ARGS_ADDRESS, floats=(1.0,))


def _tool(*command: str) -> str:
    try:
        proc = subprocess.run(command, capture_output=True, text=True, check=False)
    except OSError as exc:
        raise HarnessError(f"cannot run {command[0]}: {exc}") from None
    if proc.returncode != 0:
        raise HarnessError(f"{Path(command[0]).name} failed: {proc.stderr.strip()[:200]}")
    return proc.stdout
