"""The patch series: patches/NNNN-*.patch applied as commits on top of the Betaflight pin,
atomically and deterministically (the same patched commit on every machine), and exported
back from commits made on top of it (docs/build.md).
"""

from __future__ import annotations

import hashlib
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import PatchError
from wftool.firmware import tree
from wftool.firmware.git import TEXT_ERRORS, git, git_out
from wftool.firmware.project import Project

MANAGED_REF = "refs/wftool/managed"
"""The commit wftool last checked out in betaflight/ (pin or pin + series)."""

_PATCH_FAILED = re.compile(r"^error: patch failed: (?P<path>.+?):(?P<line>\d+)$", re.MULTILINE)
_PATH_ERROR = re.compile(r"^error: (?P<path>[^:\n]+): (?P<reason>.+)$", re.MULTILINE)

# format-patch settings that keep an exported series byte-stable across machines and users:
# no commit hashes, no git version, full blob ids, no "[PATCH n/m]" renumbering churn.
_FORMAT_PATCH_ARGS = (
    "format-patch",
    "--zero-commit",
    "--no-signature",
    "--full-index",
    "--no-numbered",
    "--no-thread",
    "--no-to",
    "--no-cc",
    "--no-attach",
    "--stat=72",
    "--src-prefix=a/",
    "--dst-prefix=b/",
)
_FORMAT_PATCH_CONFIG = ("-c", "diff.noprefix=false", "-c", "diff.mnemonicPrefix=false")


@dataclass(frozen=True)
class Patch:
    """One file of the series."""

    path: Path
    sha256: str

    @property
    def name(self) -> str:
        """The file name, e.g. 0001-Add-FSP.patch."""
        return self.path.name


@dataclass(frozen=True)
class SeriesStatus:
    """Where betaflight/ stands relative to the pin and the series."""

    pin: str
    head: str
    expected: str
    """The commit the series produces on the pin (the pin itself for an empty series)."""
    patches: list[Patch]
    applied: list[bool]
    """Per patch: whether a commit with the same change (patch-id) is in pin..HEAD."""
    dirty: list[str]
    replaceable: bool
    """Whether HEAD may be moved without losing commits (managed, pin, or exported work)."""
    problem: str | None = None
    """Why the series does not apply to the pin, if it does not."""

    @property
    def state(self) -> str:
        """One word: applied, pristine, outdated (replaceable, not the series) or modified."""
        if self.head == self.expected:
            return "applied"
        if self.head == self.pin:
            return "pristine"
        return "outdated" if self.replaceable else "modified"


def series(project: Project) -> list[Patch]:
    """The series in application order (file name order, as git format-patch numbers them)."""
    if not project.patches_dir.is_dir():
        return []
    return [
        Patch(path, hashlib.sha256(path.read_bytes()).hexdigest())
        for path in sorted(project.patches_dir.glob("*.patch"))
    ]


def series_sha256(patches: list[Patch]) -> str:
    """One hash over the ordered series: names and contents."""
    digest = hashlib.sha256()
    for patch in patches:
        digest.update(f"{patch.name} {patch.sha256}\n".encode())
    return digest.hexdigest()


