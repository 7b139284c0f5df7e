"""The upstream canary (`wftool patches check --against REF`): the series applied patch by
patch to another Betaflight (a tag, upstream master) in a scratch tree of its own, the SITL
built and each patch's unit tests run after it — what a port to REF will need.

Per patch: whether it applies as it is, only with a three-way merge, is already upstream
(nothing of it left to apply: drop it), or conflicts (which files; the series' version of
each is taken, as a port starts from, so the next patches meet what they were written on),
whether the SITL builds with it, and how its unit tests (those it adds or changes) fare.
betaflight/ is never touched; the scratch tree fetches from the submodule's URL (a mirror
through git's `url.insteadOf`), partially and sparsely, and builds offline.
"""

from __future__ import annotations

import enum
import re
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

from wftool.errors import BuildError, PatchError, TreeError, UsageError
from wftool.firmware import make, patches, toolchain, tree, unittests
from wftool.firmware.builder import make_variables
from wftool.firmware.git import git, git_out, last_line
from wftool.firmware.manifest import BuildFlags
from wftool.firmware.project import Project
from wftool.firmware.targets import SITL, resolve_target
from wftool.progress import Log, quiet

_COMMIT = re.compile(r"[0-9a-f]{40}")
_FAILED_PATH = re.compile(
    r"^(?:error: patch failed: (?P<hunk>.+?):\d+"
    r"|error: (?P<missing>[^:\n]+): (?:does not exist in index|does not match index"
    r"|already exists in (?:index|working directory)|No such file.*)"
    r"|CONFLICT \([^)]*\): (?:Merge conflict in )?(?P<conflict>\S+).*)$",
    re.MULTILINE,
)
_IDENTITY = {
    "GIT_AUTHOR_NAME": "wftool canary",
    "GIT_AUTHOR_EMAIL": "canary@wftool.invalid",
    "GIT_COMMITTER_NAME": "wftool canary",
    "GIT_COMMITTER_EMAIL": "canary@wftool.invalid",
}
_MAKE_EXIT = re.compile(r" \(make exited \d+; log: [^)]*\)$")
_VERSION_PART = re.compile(r"#define FC_VERSION_(YEAR|MONTH|PATCH_LEVEL)\s+(\d+)")


class Applied(enum.Enum):
    CLEAN = "applies"
    THREE_WAY = "3-way"
    UPSTREAM = "already upstream"
    """The change is in REF already: the patch can be dropped."""
    CONFLICT = "conflicts"


@dataclass(frozen=True)
class PatchCheck:
    """How one patch of the series fares on REF (on top of the patches before it that applied)."""

    name: str
    applied: Applied
    conflicts: tuple[str, ...] = ()
    """The files that did not apply (CONFLICT)."""
    taken: bool = False
    """A conflict resolved by taking the series' version of those files (the tree has the
    patch, to build and test it, and to try the next ones on); else it was left out."""
    built: bool | None = None
    """Whether the SITL built with it; None where it was not built (it changed nothing — a
    conflict left out, already upstream — or only applying was asked for)."""
    build_error: str | None = None
    """The SITL's first compiler error with this patch (`path:line: error: …`, the path in
    the tree; the whole log is in the scratch tree's logs/)."""
    tests: tuple[unittests.UnitTestRun, ...] = ()
    """The unit tests it adds or changes, run with it applied (and built)."""

    @property
    def changed_tree(self) -> bool:
        """Whether the tree has the patch now (applied, merged, or its conflicts taken)."""
        return self.applied in (Applied.CLEAN, Applied.THREE_WAY) or self.taken


