"""End to end: a fresh clone of this repository, the real Betaflight tree, real make.

The clone and its first builds are session fixtures (tests/conftest.py) shared with the
firmware and stream tests. Skipped only when the Betaflight repository cannot be reached.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from intelhex import IntelHex

from wftool.errors import TreeError
from wftool.firmware import BuildFlags, BuildOptions, build, patches, tree
from wftool.firmware.project import Project
from wftool.firmware.targets import resolve_target

from .conftest import commit_all, run_git

REPO = Path(__file__).resolve().parents[2]
BOARD = "SPEEDYBEEF7V3"
JOBS = min(os.cpu_count() or 1, 2)


@pytest.fixture(scope="session")
def project(fresh_clone: Project, sitl_build, board_build) -> Project:
    """The run's clone, its builds made first: one another test started meanwhile would hold
    the clone's lock while these run wftool in it ("waiting for another wftool run")."""
    return fresh_clone


@pytest.fixture(scope="session")
def sitl(sitl_build):
    return sitl_build


@pytest.fixture(scope="session")
def board(board_build):
    return board_build


def test_fresh_clone_gets_a_sparse_pinned_submodule(project, sitl):
    pin = tree.pinned_commit(project)
    status = run_git(project.root, "submodule", "status", "betaflight").split()
    assert status[0].lstrip("+") == tree.head(project) and status[1] == "betaflight"
    assert run_git(project.tree, "rev-parse", "--is-shallow-repository") == "true"
    assert run_git(project.tree, "config", "remote.origin.partialclonefilter") == "blob:none"
    sparse = run_git(project.tree, "sparse-checkout", "list").splitlines()
    assert "!/src/platform/AT32/" in sparse
    assert not (project.tree / "lib" / "main" / "STM32H7").exists()
    assert (project.tree / ".git").is_file()  # absorbed into the superproject's modules/
    base = run_git(project.tree, "rev-list", "--max-parents=0", "HEAD")
    assert sitl.manifest.betaflight_commit == pin == base


def test_sitl_manifest_and_runnable_program(project, sitl, tmp_path):
    data = sitl.manifest.to_json()
    assert data["schema"] == 1
    assert (data["target"], data["board"], data["mcu"]) == ("sitl", "SITL", "SITL")
    assert data["betaflight_version"] == "2026.6.1"
    assert data["git_revision"] == run_git(project.tree, "rev-parse", "--short=9", "HEAD")
    assert data["git_revision_msp"] == data["git_revision"][:7]
    assert data["patches"] == [
        {"name": path.name, "sha256": _sha256(path)}
        for path in sorted(project.patches_dir.glob("*.patch"))
    ]
    assert data["board_config_sha256"] is None
    assert data["toolchain"]["required"] is None
    assert data["flags"] == {
        "fsp_rate_hz": None,
        "mavlink_tunnel": False,
        "defines": [],
        "debug": False,
    }
    assert data["usage"]["flash_bytes"] > 100_000
    assert set(data["artifacts"]) == {"exe", "elf"}
    program = sitl.out_dir / data["artifacts"]["exe"]
    assert data["git_revision"].encode() in program.read_bytes()
    assert _sitl_starts(program, tmp_path)


def test_second_build_is_a_noop(project, sitl):
    manifest_mtime = sitl.manifest_path.stat().st_mtime_ns

    again = build(project, "sitl", BuildOptions(jobs=JOBS))

    # nothing compiled, linked or copied (how fast that is: `wftool bench build`)
    assert again.up_to_date and (again.compiled, again.seconds) == (0, 0.0)
    assert sitl.manifest_path.stat().st_mtime_ns == manifest_mtime


