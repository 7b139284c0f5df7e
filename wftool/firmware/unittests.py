"""Betaflight's own unit tests (src/test, gtest), for the series' firmware code.

The series adds its tests beside Betaflight's; `series_tests` finds them from the patched
commits, so a new test in patches/ is run without being listed anywhere. The tree is
fetched without src/test and lib/test; running tests checks them out first. They compile
through ccache where it is installed, as `wftool build` does, in one make (one job per
core). A test whose make rule cannot fetch a submodule it compiles (Betaflight 2026.6's
DroneCAN tests clone libcanard) is reported as not run, with that reason, apart from a
failure.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import ToolchainError
from wftool.firmware import patches, tree
from wftool.firmware.git import git, git_out
from wftool.firmware.project import Project
from wftool.firmware.targets import SITL, resolve_target

TEST_PATHS = ("src/test", "lib/test")
_UNIT_TEST = re.compile(r"^src/test/unit/(\w+_unittest)\.cc$")
_SUBMODULE_NOT_FETCHED = re.compile(r"^Failed to clone '(?P<path>[^']+)'", re.MULTILINE)
"""`git submodule update`'s words when it cannot fetch a submodule (make rules of src/test)."""
_PASSED = re.compile(r"^running (?P<name>test_\w+): PASS$")
"""src/test/Makefile's last line of a test that passed."""
_GTEST_FIRST_LINE = "Running main() from "
"""gtest_main's first line of a test's run."""
_TEST_COMPILERS = ("clang", "clang++")
"""src/test/Makefile falls back to plain clang when its preferred clang-18 is absent."""


@dataclass(frozen=True)
class UnitTestRun:
    name: str
    passed: bool
    output: str
    not_run: str | None = None
    """Why the test could not be built (a submodule it needs could not be fetched); None
    when make got to build and run it."""


def not_run_reason(output: str) -> str | None:
    """Why make could not build a test, from its output: a submodule it did not fetch."""
    fetch = _SUBMODULE_NOT_FETCHED.search(output)
    if fetch is None:
        return None
    return f"needs {fetch['path']}, a submodule of the Betaflight tree that could not be fetched"


def series_tests(project: Project) -> list[str]:
    """The unit tests the patch series adds (make target names, e.g. test_fsp_unittest)."""
    added = git_out(
        ["diff", "--name-only", "--diff-filter=A", tree.pinned_commit(project), "HEAD"],
        project.tree,
    )
    return sorted(f"test_{m.group(1)}" for m in map(_UNIT_TEST.match, added.splitlines()) if m)


def all_tests(project: Project) -> list[str]:
    """Every unit test of the patched tree (Betaflight's and the series'), as make targets."""
    unit = project.tree / "src" / "test" / "unit"
    return sorted(f"test_{path.stem}" for path in unit.glob("*_unittest.cc"))


def run_unit_tests(
    project: Project, names: list[str] | None = None, *, everything: bool = False
) -> list[UnitTestRun]:
    """Apply the series, check out the test tree, run NAMES (default: the series' tests;
    `everything`: all of them, Betaflight's `make test`)."""
    require_compilers()
    tree.ensure_tree(project, resolve_target(project, SITL), allow_dirty=True)
    patches.apply(project, override="run `wftool patches apply --force`")
    check_out_tests(project.tree)
    if everything:
        names = all_tests(project)
    chosen = names if names is not None else series_tests(project)
    if not chosen:
        return []
    _fetch_test_submodules(project.tree)
    return run_tests(project.tree, chosen)


def run_tests(repo: Path, names: list[str]) -> list[UnitTestRun]:
    """NAMES (unit tests) in one make in the Betaflight tree REPO, one job per core, going on
    past a failure: src/test/Makefile takes ~2 s of CPU to read, once per make, where a
    test that ccache compiles takes a fraction of that. A test make did not report passed
    is run again alone (`run_test`), for its own output and the reason it was not built."""
    proc = _make(repo, ["-k", f"-j{max(1, os.cpu_count() or 1)}", "--output-sync=target", *names])
    passed = passed_outputs(proc.stdout)
    return [
        UnitTestRun(name, True, passed[name]) if name in passed else run_test(repo, name)
        for name in names
    ]


