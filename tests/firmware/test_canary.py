"""The upstream canary (`wftool patches check --against REF`) against real Betaflight trees:
a series made up for the test, written on the pin, meets another release — each outcome
once: already upstream, applies, conflicts, left out; builds or not; a unit test run."""

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
MATHS_TEST = "src/test/unit/maths_unittest.cc"
README = "README.md"
NOWHERE = "src/main/canary_nowhere.c"


def git(cwd: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
        cwd=cwd, check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip


@pytest.fixture
def made_up(fresh_clone: Project, tmp_path: Path) -> tuple[Project, str]:
    """A clone of this repository whose series is five patches written on its pin, and a
    release that is not the pin: one already there (its version.h), one that applies (a new
    file, a comment in a unit test), one that conflicts (the release schedule in the
    README), one that breaks the build, one git cannot even merge (a file neither the pin
    nor the release has: the series does not apply to its own pin there)."""
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
    for path in (VERSION_H, PROTOCOL_H, MATHS_TEST, README):
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
    (work / "src/main/canary_new.c").write_text("int fresh;\n")
    git(work, "add", "src/main/canary_new.c")
    commit("applies", MATHS_TEST, (work / MATHS_TEST).read_text() + "// canary\n")
    schedule = (work / README).read_text()  # every release rewrites it
    commit("conflicts", README, re.sub(r"(?m)^\| Date .*$", "| canary |", schedule, count=1))
    commit("breaks the build", PROTOCOL_H, (work / PROTOCOL_H).read_text() + '#error "canary"\n')
    commit("cannot merge", NOWHERE, "int canary = 1;\n")
    for old in project.patches_dir.glob("*.patch"):
        old.unlink()
    git(work, "format-patch", "-q", "--full-index", "-o", str(project.patches_dir), base)
    return project, ref.release


@pytest.mark.slow
def test_each_outcome_of_a_patch_on_another_release(
    made_up: tuple[Project, str], tmp_path: Path
) -> None:
    project, ref = made_up
    report = check_against(project, ref, workdir=tmp_path / "canary")
    assert report.version == ref
    outcome = [(c.applied, c.conflicts, c.taken, c.built) for c in report.checks]
    assert outcome == [
        (Applied.UPSTREAM, (), False, None),
        (Applied.CLEAN, (), False, True),
        (Applied.CONFLICT, (README,), True, True),  # the series' version taken: it builds
        (report.checks[3].applied, (), False, False),
        (Applied.CONFLICT, (NOWHERE,), False, None),
    ]
    assert report.checks[3].applied in (Applied.CLEAN, Applied.THREE_WAY)
    [maths] = report.checks[1].tests
    assert (maths.name, maths.passed) == ("test_maths_unittest", True)
    assert re.fullmatch(
        rf'{PROTOCOL_H}:\d+: error: #error "canary"', report.checks[3].build_error or ""
    )
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
    rows = [line[2:-2].split(" | ")[1:] for line in out.splitlines() if line.startswith("| 000")]
    assert rows[3][0] in ("applies", "3-way")
    assert rows == [
        ["already upstream", " ", "—", "—"],
        ["applies", " ", "—", "—"],
        ["conflicts", README, "—", "—"],
        [rows[3][0], " ", "—", "—"],
        ["conflicts, left out", NOWHERE, "—", "—"],
    ]
    assert err.strip().splitlines()[-1] == (
        f"error: the series does not carry over to {ref} as it is (table above)"
    )
