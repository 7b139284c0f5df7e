"""The accelerometer RPM filter of the patch series, compiled for the host and driven from Python.

The harness (harness/acc_rpm_harness*.c, our code) is compiled together with the filter's
own sources from the patched tree (see `sources`) into a shared library with the host gcc
at -O2 and the defines of the series' unit test, then loaded with ctypes. Nothing of the
filter is re-implemented here: every sample goes through accRpmFilterSetMotorFrequencies()
and accRpmFilterProcess() as in accRpmFilterApply().
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wftool.analysis.sources import UNIT_TEST_FLAGS, UnitTestSources
from wftool.errors import BuildError, UsageError

if TYPE_CHECKING:
    import numpy as np

HARNESS_DIR = Path(__file__).resolve().parent / "harness"
PORTABLE_SOURCE = HARNESS_DIR / "acc_rpm_harness.c"
"""Entry points compiled for the host and for the Cortex-M7."""
HOST_SOURCE = HARNESS_DIR / "acc_rpm_harness_host.c"
"""Whole-signal runs and timing loops (host only)."""
HOST_FLAGS = ("-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Wl,--no-undefined")
COEFFICIENTS_PER_NOTCH = 6
"""b0, b1, b2, a1, a2, weight, as accHarnessCoefficients() writes them: each notch's transfer
function as a weighted biquad (the firmware's notch is a state-variable filter)."""


SETTING_LIMITS = {
    "harmonics": (0, 3),
    "min_hz": (30, 200),
    "fade_range_hz": (0, 1000),
    "q": (250, 3000),
}
"""The CLI's ranges of the acc_rpm_filter_* settings (src/main/cli/settings.c of the series)."""


class HarnessError(BuildError):
    """The harness could not be compiled or loaded."""


@dataclass(frozen=True)
class FilterSettings:
    """The acc_rpm_filter_* settings (PG_ACC_RPM_FILTER_CONFIG), in CLI units."""

    name: str = "paper"
    harmonics: int = 1
    weights: tuple[int, int, int] = (100, 100, 100)
    """Per harmonic, percent."""
    min_hz: int = 60
    fade_range_hz: int = 50
    q: int = 500
    """Notch Q × 100 (500 = Q 5)."""

    def as_ints(self) -> list[int]:
        """The order accHarnessSetup() reads: harmonics, 3 weights, min, fade range, q."""
        return [self.harmonics, *self.weights, self.min_hz, self.fade_range_hz, self.q]

    def describe(self) -> str:
        """e.g. 'harmonics 1, Q 5.0, min 60 Hz, fade 50 Hz'."""
        weights = "" if self.weights == (100, 100, 100) else f", weights {self.weights}"
        return (
            f"harmonics {self.harmonics}, Q {self.q / 100:g}, min {self.min_hz} Hz, "
            f"fade {self.fade_range_hz} Hz{weights}"
        )

    def as_dict(self) -> dict[str, object]:
        return {**asdict(self), "weights": list(self.weights)}

    @classmethod
    def parse(cls, text: str) -> FilterSettings:
        """'NAME:key=value,...' (or a preset name); keys as the CLI's acc_rpm_filter_*.

        e.g. 'wide:harmonics=2,q=300' or 'paper'; weights as 100/50/0.
        """
        name, _, assignments = text.partition(":")
        if not assignments and name in PRESETS:
            return PRESETS[name]
        if not assignments or not name:
            raise UsageError(
                f"filter setting {text!r}: use a preset ({', '.join(PRESETS)}) or "
                "NAME:key=value,... with keys harmonics, weights, min_hz, fade_range_hz, q"
            )
        values: dict[str, Any] = {}
        for item in assignments.split(","):
            key, _, value = item.partition("=")
            key = key.strip().removeprefix("acc_rpm_filter_")
            try:
                if key == "weights":
                    weights = tuple(int(w) for w in value.split("/"))
                    if len(weights) != 3 or not all(0 <= w <= 100 for w in weights):
                        raise ValueError
                    values[key] = weights
                elif key in SETTING_LIMITS:
                    low, high = SETTING_LIMITS[key]
                    number = int(value)
                    if not low <= number <= high:
                        raise UsageError(f"{name}: {key} {number} is outside {low}..{high}")
                    values[key] = number
                else:
                    raise UsageError(f"{name}: unknown filter setting {key!r}")
            except ValueError:
                raise UsageError(f"{name}: bad value for {key}: {value!r}") from None
        return replace(cls(name=name), **values)


PRESETS = {
    "paper": FilterSettings(),
    "harmonics3": FilterSettings("harmonics3", harmonics=3),
    "q3": FilterSettings("q3", q=300),
    "q8": FilterSettings("q8", q=800),
    "min30": FilterSettings("min30", min_hz=30),
}
"""The paper's defaults and single-setting alternatives to compare them with."""


def compile_host_library(sources: UnitTestSources, out_dir: Path, cc: str = "gcc") -> Path:
    """Build the harness and the filter's sources into OUT_DIR/libaccrpmharness.so."""
    compiler = shutil.which(cc)
    if compiler is None:
        raise HarnessError(f"the filter harness needs a host C compiler, and {cc} is not on PATH")
    out_dir.mkdir(parents=True, exist_ok=True)
    library = out_dir / "libaccrpmharness.so"
    command = [
        compiler,
        *host_flags(sources),
        *(f"-I{directory}" for directory in sources.include_dirs),
        "-o",
        str(library),
        *(str(path) for path in sources.sources),
        str(PORTABLE_SOURCE),
        str(HOST_SOURCE),
        "-lm",
    ]
    run_compiler(command)
    return library


def host_flags(sources: UnitTestSources) -> list[str]:
    """The host compiler's flags without the include directories."""
    return [*HOST_FLAGS, *UNIT_TEST_FLAGS, *(f"-D{define}" for define in sources.defines)]


def run_compiler(command: list[str]) -> None:
    """Run a compiler command; a failure raises HarnessError with the compiler's last error."""
    proc = subprocess.run(command, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        errors = [line for line in proc.stderr.splitlines() if "error" in line]
        reason = (errors or proc.stderr.strip().splitlines() or ["failed"])[0]
        raise HarnessError(f"compiling the harness failed: {reason}")


class HostHarness:
    """The compiled library: makes filters and times the reference notch."""

    def __init__(self, library: Path) -> None:
        try:
            lib = ctypes.CDLL(str(library))
        except OSError as exc:
            raise HarnessError(f"cannot load {library}: {exc}") from None
        f32p, size_t, voidp = ctypes.POINTER(ctypes.c_float), ctypes.c_size_t, ctypes.c_void_p
        lib.accHarnessFilterSize.restype = ctypes.c_uint
        lib.accHarnessSetup.argtypes = [
            voidp,
            ctypes.POINTER(ctypes.c_int32),
            ctypes.c_uint,
            ctypes.c_int,
        ]
        lib.accHarnessRun.argtypes = [voidp, size_t, ctypes.c_int, f32p, f32p]
        lib.accRpmFilterSetMotorFrequencies.argtypes = [voidp, f32p]
        lib.accHarnessCoefficients.argtypes = [voidp, f32p]
        lib.accHarnessTimeUpdate.argtypes = [voidp, size_t, ctypes.c_int, f32p]
        lib.accHarnessTimeProcess.argtypes = [voidp, size_t, f32p]
        lib.accHarnessTimeNotch.argtypes = [size_t, f32p]
        for timer in (
            lib.accHarnessTimeUpdate,
            lib.accHarnessTimeProcess,
            lib.accHarnessTimeNotch,
        ):
            timer.restype = ctypes.c_double
        self.lib = lib
        self.filter_size = lib.accHarnessFilterSize()
        self.harmonics_max = lib.accHarnessHarmonicsMax()

    def filter(self, settings: FilterSettings, sample_rate_hz: int, motor_count: int) -> HostFilter:
        """A filter set up as the firmware sets it up (accRpmFilterSetup)."""
        return HostFilter(self, settings, sample_rate_hz, motor_count)

    def time_notch_ns(self, samples: np.ndarray) -> float:
        """Wall time of svfNotchApply() over SAMPLES (float32, filtered in place)."""
        return self.lib.accHarnessTimeNotch(samples.size, _floats(samples))


class HostFilter:
    """One accRpmFilter_t in host memory."""

    def __init__(
        self, harness: HostHarness, settings: FilterSettings, sample_rate_hz: int, motor_count: int
    ) -> None:
        self._lib = harness.lib
        self._state = ctypes.create_string_buffer(harness.filter_size)
        self.settings = settings
        self.sample_rate_hz = sample_rate_hz
        self.motor_count = motor_count
        config = (ctypes.c_int32 * 7)(*settings.as_ints())
        self.active = bool(
            self._lib.accHarnessSetup(self._state, config, sample_rate_hz, motor_count)
        )

    def run(self, motor_hz: np.ndarray, acc: np.ndarray) -> np.ndarray:
        """Filter ACC (N×3) sample by sample with the motor frequencies MOTOR_HZ (N×motors)."""
        import numpy as np

        motors = np.ascontiguousarray(motor_hz, dtype=np.float32)
        samples = np.array(acc, dtype=np.float32, order="C", copy=True)
        if motors.shape != (samples.shape[0], self.motor_count) or samples.shape[1:] != (3,):
            raise ValueError("run() takes N×3 samples and N×motor_count frequencies")
        self._lib.accHarnessRun(
            self._state, samples.shape[0], self.motor_count, _floats(motors), _floats(samples)
        )
        return samples.astype(np.float64)

    def coefficients(self, motor_hz: np.ndarray | None = None) -> np.ndarray:
        """The notches' transfer functions as weighted biquads (b0, b1, b2, a1, a2, weight),
        motors × harmonics × 6.

        With MOTOR_HZ the notches are first moved there (accRpmFilterSetMotorFrequencies).
        """
        import numpy as np

        if motor_hz is not None:
            motors = np.ascontiguousarray(motor_hz, dtype=np.float32)
            self._lib.accRpmFilterSetMotorFrequencies(self._state, _floats(motors))
        out = np.zeros(self.motor_count * 3 * COEFFICIENTS_PER_NOTCH, dtype=np.float32)
        count = self._lib.accHarnessCoefficients(self._state, _floats(out))
        notches = out[: count * COEFFICIENTS_PER_NOTCH].astype(np.float64)
        return notches.reshape(self.motor_count, -1, COEFFICIENTS_PER_NOTCH)

    def time_update_ns(self, motor_hz: np.ndarray) -> float:
        """Wall time of accRpmFilterSetMotorFrequencies() over MOTOR_HZ's rows."""
        import numpy as np

        motors = np.ascontiguousarray(motor_hz, dtype=np.float32)
        return self._lib.accHarnessTimeUpdate(
            self._state, motors.shape[0], self.motor_count, _floats(motors)
        )

    def time_process_ns(self, samples: np.ndarray) -> float:
        """Wall time of accRpmFilterProcess() over SAMPLES (N×3 float32, filtered in place)."""
        return self._lib.accHarnessTimeProcess(self._state, samples.shape[0], _floats(samples))


def _floats(array: np.ndarray) -> ctypes._Pointer:
    import numpy as np

    if array.dtype != np.float32 or not array.flags.c_contiguous:
        raise ValueError("the harness takes C-contiguous float32 arrays")
    return array.ctypes.data_as(ctypes.POINTER(ctypes.c_float))
