"""The Betaflight source tree: the pinned submodule, fetched as a shallow, blob-less, sparse
clone of exactly the pinned commit, with only what the target needs (docs/build.md).
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import TreeError
from wftool.firmware.git import git, git_out
from wftool.firmware.project import SUBMODULE_PATH, Project
from wftool.firmware.targets import Target

ALWAYS_EXCLUDED = ("src/test", "lib/test", "images")
"""Top-level paths no firmware build reads: Betaflight's unit tests and documentation images."""

_VENDOR_LIBRARY = re.compile(r"^(STM32|AT32|APM32|GD32)(?!_USB)\w*$")
"""lib/main entries that are one MCU family's vendor library (HAL, CMSIS device files...)."""

_MCU_FAMILY = re.compile(r"^\s*TARGET_MCU_FAMILY\s*:?=\s*(\S+)", re.MULTILINE)


@dataclass(frozen=True)
class McuLayout:
    """Where an MCU lives in the Betaflight tree."""

    platform: str
    """The directory under src/platform/ (STM32, SIMULATOR, ...)."""
    family: str
    """TARGET_MCU_FAMILY from the MCU's target.mk (STM32F7, SITL, ...)."""


def pinned_commit(project: Project) -> str:
    """The Betaflight commit the superproject's HEAD pins (its gitlink)."""
    listing = git_out(["ls-tree", "HEAD", SUBMODULE_PATH], project.root, error=TreeError)
    fields = listing.split()
    if len(fields) < 3 or fields[1] != "commit":
        raise TreeError(f"{project.root}: HEAD has no gitlink for {SUBMODULE_PATH}/")
    return fields[2]


def submodule_url(project: Project) -> str:
    """The submodule's URL as .gitmodules declares it (git's url.insteadOf applies on fetch)."""
    paths = git_out(
        ["config", "-f", ".gitmodules", "--get-regexp", r"^submodule\..*\.path$"],
        project.root,
        error=TreeError,
    )
    for line in paths.splitlines():
        key, _, value = line.partition(" ")
        if value == SUBMODULE_PATH:
            name = key[len("submodule.") : -len(".path")]
            return git_out(
                ["config", "-f", ".gitmodules", f"submodule.{name}.url"],
                project.root,
                error=TreeError,
            )
    raise TreeError(f"{project.root}/.gitmodules declares no {SUBMODULE_PATH} submodule")


def is_checked_out(project: Project) -> bool:
    """Whether betaflight/ is a git work tree of its own (not an empty submodule directory)."""
    if not (project.tree / ".git").exists():
        return False
    toplevel = git(["rev-parse", "--show-toplevel"], project.tree, check=False)
    return toplevel.returncode == 0 and Path(toplevel.stdout.strip()) == project.tree.resolve()


def head(project: Project) -> str:
    """The commit betaflight/ has checked out."""
    return git_out(["rev-parse", "HEAD"], project.tree, error=TreeError)


def read_at(project: Project, commit: str, path: str) -> str:
    """The text of PATH at COMMIT (fetched on demand in the partial clone)."""
    return git_out(["cat-file", "-p", f"{commit}:{path}"], project.tree, error=TreeError)


def changed_files(project: Project, base: str, head: str) -> list[str]:
    """Paths that differ between two commits of betaflight/."""
    return git_out(["diff", "--name-only", base, head], project.tree, error=TreeError).split("\n")


def dirty_paths(project: Project) -> list[str]:
    """Modified, staged or untracked (and not ignored) paths in betaflight/."""
    status = git_out(["status", "--porcelain", "--untracked-files=all"], project.tree)
    return [line[3:] for line in status.splitlines() if line.strip()]


def discard_changes(project: Project) -> None:
    """Throw away uncommitted changes and untracked files (build outputs are ignored, kept)."""
    git(["reset", "-q", "--hard"], project.tree, error=TreeError)
    git(["clean", "-q", "-fd"], project.tree, error=TreeError)


def ensure_commit(repo: Path, commit: str) -> None:
    """Make COMMIT (with its trees, without blobs) present in REPO, fetching it if needed."""
    if git(["cat-file", "-e", f"{commit}^{{commit}}"], repo, check=False).returncode == 0:
        return
    git(
        ["fetch", "-q", "--filter=blob:none", "--depth=1", "--no-tags", "origin", commit],
        repo,
        error=TreeError,
    )


def ensure_tree(project: Project, target: Target, *, allow_dirty: bool = False) -> None:
    """Make betaflight/ a checkout holding the pinned commit and what TARGET needs.

    Fetches the tree when absent. A dirty tree is refused, unless ALLOW_DIRTY: then the
    caller decides (`patches.apply` discards changes only once the series is known to
    apply). Which commit ends up checked out (the pin plus the series) is the patches
    module's business.
    """
    pin = pinned_commit(project)
    if not is_checked_out(project):
        fetch_tree(project, pin, target)
        return
    dirty = dirty_paths(project)
    if dirty and not allow_dirty:
        shown = ", ".join(dirty[:3]) + (", ..." if len(dirty) > 3 else "")
        raise TreeError(
            f"betaflight/ has uncommitted changes ({shown}); commit them and run "
            "`wftool patches export`, or pass --clean to discard them"
        )
    ensure_commit(project.tree, pin)
    widen_checkout(project, pin, target)