@dataclass
class CanaryReport:
    ref: str
    commit: str
    version: str
    """Betaflight's FC_VERSION at REF (version.h)."""
    checks: list[PatchCheck] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Every patch applies (three-way merges included), builds and passes its tests."""
        return all(
            c.applied is not Applied.CONFLICT
            and c.built is not False
            and all(t.passed for t in c.tests)
            for c in self.checks
        )


def check_against(
    project: Project,
    ref: str,
    *,
    workdir: Path | None = None,
    jobs: int = 2,
    build: bool = True,
    log: Log = quiet,
) -> CanaryReport:
    """Apply the project's series to REF (tag, branch or commit id of the Betaflight repository)
    in WORKDIR (default: a temporary directory, removed afterwards), patch by patch: apply,
    and (`build`) build the SITL and run the patch's unit tests."""
    if not patches.series(project):
        raise UsageError(f"no patch series in {project.patches_dir}")
    if build:
        unittests.require_compilers()
    compiler = toolchain.host_toolchain()
    with _scratch(workdir) as scratch:
        series = _snapshot(project, scratch / "series")
        repo = scratch / "betaflight"
        commit = _fetch(project, repo, ref)
        _series_objects(project, repo, series, log)
        version = _version(repo, commit)
        log(f"{ref} is {commit[:9]}, Betaflight {version}; scratch tree {repo}")
        report = CanaryReport(ref, commit, version)
        config_dir = scratch / "targets"
        (config_dir / "configs").mkdir(parents=True)
        target = resolve_target(project, SITL)
        variables = make_variables(target, config_dir, compiler, BuildFlags())
        object_dir = scratch / "obj"
        variables |= make.object_dir_variables(repo, object_dir)
        command = make.MakeCommand(
            tree=repo,
            variables=variables,
            jobs=jobs,
            hook=object_dir / "wftool.mk",
            env={"CCACHE_BASEDIR": str(scratch), "CCACHE_NOHASHDIR": "true"},
        )
        make.write_hook(command.hook)
        for patch in series:
            check = _apply(repo, patch.path)
            if build and check.changed_tree:
                check = _build_and_test(check, command, repo, patch.path, scratch / "logs")
            log(_line(check))
            report.checks.append(check)
        return report


def _snapshot(project: Project, directory: Path) -> list[patches.Patch]:
    """The series as it is now, copied: what the run checks whatever patches/ becomes meanwhile."""
    directory.mkdir()
    copies = []
    for patch in patches.series(project):
        shutil.copyfile(patch.path, directory / patch.name)
        copies.append(patches.Patch(directory / patch.name, patch.sha256))
    return copies


def _series_objects(project: Project, repo: Path, series: list[patches.Patch], log: Log) -> None:
    """The series' own commits on its pin in REPO, so a three-way merge finds every blob a
    patch names (those between two patches exist nowhere upstream); as far as it applies."""
    parent = tree.pinned_commit(project)
    tree.ensure_commit(repo, parent)
    for patch in series:
        try:
            [parent] = patches.series_commits(repo, parent, [patch])
        except PatchError as exc:
            log(f"the series does not apply to its own pin: {exc}")
            return


@contextmanager
def _scratch(workdir: Path | None) -> Iterator[Path]:
    if workdir is None:
        with tempfile.TemporaryDirectory(prefix="wftool-canary-") as scratch:
            yield Path(scratch)
        return
    if workdir.exists() and any(workdir.iterdir()):
        raise UsageError(f"--workdir {workdir} is not empty (the canary starts from nothing)")
    workdir.mkdir(parents=True, exist_ok=True)
    yield workdir


def _fetch(project: Project, repo: Path, ref: str) -> str:
    """Make REPO a partial, sparse checkout of REF (SITL and the unit tests); its commit id."""
    git(["init", "-q", str(repo)], repo.parent, error=TreeError)
    git(["remote", "add", "origin", tree.submodule_url(project)], repo, error=TreeError)
    commit = ref if _COMMIT.fullmatch(ref) else _resolve(repo, ref)
    tree.ensure_commit(repo, commit)
    excluded = tree.excluded_paths(repo, commit, resolve_target(project, SITL))
    wanted = [path for path in excluded if path not in unittests.TEST_PATHS]
    git(["sparse-checkout", "set", "--no-cone", *tree.sparse_patterns(wanted)], repo)
    git(["checkout", "-q", "--detach", commit], repo, error=TreeError)
    return commit


