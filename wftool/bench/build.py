"""`wftool bench build`: what wftool costs on top of Betaflight's own make.

Four figures on one target and one tree: a from-scratch build with plain `make` (Betaflight's
default goal, same variables), the same with `wftool build`, a no-op rebuild, and a rebuild
after touching one file the patch series changes. ccache is off for all of them, or the
second full build would be served from the cache the first one filled.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import time
from dataclasses import dataclass

from wftool.errors import BuildError
from wftool.firmware import builder, make, patches, tree
from wftool.firmware.builder import BuildOptions
from wftool.firmware.project import Project

FALLBACK_TOUCH = "src/main/fc/core.c"
"""The file touched when the series is empty: compiled for every target."""


@dataclass(frozen=True)
class BenchFigures:
    """Seconds for each measurement (best of the repeats for the full builds)."""

    target: str
    jobs: int
    raw_make: float
    wftool_build: float
    noop: float
    touch: float
    touched: str
    touch_compiled: int

    @property
    def overhead_percent(self) -> float:
        """wftool's full build time relative to plain make's, in percent."""
        return 100 * (self.wftool_build - self.raw_make) / self.raw_make


def bench_build(
    project: Project, target_name: str, options: BuildOptions, repeat: int = 1
) -> BenchFigures:
    """Measure; every build here is real (a full F7 build takes minutes on two cores).

    The full builds run REPEAT times each, interleaved, and the fastest of each counts:
    on a shared machine the minimum is the figure least disturbed by other work.
    """
    options = dataclasses.replace(options, ccache=False)
    prepared = builder.prepare(project, target_name, options)
    raw_variables = {
        name: value
        for name, value in prepared.command.variables.items()
        if name not in ("OBJECT_DIR", "BIN_DIR")
    }
    raw_times, wftool_times = [], []
    for _ in range(repeat):  # interleaved, so load from other work hits both alike
        raw_times.append(_raw_make(prepared, raw_variables))
        rebuild = dataclasses.replace(options, rebuild=True)
        wftool_times.append(_timed_build(project, target_name, rebuild)[0])
    raw_make, wftool_build = min(raw_times), min(wftool_times)
    noop, result = _timed_build(project, target_name, options)
    if not result.up_to_date:
        raise BuildError("the rebuild after a build was not a no-op; see build/<target>/build.log")
    touched = _file_to_touch(project)
    os.utime(project.tree / touched)
    touch, result = _timed_build(project, target_name, options)
    return BenchFigures(
        target=prepared.target.name,
        jobs=prepared.command.jobs,
        raw_make=raw_make,
        wftool_build=wftool_build,
        noop=noop,
        touch=touch,
        touched=touched,
        touch_compiled=result.compiled,
    )


def _raw_make(prepared: builder.Prepared, variables: dict[str, str]) -> float:
    """Seconds for `make clean` then plain `make` (Betaflight's default goal)."""
    base = ["make", "-C", str(prepared.project.tree), *(f"{k}={v}" for k, v in variables.items())]
    env = {**os.environ, "LC_ALL": "C", **prepared.command.env}
    subprocess.run([*base, "clean"], env=env, capture_output=True, check=False)
    started = time.monotonic()
    proc = subprocess.run(
        [*base, f"-j{prepared.command.jobs}"], env=env, capture_output=True, text=True, check=False
    )
    seconds = time.monotonic() - started
    if proc.returncode != 0:
        error = make.first_error(proc.stdout.splitlines(), prepared.project.tree)
        raise BuildError(f"plain make failed: {error}")
    return seconds


def _timed_build(
    project: Project, target_name: str, options: BuildOptions
) -> tuple[float, builder.BuildResult]:
    started = time.monotonic()
    result = builder.build(project, target_name, options)
    return time.monotonic() - started, result


def _file_to_touch(project: Project) -> str:
    """A C file the series changes and the checkout has, else FALLBACK_TOUCH."""
    pin = tree.pinned_commit(project)
    changed = tree.changed_files(project, pin, patches.MANAGED_REF)
    candidates = [path for path in changed if path.endswith(".c")]
    existing = [path for path in candidates if (project.tree / path).is_file()]
    return existing[0] if existing else FALLBACK_TOUCH