def series_commits(repo: Path, base: str, patches: list[Patch]) -> list[str]:
    """Commit PATCHES on BASE in a scratch index; return the new commits, oldest first.

    Raises PatchError naming the patch and the file that did not apply. Touches neither the
    work tree nor the real index; the commits are deterministic (docs/build.md).
    """
    commits: list[str] = []
    parent = base
    with tempfile.TemporaryDirectory(prefix="wftool-am-") as scratch:
        index = {"GIT_INDEX_FILE": str(Path(scratch) / "index")}
        git(["read-tree", base], repo, env=index, error=PatchError)
        for patch in patches:
            message_file, diff_file = Path(scratch) / "msg", Path(scratch) / "diff"
            info = git(
                ["mailinfo", str(message_file), str(diff_file)],
                repo,
                input=patch.path.read_text(errors=TEXT_ERRORS),
                error=PatchError,
            ).stdout
            header = dict(line.split(": ", 1) for line in info.splitlines() if ": " in line)
            if diff_file.stat().st_size:
                applied = git(
                    ["apply", "--cached", "--whitespace=nowarn", str(diff_file)],
                    repo,
                    env=index,
                    check=False,
                )
                if applied.returncode != 0:
                    raise PatchError(_describe_failure(patch, applied.stderr))
            # --missing-ok: in the partial clone most blobs are absent (and some, too big for
            # the mirror, cannot be fetched at all); a tree only names them.
            tree_id = git_out(["write-tree", "--missing-ok"], repo, env=index, error=PatchError)
            body = message_file.read_text(errors=TEXT_ERRORS).strip()
            subject = header.get("Subject", patch.path.stem)
            message = f"{subject}\n\n{body}\n" if body else f"{subject}\n"
            identity = {
                "GIT_AUTHOR_NAME": header.get("Author", "unknown"),
                "GIT_AUTHOR_EMAIL": header.get("Email", ""),
                "GIT_AUTHOR_DATE": header.get("Date", "1970-01-01T00:00:00Z"),
            }
            identity |= {
                key.replace("AUTHOR", "COMMITTER"): value for key, value in identity.items()
            }
            parent = git_out(
                ["commit-tree", tree_id, "-p", parent, "-F", "-"],
                repo,
                env=identity,
                input=message,
                error=PatchError,
            )
            commits.append(parent)
    return commits


def status(project: Project) -> SeriesStatus:
    """Compare betaflight/ with the pin and the series (the tree must be checked out)."""
    _require_tree(project)
    pin = tree.pinned_commit(project)
    tree.ensure_commit(project.tree, pin)
    head = tree.head(project)
    patches = series(project)
    problem = None
    try:
        expected = (series_commits(project.tree, pin, patches) or [pin])[-1]
    except PatchError as exc:
        expected, problem = "", str(exc)
    series_ids = [
        _patch_id(project.tree, patch.path.read_text(errors=TEXT_ERRORS)) for patch in patches
    ]
    head_ids = _commit_patch_ids(project.tree, pin, head)
    managed = git(["rev-parse", "-q", "--verify", MANAGED_REF], project.tree, check=False)
    replaceable = head in (pin, managed.stdout.strip()) or (
        bool(head_ids) and head_ids == series_ids
    )
    return SeriesStatus(
        pin=pin,
        head=head,
        expected=expected,
        patches=patches,
        applied=[patch_id in set(head_ids) for patch_id in series_ids],
        dirty=tree.dirty_paths(project),
        replaceable=replaceable,
        problem=problem,
    )


def apply(project: Project, *, force: bool = False, override: str = "pass --force") -> bool:
    """Put betaflight/ at pin + series; return whether anything changed.

    Refuses a dirty tree and commits that are not the series (export them first), unless
    FORCE (OVERRIDE says how on the command line: "pass --force"). Whether the series applies is
    checked first, so a series that does not apply raises PatchError before anything is
    discarded; a tree with nothing to lose is then left at the pristine pin.
    """
    current = status(project)
    if current.head == current.expected and not current.dirty:
        _mark_managed(project, current.head)
        return False
    if current.problem:
        if current.replaceable and not current.dirty:
            _checkout(project, current.pin)
            raise PatchError(f"{current.problem}; betaflight/ is back at the pristine pin")
        raise PatchError(f"{current.problem}; betaflight/ is left as it was, nothing discarded")
    _require_replaceable(current, force, "apply the series", override)
    if current.dirty:
        tree.discard_changes(project)
    try:
        commits = series_commits(project.tree, current.pin, current.patches)
    except PatchError as exc:
        _checkout(project, current.pin)
        raise PatchError(f"{exc}; betaflight/ is back at the pristine pin") from None
    _checkout(project, commits[-1] if commits else current.pin)
    return True


def reset(project: Project, *, force: bool = False, override: str = "pass --force") -> bool:
    """Return betaflight/ to the pristine pin; return whether anything changed."""
    current = status(project)
    if current.head == current.pin and not current.dirty:
        _mark_managed(project, current.pin)
        return False
    _require_replaceable(current, force, "reset", override)
    if current.dirty:
        tree.discard_changes(project)
    _checkout(project, current.pin)
    return True