def _resolve(repo: Path, ref: str) -> str:
    """The commit a tag or branch of the remote names (an annotated tag peeled)."""
    listing = git_out(
        ["ls-remote", "origin", f"refs/tags/{ref}", f"refs/tags/{ref}^{{}}", f"refs/heads/{ref}"],
        repo,
        error=TreeError,
    )
    refs = {
        name: commit for commit, _, name in (line.partition("\t") for line in listing.splitlines())
    }
    for name in (f"refs/tags/{ref}^{{}}", f"refs/tags/{ref}", f"refs/heads/{ref}"):
        if name in refs:
            return refs[name]
    raise UsageError(f"Betaflight's repository has no tag or branch {ref!r}")


def _version(repo: Path, commit: str) -> str:
    header = git_out(["cat-file", "-p", f"{commit}:src/main/build/version.h"], repo)
    parts = dict(_VERSION_PART.findall(header))
    return f"{parts.get('YEAR', '?')}.{parts.get('MONTH', '?')}.{parts.get('PATCH_LEVEL', '?')}"


def _apply(repo: Path, patch: Path) -> PatchCheck:
    """`git am` PATCH onto REPO's HEAD: as it is, else three-way. A conflict is resolved by
    taking the series' version of each conflicting file, as a port starts from; where git
    cannot even merge (a file missing on both sides), the patch is left out."""
    before = git_out(["rev-parse", "HEAD"], repo)
    plain = git(["apply", "--check", str(patch)], repo, check=False)
    applied = git(["am", "-q", "--3way", str(patch)], repo, env=_IDENTITY, check=False)
    if applied.returncode == 0:
        if git_out(["rev-parse", "HEAD"], repo) == before:  # "No changes -- already applied"
            return PatchCheck(patch.name, Applied.UPSTREAM)
        return PatchCheck(patch.name, Applied.CLEAN if plain.returncode == 0 else Applied.THREE_WAY)
    unmerged = git_out(["diff", "--name-only", "--diff-filter=U"], repo).split()
    reported = [
        next(path for path in match.groups() if path)
        for match in _FAILED_PATH.finditer(plain.stderr + applied.stdout + applied.stderr)
    ]
    conflicts = tuple(dict.fromkeys(unmerged or reported)) or (last_line(applied.stderr),)
    if unmerged:
        git(["checkout", "--theirs", "--", *unmerged], repo, check=False)
        git(["add", "--", *unmerged], repo, check=False)
        taken = git(["am", "--continue"], repo, env=_IDENTITY, check=False)
        if taken.returncode == 0:
            return PatchCheck(patch.name, Applied.CONFLICT, conflicts, taken=True)
    git(["am", "--abort"], repo, check=False)
    git(["reset", "-q", "--hard", before], repo, check=False)
    git(["clean", "-q", "-fd"], repo, check=False)  # files the patch added (ignored ones stay)
    return PatchCheck(patch.name, Applied.CONFLICT, conflicts)


def _build_and_test(
    check: PatchCheck, command: make.MakeCommand, repo: Path, patch: Path, logs: Path
) -> PatchCheck:
    build_error = None
    log = logs / f"{patch.stem}.build.log"
    try:
        make.run(command, log)
    except BuildError:
        # Which error a parallel make meets first varies from run to run: one job tells.
        try:
            make.run(replace(command, jobs=1), log)
        except BuildError as exc:  # its first error, as a path in the tree (the log is kept)
            build_error = _MAKE_EXIT.sub("", str(exc)).replace(f"{repo}/", "")
    runs = tuple(unittests.run_test(repo, name) for name in unittests.tests_of_patch(patch))
    return replace(check, built=build_error is None, build_error=build_error, tests=runs)


def _line(check: PatchCheck) -> str:
    """One patch's result as a log line."""
    applied = check.applied.value
    if check.applied is Applied.CONFLICT:
        taken = "the series' version taken" if check.taken else "left out"
        applied = f"conflicts in {', '.join(check.conflicts)} ({taken})"
    if check.built is None:
        return f"{check.name}: {applied}"
    built = "builds" if check.built else f"does not build: {check.build_error}"
    passed = sum(run.passed for run in check.tests)
    tests = f", tests {passed}/{len(check.tests)}" if check.tests else ""
    return f"{check.name}: {applied}, {built}{tests}"
