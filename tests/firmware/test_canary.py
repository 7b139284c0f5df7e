"""The upstream canary (`wftool patches check --against REF`) against real Betaflight trees:
a series made up for the test meets a release it was not written on (each outcome once), and
the project's own series its own pin (everything applies, builds and passes)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from tests.conftest import REPO, run_cli
from wftool.fc.versions import BETAFLIGHT_2025_12, BETAFLIGHT_2026_6
from wftool.firmware import tree
from wftool.firmware.canary import Applied, check_against
from wftool.firmware.project import Project

VERSION_H = "src/main/build/version.h"
PROTOCOL_H = "src/main/msp/msp_protocol.h"
NOWHERE = "src/main/canary_nowhere.c"


def git(cwd: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
        cwd=cwd, check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip


@pytest.fixture
def made_up(fresh_clone: Project, tmp_path: Path) -> tuple[Project, str]:
    """A clone of this repository whose series is four patches written on its pin, and a
    release that is not the pin: one already there (its version.h), one that applies (a new
    file), one that conflicts (another MSP API version), one git cannot even merge (a file
    neither the pin nor the release has: the series does not apply to its own pin there)."""
    project = Project(tmp_path / "wftool")
    git(tmp_path, "clone", "-q", str(REPO), str(project.root))
    pin = tree.pinned_commit(project)
    ref = BETAFLIGHT_2026_6 if pin != BETAFLIGHT_2026_6.commit else BETAFLIGHT_2025_12
    upstream = tmp_path / "upstream"
    git(tmp_path, "init", "-q", str(upstream))
    git(upstream, "remote", "add", "origin", tree.submodule_url(project))
    for commit in (pin, ref.commit):
        tree.ensure_commit(upstream, commit)
    work = tmp_path / "work"  # the pin's files, and one no Betaflight has
    git(tmp_path, "init", "-q", str(work))
    for path in (VERSION_H, PROTOCOL_H):
        (work / path).parent.mkdir(parents=True, exist_ok=True)
        (work / path).write_text(git(upstream, "cat-file", "-p", f"{pin}:{path}") + "\n")
    (work / NOWHERE).write_text("int canary;\n")
    git(work, "add", ".")
    git(work, "commit", "-q", "-m", "base")
    base = git(work, "rev-parse", "HEAD")

    def commit(subject: str, path: str, text: str) -> None:
        (work / path).write_text(text)
        git(work, "add", path)
        git(work, "commit", "-q", "-m", subject)

    commit(
        "upstream has it",
        VERSION_H,
        git(upstream, "cat-file", "-p", f"{ref.commit}:{VERSION_H}") + "\n",
    )
    commit("a new file", "src/main/canary_new.c", "int fresh;\n")
    protocol = (work / PROTOCOL_H).read_text()  # the API minor version: another in REF
    commit("conflicts", PROTOCOL_H, re.sub(r"(API_VERSION_MINOR\s+)\d+", r"\g<1>99", protocol))
    commit("cannot merge", NOWHERE, "int canary = 1;\n")
    for old in project.patches_dir.glob("*.patch"):
        old.unlink()
    git(work, "format-patch", "-q", "--full-index", "-o", str(project.patches_dir), base)
    return project, ref.release


def test_each_outcome_of_a_patch_on_another_release(made_up: tuple[Project, str]) -> None:
    project, ref = made_up
    report = check_against(project, ref, build=False)
    assert report.version == ref
    outcome = [(c.applied, c.conflicts, c.taken, c.built) for c in report.checks]
    assert outcome == [
        (Applied.UPSTREAM, (), False, None),
        (Applied.CLEAN, (), False, None),
        (Applied.CONFLICT, (PROTOCOL_H,), True, None),
        (Applied.CONFLICT, (NOWHERE,), False, None),
    ]
    assert not report.ok


def test_the_command_prints_the_table_and_fails(
    made_up: tuple[Project, str], capsys: pytest.CaptureFixture[str]
) -> None:
    project, ref = made_up
    code, out, err = run_cli(
        capsys, "patches", "check", "--against", ref, "--apply-only", "--markdown",
        "--project", str(project.root),
    )  # fmt: skip
    assert code == 1
    rows = [line.split(" | ")[1:4] for line in out.splitlines() if line.startswith("| 000")]
    assert rows == [
        ["already upstream", " ", "—"],
        ["applies", " ", "—"],
        ["conflicts", PROTOCOL_H, "—"],
        ["conflicts, left out", NOWHERE, "—"],
    ]
    assert err.strip().splitlines()[-1] == (
        f"error: the series does not carry over to {ref} as it is (table above)"
    )


@pytest.mark.slow
def test_the_series_on_its_own_pin_applies_builds_and_passes(
    fresh_clone: Project, tmp_path: Path
) -> None:
    report = check_against(fresh_clone, tree.pinned_commit(fresh_clone), workdir=tmp_path / "c")
    assert report.ok, [c for c in report.checks if not (c.built and c.applied is Applied.CLEAN)]
    assert all(c.applied is Applied.CLEAN and c.built for c in report.checks)
    tests = [run.name for c in report.checks for run in c.tests]
    assert "test_fsp_unittest" in tests and all(
        run.passed for c in report.checks for run in c.tests
    )
    assert not (fresh_clone.tree / ".git").exists() or tree.dirty_paths(fresh_clone) == []