def export(project: Project) -> list[str]:
    """Write the commits pin..HEAD as the new series in patches/; return the file names.

    The old series is replaced; afterwards the tree is re-applied from the files, so HEAD is
    the deterministic commit every other machine will build.
    """
    _require_tree(project)
    pin = tree.pinned_commit(project)
    head = tree.head(project)
    dirty = tree.dirty_paths(project)
    if dirty:
        raise PatchError(
            f"betaflight/ has uncommitted changes ({dirty[0]}, ...); commit them first"
        )
    if not _descends_from(project.tree, pin, head):
        raise PatchError(f"betaflight/ HEAD {head[:9]} is not based on the pin {pin[:9]}")
    merges = git_out(["rev-list", "--merges", f"{pin}..{head}"], project.tree)
    if merges:
        raise PatchError("pin..HEAD contains merge commits; a patch series must be linear")
    with tempfile.TemporaryDirectory(prefix="wftool-export-") as scratch:
        git(
            [*_FORMAT_PATCH_CONFIG, *_FORMAT_PATCH_ARGS, "-o", scratch, f"{pin}..{head}"],
            project.tree,
            error=PatchError,
        )
        written = sorted(Path(scratch).glob("*.patch"))
        project.patches_dir.mkdir(exist_ok=True)
        for old in project.patches_dir.glob("*.patch"):
            if old.name not in {path.name for path in written}:
                old.unlink()
        for path in written:
            destination = project.patches_dir / path.name
            if not destination.exists() or destination.read_bytes() != path.read_bytes():
                shutil.copyfile(path, destination)
    apply(project)
    return [path.name for path in written]


def _require_tree(project: Project) -> None:
    if not tree.is_checked_out(project):
        raise PatchError(
            "betaflight/ is not checked out; `wftool build <target>` or "
            "`wftool patches apply` fetches it"
        )


def _require_replaceable(current: SeriesStatus, force: bool, action: str, override: str) -> None:
    """Refuse to lose work: uncommitted changes, or commits that are not the series."""
    if force or (current.replaceable and not current.dirty):
        return
    if current.dirty:
        detail = f"uncommitted changes ({current.dirty[0]}, ...)"
        keep = "commit them and run `wftool patches export` to keep them"
    else:
        detail = f"commits on top of the pin that are not the series (HEAD {current.head[:9]})"
        keep = "run `wftool patches export` to keep them"
    raise PatchError(
        f"betaflight/ has {detail}; {keep}, or {override} to {action} anyway (which discards them)"
    )


def _checkout(project: Project, commit: str) -> None:
    """Move betaflight/ to COMMIT, leaving a clean tree, and remember it as managed."""
    git(["checkout", "-q", "--detach", "--force", commit], project.tree, error=PatchError)
    git(["clean", "-q", "-fd"], project.tree, error=PatchError)
    _mark_managed(project, commit)


def _mark_managed(project: Project, commit: str) -> None:
    git(["update-ref", MANAGED_REF, commit], project.tree, error=PatchError)


def _descends_from(repo: Path, ancestor: str, commit: str) -> bool:
    merge_base = git(["merge-base", "--is-ancestor", ancestor, commit], repo, check=False)
    return merge_base.returncode == 0


def _patch_id(repo: Path, diff: str) -> str:
    """git's stable patch-id of one patch (the same change gives the same id)."""
    output = git(["patch-id", "--stable"], repo, input=diff).stdout
    return output.split()[0] if output.strip() else ""


def _commit_patch_ids(repo: Path, base: str, head: str) -> list[str]:
    """The patch-ids of the commits base..head, oldest first (empty commits give "")."""
    if not _descends_from(repo, base, head):
        return []
    commits = git_out(["rev-list", "--reverse", f"{base}..{head}"], repo).split()
    return [
        _patch_id(repo, git(["show", "--format=", "-p", commit], repo).stdout) for commit in commits
    ]


def _describe_failure(patch: Patch, stderr: str) -> str:
    """'0002-x.patch does not apply: src/main/fc/core.c (patch failed at line 12)'."""
    failed = _PATCH_FAILED.search(stderr)
    if failed:
        where = f"{failed.group('path')} (hunk at line {failed.group('line')} does not match)"
    else:
        path_error = _PATH_ERROR.search(stderr)
        where = (
            f"{path_error.group('path')} ({path_error.group('reason')})"
            if path_error
            else stderr.strip() or "git apply failed"
        )
    return f"{patch.name} does not apply: {where}"