def fetch_tree(project: Project, pin: str, target: Target) -> None:
    """Clone PIN partially and sparsely into betaflight/ and register it as the submodule.

    The clone is built in a scratch directory and moved into place only when complete, so an
    interrupted fetch never leaves a half tree that looks usable.
    """
    scratch = project.root / f".{SUBMODULE_PATH}.fetching"
    shutil.rmtree(scratch, ignore_errors=True)
    try:
        git(["init", "-q", str(scratch)], project.root, error=TreeError)
        git(["remote", "add", "origin", submodule_url(project)], scratch, error=TreeError)
        ensure_commit(scratch, pin)
        patterns = sparse_patterns(excluded_paths(scratch, pin, target))
        git(["sparse-checkout", "set", "--no-cone", *patterns], scratch, error=TreeError)
        git(["checkout", "-q", "--detach", pin], scratch, error=TreeError)
        if project.tree.exists():
            project.tree.rmdir()  # the empty directory git leaves for an uninitialised submodule
        scratch.rename(project.tree)
    except OSError as exc:
        raise TreeError(f"cannot fetch Betaflight into {project.tree}: {exc}") from exc
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    git(["submodule", "init", "--", SUBMODULE_PATH], project.root, error=TreeError)
    git(["submodule", "absorbgitdirs", "--", SUBMODULE_PATH], project.root, error=TreeError)


def widen_checkout(project: Project, pin: str, target: Target) -> None:
    """Check out what TARGET needs in addition to what earlier builds needed."""
    current = current_exclusions(project.tree)
    if not current:  # a full checkout already has everything
        return
    wanted = current & set(excluded_paths(project.tree, pin, target))
    if wanted != current:
        git(
            ["sparse-checkout", "set", "--no-cone", *sparse_patterns(sorted(wanted))],
            project.tree,
            error=TreeError,
        )


def current_exclusions(repo: Path) -> set[str]:
    """The paths the sparse checkout leaves out now."""
    listing = git(["sparse-checkout", "list"], repo, check=False).stdout
    return {line[2:-1] for line in listing.splitlines() if line.startswith("!/")}


def sparse_patterns(excluded: list[str]) -> list[str]:
    """Non-cone sparse-checkout patterns: everything except the EXCLUDED directories."""
    return ["/*", *(f"!/{path}/" for path in excluded)]


def excluded_paths(repo: Path, commit: str, target: Target) -> list[str]:
    """The directories of COMMIT's tree that building TARGET does not read."""
    layout = mcu_layout(repo, commit, target.mcu)
    platforms = _subtrees(repo, commit, "src/platform")
    libraries = _subtrees(repo, commit, "lib/main")
    excluded = [
        f"src/platform/{name}" for name in platforms if name not in ("common", layout.platform)
    ]
    for name in libraries:
        if _VENDOR_LIBRARY.match(name):
            needed = name.startswith(layout.family) or layout.family.startswith(name)
        elif name.startswith("STM32_USB"):
            needed = layout.platform == "STM32"
        else:
            needed = True
        if not needed:
            excluded.append(f"lib/main/{name}")
    for path in ALWAYS_EXCLUDED:
        parent, _, name = path.rpartition("/")
        if name in _subtrees(repo, commit, parent):
            excluded.append(path)
    return sorted(excluded)


def mcu_layout(repo: Path, commit: str, mcu: str) -> McuLayout:
    """Find the platform and MCU family of MCU (e.g. STM32F722 -> STM32, STM32F7) at COMMIT."""
    names = git_out(
        ["ls-tree", "-r", "--name-only", commit, "--", "src/platform"], repo, error=TreeError
    )
    pattern = re.compile(rf"src/platform/([^/]+)/target/{re.escape(mcu)}/target\.mk")
    for path in names.splitlines():
        match = pattern.fullmatch(path)
        if match:
            target_mk = git_out(["cat-file", "-p", f"{commit}:{path}"], repo, error=TreeError)
            family = _MCU_FAMILY.search(target_mk)
            if family is None:
                raise TreeError(f"{path} does not set TARGET_MCU_FAMILY")
            return McuLayout(platform=match.group(1), family=family.group(1))
    raise TreeError(f"Betaflight {commit[:9]} has no MCU target {mcu} (src/platform/*/target/)")


def _subtrees(repo: Path, commit: str, directory: str) -> list[str]:
    """Names of the directories and submodules directly inside DIRECTORY at COMMIT."""
    spec = f"{commit}:{directory}" if directory else commit
    listing = git_out(["ls-tree", spec], repo, error=TreeError)
    return [
        line.split("\t", 1)[1]
        for line in listing.splitlines()
        if line.split()[1] in ("tree", "commit")
    ]
