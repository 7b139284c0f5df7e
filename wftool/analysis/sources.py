"""The patched Betaflight sources the harnesses compile (as the series' unit tests list them:
the accelerometer filter's, the timed-command queue's), and the compilers they use: the one
module of `wftool.analysis` that talks to the firmware build package.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import UsageError
from wftool.firmware.git import git_out

FILTER_SOURCE = "src/main/flight/acc_rpm_filter.c"
QUEUE_SOURCE = "src/main/io/fsp_queue.c"
UNIT_TEST_MAKEFILE = "src/test/Makefile"
UNIT_TEST_DIR = "src/test/unit"
UNIT_TEST_NAME = "acc_rpm_filter_unittest"
QUEUE_UNIT_TEST_NAME = "fsp_queue_unittest"
UNIT_TEST_FLAGS = ("-DUNIT_TEST", "-D_GNU_SOURCE", "-std=gnu99")
"""src/test/Makefile's COMMON_FLAGS and C_FLAGS defines and language (its -O0, warnings,
coverage and gtest flags are left out: the harness compiles with -O2)."""

BOARD_TARGET = "speedybeef7v3"
"""The board whose compiler the Cortex-M7 estimate uses."""

_MAKE_ASSIGNMENT = re.compile(r"^(?P<name>[A-Za-z_][\w.]*)\s*(?P<op>:=|\+=|\?=|=)\s*(?P<value>.*)$")


class SourcesError(UsageError):
    """The Betaflight tree does not hold the series' code, or the harness sources cannot be
    read."""


@dataclass(frozen=True)
class UnitTestSources:
    """Everything a compiler needs to build what one of the series' unit tests compiles
    (the filter, the queue) from one tree."""

    tree: Path
    revision: str
    """The tree's HEAD commit, with "-dirty" when it has uncommitted changes."""
    sources: tuple[Path, ...]
    """The C files the unit test compiles (the filter's: acc_rpm_filter.c, filter.c,
    maths.c)."""
    defines: tuple[str, ...]
    """That unit test's extra defines (e.g. USE_ACC_RPM_FILTER=)."""
    include_dirs: tuple[Path, ...]
    """The unit tests' board headers first, then src/main and MAVLink, as src/test/Makefile."""
    sha256: str
    """One hash over the sources' paths and contents."""


def make_variables(text: str) -> dict[str, list[str]]:
    """The words of each unconditional make variable in TEXT (`:=`/`=` set, `+=` appends).

    Enough for src/test/Makefile's per-test lists; it does not evaluate conditionals.
    """
    variables: dict[str, list[str]] = {}
    logical = re.sub(r"\\\n", " ", text)
    for line in logical.splitlines():
        match = _MAKE_ASSIGNMENT.match(line.split("#", 1)[0].rstrip())
        if match is None:
            continue
        words = match.group("value").split()
        name, op = match.group("name"), match.group("op")
        if op == "+=":
            variables.setdefault(name, []).extend(words)
        elif op != "?=" or name not in variables:
            variables[name] = words
    return variables


def tree_text(tree: Path, path: str) -> str:
    """PATH from the work tree, else from HEAD (the sparse checkout leaves src/test out)."""
    on_disk = tree / path
    if on_disk.is_file():
        return on_disk.read_text()
    return git_out(["show", f"HEAD:{path}"], tree) + "\n"


def filter_sources(tree: Path, scratch: Path) -> UnitTestSources:
    """The accelerometer filter's sources in TREE (see `unit_test_sources`)."""
    return unit_test_sources(tree, scratch, UNIT_TEST_NAME, FILTER_SOURCE)


def queue_sources(tree: Path, scratch: Path) -> UnitTestSources:
    """The timed-command queue's sources in TREE, with the freshness gate and the MSP
    receiver it hands commands to (see `unit_test_sources`)."""
    return unit_test_sources(tree, scratch, QUEUE_UNIT_TEST_NAME, QUEUE_SOURCE)


def unit_test_sources(tree: Path, scratch: Path, unit_test: str, required: str) -> UnitTestSources:
    """What the series' unit test `unit_test` compiles in TREE, which must hold `required`;
    the unit tests' headers are copied into SCRATCH."""
    if not (tree / required).is_file():
        raise SourcesError(
            f"{tree} holds no {required}: not a Betaflight tree with the patch series "
            "(`wftool patches apply`)"
        )
    variables = make_variables(tree_text(tree, UNIT_TEST_MAKEFILE))
    listed = variables.get(f"{unit_test}_SRC")
    if not listed:
        raise SourcesError(f"{tree}/{UNIT_TEST_MAKEFILE} lists no {unit_test}_SRC")
    sources = tuple(tree / "src/main" / word.replace("$(USER_DIR)/", "") for word in listed)
    missing = [str(path) for path in sources if not path.is_file()]
    if missing:
        raise SourcesError(f"{unit_test}_SRC names missing files: {', '.join(missing)}")
    headers = scratch / "unit-test-headers"
    for name in _unit_test_headers(tree):
        destination = headers / name
        destination.parent.mkdir(parents=True, exist_ok=True)
        destination.write_text(tree_text(tree, f"{UNIT_TEST_DIR}/{name}"))
    digest = hashlib.sha256()
    for path in sources:
        digest.update(f"{path.relative_to(tree)}\n".encode() + path.read_bytes())
    return UnitTestSources(
        tree=tree,
        revision=_revision(tree),
        sources=sources,
        defines=tuple(variables.get(f"{unit_test}_DEFINES", [])),
        include_dirs=(headers, tree / "src/main", tree / "lib/main/MAVLink"),
        sha256=digest.hexdigest(),
    )


def patched_tree(project_dir: Path | None) -> Path:
    """betaflight/ of the project, holding the series: fetched and patched when it is not.

    A tree that already holds the series is used as it is, uncommitted edits included (the
    report names the revision and marks it dirty), so a change can be measured before it is
    exported; a pristine or outdated tree gets the series applied, as `wftool build`.
    """
    from wftool.firmware import find_project, patches, tree
    from wftool.firmware.project import exclusive
    from wftool.firmware.targets import SITL, resolve_target

    project = find_project(project_dir)
    with exclusive(project):
        if not tree.is_checked_out(project):
            tree.ensure_tree(project, resolve_target(project, SITL))
        current = patches.status(project)
        if current.state in ("pristine", "outdated") and not current.dirty:
            patches.apply(project)
    return project.tree


def arm_gcc(project_dir: Path | None) -> Path:
    """arm-none-eabi-gcc as `wftool build speedybeef7v3` would find it."""
    from wftool.firmware import BuildOptions, builder, find_project
    from wftool.firmware.targets import resolve_target

    project = find_project(project_dir)
    target = resolve_target(project, BOARD_TARGET)
    return builder.find_toolchain(project, target, BuildOptions()).gcc


def _unit_test_headers(tree: Path) -> list[str]:
    """The unit tests' headers below src/test/unit, without the per-test *.include dirs."""
    listing = git_out(["ls-tree", "-r", "--name-only", "HEAD", "--", f"{UNIT_TEST_DIR}/"], tree)
    names = [path[len(UNIT_TEST_DIR) + 1 :] for path in listing.splitlines()]
    return [
        name
        for name in names
        if name.endswith(".h") and not any(part.endswith(".include") for part in name.split("/"))
    ]


def _revision(tree: Path) -> str:
    head = git_out(["rev-parse", "HEAD"], tree)
    dirty = git_out(["status", "--porcelain", "--untracked-files=no"], tree)
    return f"{head}-dirty" if dirty.strip() else head
