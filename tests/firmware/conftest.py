"""Fixtures for the build tests: small real git repositories shaped like a wftool project."""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from wftool.firmware.project import Project

UPSTREAM_FILES = {
    "Makefile": "all:\n\t@echo upstream\n",
    "src/main/a.c": "int a(void)\n{\n    return 1;\n}\n",
    "src/main/b.c": "int b(void)\n{\n    return 2;\n}\n",
}


def run_git(cwd: Path, *args: str, env: dict[str, str] | None = None) -> str:
    """Run git in CWD and return its stdout (raises on failure)."""
    return subprocess.run(
        ["git", *args], cwd=cwd, env=env, check=True, capture_output=True, text=True
    ).stdout.strip()


def commit_all(
    repo: Path, message: str, date: str = "2025-01-02T03:04:05+00:00", *, add: bool = True
) -> str:
    """Commit everything in REPO (or, without ADD, the index) with a fixed identity and date."""
    if add:
        run_git(repo, "add", "-A")
    env = {
        "GIT_AUTHOR_NAME": "Test Author",
        "GIT_AUTHOR_EMAIL": "author@example.invalid",
        "GIT_AUTHOR_DATE": date,
        "GIT_COMMITTER_NAME": "Someone Else",
        "GIT_COMMITTER_EMAIL": "committer@example.invalid",
        "GIT_COMMITTER_DATE": "2030-01-01T00:00:00+00:00",
        "PATH": "/usr/bin:/bin",
        "HOME": str(repo),
    }
    run_git(repo, "commit", "-q", "-m", message, env=env)
    return run_git(repo, "rev-parse", "HEAD")


def write_files(root: Path, files: dict[str, str]) -> None:
    """Create FILES (relative path -> text) under ROOT."""
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


@pytest.fixture
def upstream(tmp_path: Path) -> tuple[Path, str]:
    """A tiny stand-in for Betaflight: one commit, returned with its hash (the pin)."""
    repo = tmp_path / "upstream"
    repo.mkdir()
    run_git(repo, "init", "-q")
    write_files(repo, UPSTREAM_FILES)
    return repo, commit_all(repo, "Upstream release")


@pytest.fixture
def fixture_project(tmp_path: Path, upstream: tuple[Path, str]) -> Project:
    """A wftool-shaped superproject pinning UPSTREAM, with betaflight/ checked out."""
    repo, pin = upstream
    root = tmp_path / "project"
    root.mkdir()
    run_git(root, "init", "-q")
    (root / ".gitmodules").write_text(
        f'[submodule "betaflight"]\n\tpath = betaflight\n\turl = {repo}\n\tignore = all\n'
    )
    run_git(root, "add", ".gitmodules")
    run_git(root, "update-index", "--add", "--cacheinfo", f"160000,{pin},betaflight")
    commit_all(root, "Pin upstream", add=False)
    run_git(root, "clone", "-q", str(repo), "betaflight")
    run_git(root / "betaflight", "checkout", "-q", "--detach", pin)
    (root / "patches").mkdir()
    return Project(root)


@pytest.fixture
def make_patch(tmp_path: Path, upstream: tuple[Path, str]) -> Callable[..., Path]:
    """Write a format-patch file into a project's patches/ from edits on top of a base.

    make_patch(project, "0001-x.patch", {"src/main/a.c": "..."}, base=None) commits the edits
    on BASE (default: the previous patch, else the pin) in a scratch clone and exports them.
    """
    repo, pin = upstream
    scratch = tmp_path / "patch-scratch"
    run_git(tmp_path, "clone", "-q", str(repo), str(scratch))
    run_git(scratch, "checkout", "-q", "--detach", pin)

    def make(
        project: Project,
        name: str,
        files: dict[str, str],
        *,
        base: str | None = None,
        date: str = "2025-02-03T04:05:06+00:00",
    ) -> Path:
        if base is not None:
            run_git(scratch, "checkout", "-q", "--detach", base)
        write_files(scratch, files)
        commit_all(scratch, f"Change {name}\n\nWhy: testing.", date=date)
        patch_text = run_git(scratch, "format-patch", "--stdout", "-1", "HEAD") + "\n"
        path = project.patches_dir / name
        path.write_text(patch_text)
        return path

    return make