def test_a_changed_header_recompiles_what_includes_it(project, sitl):
    """make's dependency files and its own names for the objects agree (ccache hands the
    compiler relative paths): a header newer than the objects recompiles its includers."""
    from wftool.firmware import builder, make

    header = project.tree / "src" / "main" / "io" / "fsp_queue.h"
    was = header.stat()
    os.utime(header)  # now: newer than every object, older than what compiles next
    try:
        units = make.plan(builder.prepare(project, "sitl", BuildOptions(jobs=JOBS)).command).units
        assert {"./src/main/io/fsp.c", "./src/main/io/fsp_queue.c"} <= set(units), units
        assert "./src/main/io/fsp_codec.c" not in units  # it does not include it
        again = build(project, "sitl", BuildOptions(jobs=JOBS))
        assert again.compiled == len(units)
        assert build(project, "sitl", BuildOptions(jobs=JOBS)).up_to_date
    finally:  # as it was: the board build's objects, older than now, stay up to date
        os.utime(header, ns=(was.st_atime_ns, was.st_mtime_ns))
        build(project, "sitl", BuildOptions(jobs=JOBS))


def test_flags_select_their_own_objects(project, sitl):
    flagged = build(
        project,
        "sitl",
        BuildOptions(jobs=JOBS, flags=BuildFlags(fsp_rate_hz=500, defines=("WFTOOL_E2E=1",))),
    )
    assert not flagged.up_to_date and flagged.compiled > 200
    assert flagged.manifest.to_json()["flags"]["fsp_rate_hz"] == 500
    assert flagged.manifest.to_json()["flags"]["defines"] == ["WFTOOL_E2E=1"]
    log = (flagged.out_dir / "build.log").read_text()
    assert "-DFSP_RATE_HZ_DEFAULT=500 -DWFTOOL_E2E=1" in log

    back = build(project, "sitl", BuildOptions(jobs=JOBS))

    assert not back.up_to_date  # the outputs are switched back ...
    assert back.compiled == 0  # ... from objects that are still up to date
    assert back.manifest.to_json()["flags"]["defines"] == []
    assert build(project, "sitl", BuildOptions(jobs=JOBS)).up_to_date


def test_a_build_carries_the_date_it_was_built_for(project, sitl, monkeypatch):
    """ccache serves the units by direct mode, the STM32 HAL's __TIME__ notwithstanding
    (builder.CCACHE_DIRECT); version.c expands __DATE__ and __TIME__ and is compiled for each
    date (SOURCE_DATE_EPOCH), never served for it by a build of another date."""
    version_c = project.tree / "src" / "main" / "build" / "version.c"
    was = version_c.stat()
    committed = int(run_git(project.root, "log", "-1", "--format=%ct"))

    def build_dated(epoch: int) -> bytes:
        monkeypatch.setenv("SOURCE_DATE_EPOCH", str(epoch))
        os.utime(version_c)  # newer than its object: make compiles it again, through ccache
        dated = build(project, "sitl", BuildOptions(jobs=JOBS))
        assert dated.compiled == 1
        return dated.firmware.read_bytes()

    dated = None
    try:
        for dated in (committed + 40 * 86400 + 3661, committed):  # then the run's date again
            when = time.gmtime(dated)
            stamps = {
                f"{time.strftime('%b', when)} {when.tm_mday:2d} {when.tm_year}",  # __DATE__
                time.strftime("%H:%M:%S", when),  # __TIME__
            }
            image = build_dated(dated)
            assert {stamp for stamp in stamps if stamp.encode() in image} == stamps
    finally:  # as it was: the run's build date (tests/conftest.py), version.c's time
        if dated != committed:
            build_dated(committed)
        os.utime(version_c, ns=(was.st_atime_ns, was.st_mtime_ns))


def test_speedybeef7v3_is_flashable_and_traceable(project, board):
    data = board.manifest.to_json()
    assert (data["target"], data["board"], data["mcu"]) == ("speedybeef7v3", BOARD, "STM32F722")
    config = project.config_dir / "configs" / BOARD / "config.h"
    assert data["board_config_sha256"] == _sha256(config)
    assert data["toolchain"]["required"] == "13.3.1"
    assert data["toolchain"]["version"]
    usage = data["usage"]
    assert 0 < usage["flash_bytes"] < usage["flash_total"] == 512 * 1024
    assert 0 < usage["ram_bytes"] < usage["ram_total"]
    assert set(data["artifacts"]) == {"hex", "bin", "elf"}
    firmware = IntelHex(str(board.out_dir / data["artifacts"]["hex"]))
    assert firmware.minaddr() == 0x08000000
    binary = (board.out_dir / data["artifacts"]["bin"]).read_bytes()
    firmware.padding = 0x00  # objcopy fills gaps with zeros
    assert firmware.tobinstr() == binary
    assert data["git_revision"].encode() in binary
    assert data["board_config_sha256"][:7].encode() in binary  # the firmware's "config rev"
    assert (project.tree / "lib" / "main" / "STM32F7").is_dir()
    assert build(project, "speedybeef7v3", BuildOptions(jobs=JOBS)).up_to_date