def passed_outputs(output: str) -> dict[str, str]:
    """Each passed test's output in a make's (`--output-sync`: a test's run is one block,
    from gtest's first line to the rule's `running test_NAME: PASS`), by make target."""
    passed: dict[str, str] = {}
    block: list[str] = []
    for line in output.splitlines():
        if line.startswith(_GTEST_FIRST_LINE):
            block = []
        block.append(line)
        if match := _PASSED.match(line):
            passed[match["name"]] = "\n".join(block)
            block = []
    return passed


def tests_of_patch(patch: Path) -> list[str]:
    """The unit tests a patch file adds or changes (make target names)."""
    text = patch.read_text(errors="replace")
    found = re.findall(r"^\+\+\+ b/src/test/unit/(\w+_unittest)\.cc$", text, re.MULTILINE)
    return sorted({f"test_{name}" for name in found})


def require_compilers() -> None:
    """Betaflight's unit tests build with clang; ToolchainError if it is missing."""
    missing = [c for c in _TEST_COMPILERS if shutil.which(c) is None]
    if missing:
        raise ToolchainError(
            f"Betaflight's unit tests need {' and '.join(missing)} (Debian: clang)"
        )


def run_test(repo: Path, name: str) -> UnitTestRun:
    """`make NAME` (a unit test) in the Betaflight tree REPO, through ccache where it is
    installed, as the firmware builds are (a second run, or another clone, compiles nothing)."""
    proc = _make(repo, [name])
    output = proc.stdout + proc.stderr
    passed = proc.returncode == 0
    return UnitTestRun(name, passed, output, None if passed else not_run_reason(output))


def _make(repo: Path, args: list[str]) -> subprocess.CompletedProcess[str]:
    """make ARGS in REPO with the test compilers, without src/test/Makefile's coverage
    instrumentation (`USE_COVERAGE=`): nothing here reads its .gcda reports, and it writes
    the clone's absolute path into every object, which ccache then hashes (each clone
    compiled the whole suite again)."""
    env = {**os.environ, "CCACHE_BASEDIR": str(repo), "CCACHE_NOHASHDIR": "true"}
    return subprocess.run(
        ["make", *args, "USE_COVERAGE=", *_compilers()],
        cwd=repo,
        env=env,
        capture_output=True,
        text=True,
        errors="replace",
        check=False,
    )


def _fetch_test_submodules(repo: Path) -> None:
    """Fetch once the submodules src/test/Makefile names (its rules fetch one on demand, and
    two makes at once would both try); one that cannot be fetched is left to its tests'
    `not_run` reason."""
    makefile = (repo / "src" / "test" / "Makefile").read_text(errors="replace")
    listed = git_out(["config", "-f", ".gitmodules", "--get-regexp", r"\.path$"], repo, check=False)
    for path in (line.split()[1] for line in listed.splitlines() if len(line.split()) == 2):
        fetched = (repo / path).is_dir() and any((repo / path).iterdir())
        if path in makefile and not fetched:
            git(["submodule", "update", "--init", "--", path], repo, check=False)


def _compilers() -> list[str]:
    """make's CC and CXX: those src/test/Makefile picks (clang-18, else clang), through ccache
    when it is installed."""
    if shutil.which("ccache") is None:
        return []
    pair = ("clang-18", "clang++-18")
    if not all(shutil.which(compiler) for compiler in pair):
        pair = _TEST_COMPILERS
    return [f"CC=ccache {pair[0]}", f"CXX=ccache {pair[1]}"]


def check_out_tests(repo: Path) -> None:
    """Widen REPO's sparse checkout by the unit tests (src/test, lib/test)."""
    excluded = tree.current_exclusions(repo)
    wanted = excluded - set(TEST_PATHS)
    if wanted != excluded:
        patterns = tree.sparse_patterns(sorted(wanted))
        git(["sparse-checkout", "set", "--no-cone", *patterns], repo)