def test_cli_build_prints_the_summary(project, sitl):
    proc = _wftool("build", "sitl", "--project", str(project.root))
    assert proc.returncode == 0, proc.stderr
    assert "sitl: up to date" in proc.stdout
    assert "build/sitl" in proc.stdout.replace(os.sep, "/")


def test_toolchain_mismatch_warns_or_fails_when_strict(project, board):
    found = board.manifest.toolchain
    if found["version"] == found["required"]:
        pytest.skip(f"this arm-none-eabi-gcc is the required {found['required']}: no mismatch")
    assert any("--strict-toolchain" in warning for warning in board.warnings)

    proc = _wftool("build", "speedybeef7v3", "--strict-toolchain", "--project", str(project.root))

    assert proc.returncode == 1
    assert proc.stderr.strip().count("\n") == 0
    assert f"requires {found['required']}" in proc.stderr


def test_cli_unknown_target_is_a_one_line_usage_error(project):
    proc = _wftool("build", "nosuchboard", "--project", str(project.root))
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0
    assert "unknown target 'nosuchboard'" in proc.stderr


def test_worktree_superproject_and_dirty_tree(project, tmp_path):
    worktree = tmp_path / "worktree"
    run_git(project.root, "worktree", "add", "-q", "--detach", str(worktree))
    other = Project(worktree)
    target = resolve_target(other, "sitl")

    tree.ensure_tree(other, target)

    gitdir = run_git(other.tree, "rev-parse", "--absolute-git-dir")
    assert "/worktrees/" in gitdir and gitdir.endswith("/modules/betaflight")
    assert tree.head(other) == tree.pinned_commit(other)
    (other.tree / "Makefile").write_text("# local edit\n")
    with pytest.raises(TreeError, match=r"uncommitted changes.*--clean"):
        tree.ensure_tree(other, target)
    tree.ensure_tree(other, target, allow_dirty=True)  # for `patches.apply` to decide
    assert tree.dirty_paths(other) == ["Makefile"]
    patches.apply(other, force=True)
    assert tree.dirty_paths(other) == []


def test_series_round_trip_on_the_real_tree(project, tmp_path):
    """Commit in betaflight/, export, reset, apply: the partial clone handles the series."""
    worktree = tmp_path / "series"
    run_git(project.root, "worktree", "add", "-q", "--detach", str(worktree))
    other = Project(worktree)
    tree.ensure_tree(other, resolve_target(other, "sitl"))
    pin = tree.pinned_commit(other)
    core = other.tree / "src" / "main" / "fc" / "core.c"
    core.write_text(core.read_text() + "\n/* wftool e2e */\n")
    commit_all(other.tree, "Mark core.c\n\nAn e2e test change.")

    names = patches.export(other)
    exported = tree.head(other)
    assert patches.reset(other) and tree.head(other) == pin
    assert "wftool e2e" not in core.read_text()
    assert patches.apply(other)

    assert [path.name for path in other.patches_dir.glob("*.patch")] == names
    assert tree.head(other) == exported  # deterministic: the same commit again
    assert "wftool e2e" in core.read_text()
    assert patches.status(other).state == "applied"


def _wftool(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "wftool", *args], capture_output=True, text=True, timeout=600
    )


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _sitl_starts(program: Path, workdir: Path) -> bool:
    """Run the SITL binary briefly (it writes eeprom.bin to its cwd): does it initialise?"""
    copy = workdir / program.name
    shutil.copy2(program, copy)
    with subprocess.Popen(
        [str(copy)], cwd=workdir, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    ) as process:
        deadline = time.monotonic() + 20
        seen = ""
        try:
            assert process.stdout is not None
            while time.monotonic() < deadline and "[system]Init" not in seen:
                line = process.stdout.readline()
                if not line:
                    break
                seen += line
        finally:
            process.kill()
    return "[system]Init" in seen
